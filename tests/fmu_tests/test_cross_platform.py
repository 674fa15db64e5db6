"""The native FMUs on every desktop (issue 28): each of the six native FMUs of the session build
(RailCarNative, RailCarEstimatorNative, AtoControllerNative: FMI 2.0; RailCarNative3,
RailCarEstimatorNative3, AtoControllerNative3: FMI 3.0) carries a binary for every platform of ``fmu_src.build.toolchain.TARGETS`` (linux x86-64,
Windows x86-64, linux aarch64) whose compiler this machine has, and its ``sources/`` alone
compile for each of them with all warnings as errors.

- sources/ is unpacked into a fresh folder and compiled with nothing else: no -I to fmpy's
  headers, no define; the Windows DLL needs only what Windows ships (KERNEL32.dll, msvcrt.dll);
- every library scenario, closed loop on the native RailCar, replayed through the C host
  tests/fmu_cases/csv_host.c on all four native FMUs (tests/fmu_cases/cross_platform.py): the
  aarch64 binaries under qemu-aarch64 (the host cross-compiled for aarch64) and the Windows DLLs
  under Wine (the host built with mingw-w64: LoadLibrary, Windows paths and resource
  locations), one host process per platform, against the x86-64 binaries: bit-identical, but
  for the outputs in ULP_BOUNDS, whose largest difference is bounded and explained there;
- the two native AtoControllers (FMI 2 and 3) on ato_nominal's span, fed the inputs of the
  Python controller's closed loop (test_ato_fmu.closed_loop_on_chain), through the same host on
  each platform (Booleans and Int32 among the inputs and outputs): every output at every step
  as the x86-64 binary's, within ATO_ULP_BOUNDS (the ATO calls libm's pow);
- FMU states on every platform (csv_host -k): all six native FMUs (RailCar and the estimator on
  two library scenarios, the AtoControllers on ato_nominal's span) take their state mid-run,
  serialize it, and replay from the deserialized bytes and from the state itself bit for bit,
  on each platform's binary; the bytes are compared with the x86-64 ones and the x86-64 bytes
  are deserialized on the foreign platform: the same and replaying bit for bit on aarch64,
  refused by the type-size check on Windows (LLP64), as STATE_OUTCOME records;
- the commands docs/native_fmus.md gives Windows and ARM users, run as written: the libraries
  they build, put back into the FMU and zipped, run like the shipped binaries.

A platform whose compiler (or qemu, or Wine) is missing cannot be checked here: those tests are
skipped with a reason naming the Debian package to install (.ci/run installs them, so CI runs
them all).
"""
from __future__ import annotations

import dataclasses
import os
import re
import shutil
import subprocess
from concurrent.futures import ThreadPoolExecutor
import time
import zipfile
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from conftest import ROOT
from csv_host_cases import HOST_FLAGS, NativeFmu, assert_same, bits, read_output
from fmu_cases import cross_platform
from fmu_cases.cross_platform import FOREIGN, Platform, Unavailable
from fmu_src.build import native_fmi3, toolchain
from fmu_src.build.toolchain import LINUX_AARCH64, LINUX_X86_64, TARGETS, WINDOWS_X86_64

NATIVE = {  # native FMU -> (modelIdentifier, FMI version)
    "RailCarNative": ("RailCar", 2),
    "RailCarEstimatorNative": ("RailCarEstimator", 2),
    "RailCarNative3": ("RailCar", 3),
    "RailCarEstimatorNative3": ("RailCarEstimator", 3),
    "AtoControllerNative": ("AtoController", 2),
    "AtoControllerNative3": ("AtoController", 3),
}
ATO_NATIVE = ("AtoControllerNative", "AtoControllerNative3")
COMPILED_ALONE = [pytest.param(name, target, id=f"{name}-{target.tuple}")
                  for name in NATIVE for target in TARGETS
                  if name not in ATO_NATIVE
                  or (name == "AtoControllerNative3" and target is not LINUX_AARCH64)]
"""sources/ compiled alone (~8 s a build): every platform for the RailCar and estimator FMUs;
AtoControllerNative3's on linux x86-64 and Windows (its aarch64 library is build.py's, with
these flags, from the same files; the FMI 3 glue's sources/ compile alone for aarch64 in
RailCarNative3's); AtoControllerNative's differ from those only by the FMI 2 glue, which
RailCarNative's compile everywhere."""
STRICT = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-ffp-contract=off",
          "-shared", "-Wl,--no-undefined"]
LINK_ONLY = ("-shared", "-Wl,--no-undefined")       # STRICT's flags that only the link reads
WINDOWS_DLLS = {"kernel32.dll", "msvcrt.dll"}      # shipped with every Windows


def compiler_or_skip(target: toolchain.Target) -> list[str]:
    cc = toolchain.target_compiler(target)
    if cc is None:
        pytest.skip(f"not checked on this machine: {toolchain.missing_compiler(target)}")
    return cc


def binary_name(target: toolchain.Target, name: str) -> str:
    model, version = NATIVE[name]
    folder = target.fmi2_folder if version == 2 else target.tuple
    return f"binaries/{folder}/{model}{target.extension}"


@pytest.fixture(scope="module")
def native_dir(built_fmus) -> Path:
    return built_fmus["RailCar"].parent / "native"


# ----------------------------------------------------------------------- what the FMUs carry

@pytest.mark.parametrize("name", NATIVE)
def test_every_platform_with_a_compiler_has_its_binary(native_dir, name):
    """The binaries/ folders are exactly the platforms whose compiler is here, in FMI 2's
    folder names (linux64, win64; aarch64-linux: FMI 2.0.4 section 2.3 refers other platforms
    to FMI 3's tuples) or FMI 3's tuples; the documentation page lists the same."""
    with zipfile.ZipFile(native_dir / f"{name}.fmu") as z:
        binaries = sorted(n for n in z.namelist() if n.startswith("binaries/") and not n.endswith("/"))
        page = z.read("documentation/_main.html" if NATIVE[name][1] == 2
                      else "documentation/index.html").decode()
    here = toolchain.available_targets(report=False)
    assert binaries == sorted(binary_name(t, name) for t in here)
    assert sorted(re.findall(r"<code>binaries/([\w-]+)/</code>", page)) == sorted(
        b.split("/")[1] for b in binaries)


@pytest.mark.parametrize("name", NATIVE)
def test_sources_list_every_file_and_carry_every_header(native_dir, name, tmp_path):
    """SourceFiles (FMI 2) / buildDescription.xml (FMI 3) name every .c file shipped; every
    #include "..." of the sources is in sources/; FMI 3 FMUs carry the FMI 3 headers."""
    from fmpy import read_model_description
    fmu = native_dir / f"{name}.fmu"
    md = read_model_description(str(fmu))
    listed = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    with zipfile.ZipFile(fmu) as z:
        shipped = {n[len("sources/"):]: z.read(n) for n in z.namelist()
                   if n.startswith("sources/") and not n.endswith("/")}
    assert sorted(listed) == sorted(n for n in shipped if n.endswith(".c"))
    included = {m.decode() for data in shipped.values()
                for m in re.findall(rb'^\s*#\s*include\s+"([^"]+)"', data, re.M)}
    assert included and not included - shipped.keys(), included - shipped.keys()
    if NATIVE[name][1] == 3:
        assert {"fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h"} <= included
        xml = shipped["buildDescription.xml"].decode()
        assert '<IncludeDirectory name="." />' in xml
        assert '<Library name="m"' in xml and '<Library name="pthread"' in xml


# --------------------------------------------------------- sources/ alone, for each platform

@pytest.mark.parametrize("name, target", COMPILED_ALONE)
def test_sources_alone_compile_with_warnings_as_errors(native_dir, name, target, tmp_path):
    cc = compiler_or_skip(target)
    src = tmp_path / "sources"
    with zipfile.ZipFile(native_dir / f"{name}.fmu") as z:
        for n in z.namelist():
            if n.startswith("sources/") and not n.endswith("/"):
                z.extract(n, tmp_path)
    out = tmp_path / f"{NATIVE[name][0]}{target.extension}"
    compile_flags = [f for f in STRICT if f not in LINK_ONLY]
    sources = sorted(src.glob("*.c"))

    def compile_one(c_file: Path) -> tuple[list[str], subprocess.CompletedProcess]:
        cmd = [*cc, *compile_flags, *target.flags, "-I", str(src), "-c", str(c_file),
               "-o", str(c_file.with_suffix(".o"))]
        return cmd, subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)

    # each file compiled on its own, as many at a time as there are cores (the same compiler
    # and flags as one command with every file: a build system's way), then linked
    with ThreadPoolExecutor(max_workers=os.cpu_count() or 1) as pool:
        for cmd, proc in pool.map(compile_one, sources):
            assert proc.returncode == 0 and not proc.stderr, f"{' '.join(cmd)}\n{proc.stderr}"
    cmd = [*cc, *STRICT, *target.flags, *(str(c.with_suffix(".o")) for c in sources),
           "-o", str(out), *target.libraries]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0 and not proc.stderr, f"{' '.join(cmd)}\n{proc.stderr}"
    prefix = "fmi2" if NATIVE[name][1] == 2 else "fmi3"
    exports, needed = _exports_and_needs(out, target)
    assert f"{prefix}DoStep" in exports and "railcar_fmu_binary_id" in exports
    assert not [s for s in exports if s.startswith(("glue_", "model_", "rc_", "gc_"))]
    if target is WINDOWS_X86_64:
        assert {d.lower() for d in needed} <= WINDOWS_DLLS, needed
    else:
        assert not [d for d in needed if "pthread" in d and d != "libpthread.so.0"], needed


def _exports_and_needs(lib: Path, target: toolchain.Target) -> tuple[list[str], list[str]]:
    """The exported symbols and the shared libraries ``lib`` needs at run time."""
    if target is WINDOWS_X86_64:
        dump = subprocess.run(["x86_64-w64-mingw32-objdump", "-p", str(lib)], capture_output=True,
                              text=True, check=True).stdout
        needed = re.findall(r"DLL Name: (\S+)", dump)
        table = dump.split("[Ordinal/Name Pointer] Table", 1)[1]
        exports = re.findall(r"^\s*\[\s*\d+\]\s+(\S+)$", table, re.M)
        return exports, needed
    dyn = subprocess.run(["readelf", "-d", "--dyn-syms", "-W", str(lib)], capture_output=True,
                         text=True, check=True).stdout
    needed = re.findall(r"\(NEEDED\)\s+Shared library: \[(.+?)\]", dyn)
    exports = [f[7] for f in (ln.split() for ln in dyn.splitlines())
               if len(f) >= 8 and f[4] == "GLOBAL" and f[6] != "UND"]
    return exports, needed


@pytest.mark.parametrize("name", NATIVE)
def test_windows_binary_needs_only_what_windows_ships(native_dir, name, tmp_path):
    compiler_or_skip(WINDOWS_X86_64)
    dll = tmp_path / "x.dll"
    with zipfile.ZipFile(native_dir / f"{name}.fmu") as z:
        dll.write_bytes(z.read(binary_name(WINDOWS_X86_64, name)))
    exports, needed = _exports_and_needs(dll, WINDOWS_X86_64)
    assert {d.lower() for d in needed} == WINDOWS_DLLS, needed
    prefix = "fmi2" if NATIVE[name][1] == 2 else "fmi3"
    assert f"{prefix}Instantiate" in exports or f"{prefix}InstantiateCoSimulation" in exports


# ------------------------------------- every library scenario on the foreign binaries

# The largest difference from the linux x86-64 binary each output may show, per platform, in
# units in the last place (ulps: how many doubles lie between the two values); every output not
# listed, the time column included, must be bit-identical at every row of every library
# scenario through all four native FMUs. Measured 2026-11-27 (`python
# tests/fmu_cases/cross_platform.py` prints the table; the test prints it too, with -s): under
# qemu (aarch64) and under Wine (Windows x86-64), 76 runs (19 scenarios x 4 FMUs), 2128 output
# columns, all bit-identical. Before the core stopped calling libm for results (models/fpmath.py,
# models/core/fpmath.c: squares as x * x), est.mass_std differed under Wine in 34 of the 76 runs
# by up to 3 ulps: it divides by theta1 squared, then computed with pow(x, 2.0), which glibc does
# not always round as x * x and mingw-w64's pow does (test_libm_pow_of_a_square_depends_on_the_
# library shows both). No bound is left; a platform whose results differ again gets its output
# listed here with the measured bound and the reason.
ULP_BOUNDS = {
    "aarch64-linux": {},
    "x86_64-windows": {},
}


@pytest.fixture(scope="module")
def hosts(tmp_path_factory) -> SimpleNamespace:
    """Each platform's csv_host, built on first use (platform_or_skip), once per module: the
    library sweep and the AtoController's span share them (and Wine's prefix)."""
    return SimpleNamespace(folder=tmp_path_factory.mktemp("hosts"), platforms={})


@pytest.fixture(scope="module")
def sweep_inputs(native_dir, hosts, tmp_path_factory) -> SimpleNamespace:
    """The four native FMUs unpacked, every library scenario's cases (closed loop on the native
    RailCar) and the linux x86-64 host's outputs for each: the reference."""
    folder = tmp_path_factory.mktemp("cross_platform")
    started = time.perf_counter()
    fmus = cross_platform.unpack_all(native_dir, folder / "fmus")
    cases = cross_platform.closed_loop_cases(native_dir)
    x86 = platform_or_skip(hosts, LINUX_X86_64)
    reference = cross_platform.run_platform(x86, cases, fmus, folder / "runs")
    return SimpleNamespace(native_dir=native_dir, folder=folder, fmus=fmus, cases=cases,
                           reference=reference, x86=x86, seconds=time.perf_counter() - started,
                           platforms=hosts.platforms)


def platform_or_skip(inputs: SimpleNamespace, target: toolchain.Target) -> Platform:
    """The host for ``target`` (built once per module: ``inputs`` is the hosts fixture, or
    sweep_inputs, which shares its platforms), or a skip naming what is missing."""
    if target.tuple not in inputs.platforms:
        try:
            inputs.platforms[target.tuple] = cross_platform.build_platform(
                target, inputs.folder / "hosts")
        except Unavailable as exc:
            inputs.platforms[target.tuple] = exc
    found = inputs.platforms[target.tuple]
    if isinstance(found, Unavailable):
        pytest.skip(f"not checked on this machine: {found}")
    return found


def test_the_x86_64_replay_reproduces_the_closed_loop_runs(sweep_inputs):
    """The cases replay what the closed loop did: the x86-64 host's RailCar outputs (FMI 2 and
    3) are the closed-loop run's, bit for bit, in every scenario; and the runs moved."""
    stems = cross_platform.library_scenarios()
    assert len(stems) >= 19 and len(sweep_inputs.cases) == 4 * len(stems)
    for case in sweep_inputs.cases:
        got = sweep_inputs.reference[case.key]
        if case.closed_loop is not None:
            assert_same(case.closed_loop, {n: got[n] for n in case.closed_loop}, case.key)
        if NATIVE[case.fmu][0] == "RailCar":
            assert got["car.speed"].max() > 5.0, case.key


@pytest.mark.parametrize("target", FOREIGN, ids=[t.tuple for t in FOREIGN])
def test_every_library_scenario_on_the_foreign_binary(sweep_inputs, target):
    """Every library scenario through the four native FMUs' binaries for ``target`` (one host
    process: csv_host -b), against the linux x86-64 binary: every output at every row
    bit-identical, but the outputs of ULP_BOUNDS[target], within their bound. The table of
    every difference is printed (pytest -s) and is the failure's message."""
    platform = platform_or_skip(sweep_inputs, target)
    started = time.perf_counter()
    result = cross_platform.sweep(platform, sweep_inputs.reference, sweep_inputs.cases,
                                  sweep_inputs.fmus, sweep_inputs.folder / "runs")
    seconds = time.perf_counter() - started
    bounds = ULP_BOUNDS[target.tuple]
    largest = cross_platform.largest_per_output(result)
    report = [f"{target.tuple}: {len(result)} runs in {seconds:.1f} s (the x86-64 reference and "
              f"the closed-loop runs: {sweep_inputs.seconds:.1f} s)",
              cross_platform.scenario_table(target.tuple, result),
              cross_platform.table({target.tuple: result}, only_differing=False)]
    report += [f"largest difference of {name}: {largest.get(name, 0):g} ulp (bound {bound})"
               + ("; bit-identical everywhere, its bound can go" if name not in largest else "")
               for name, bound in bounds.items()]
    text = "\n".join(report)
    print(text)
    assert len(result) == len(sweep_inputs.cases)
    beyond = [f"{key} {name}: {d.ulps:g} ulp > {bounds.get(name, 0)}"
              for key, diffs in result.items() for name, d in diffs.items()
              if d.ulps > bounds.get(name, 0)]
    assert not beyond, "\n".join(["beyond the bounds:", *beyond, "", text])


def test_the_comparison_sees_one_ulp(sweep_inputs):
    """One output one ulp off at one row is reported as 1 ulp there, and the time column is
    compared too; NaN against a number is infinitely far."""
    case = sweep_inputs.cases[0]
    reference = sweep_inputs.reference[case.key]
    changed = {n: np.array(v, copy=True) for n, v in reference.items()}
    name = next(n for n, v in changed.items()
                if n != "time" and v.dtype.kind == "f" and v[7] != 0.0)
    changed[name][7] = np.nextafter(changed[name][7], np.inf)
    changed["time"][3] = np.nan
    diffs = cross_platform.compare(reference, changed)
    assert (diffs[name].ulps, diffs[name].rows, diffs[name].first_row) == (1.0, 1, 7)
    assert diffs["time"].ulps == np.inf
    assert all(d.rows == 0 for n, d in diffs.items() if n not in (name, "time"))
    assert cross_platform.ulp_distance(np.array([-0.0, 1.0, -1e-300]),
                                       np.array([0.0, 1.0 + 2 ** -52 * 3, 1e-300])).tolist() == [
        0.0, 3.0, 2.0 * np.float64(1e-300).view(np.int64)]


def test_one_host_process_runs_a_batch_and_names_the_run_that_failed(sweep_inputs, tmp_path):
    """csv_host -b: the runs of RUNS.txt one after the other; a failing run (a wrong GUID) is
    named by its line and does not stop the next, whose outputs equal a run alone; the exit
    status is the largest of the runs'. An empty RUNS.txt is refused."""
    case = next(c for c in sweep_inputs.cases if c.fmu == "RailCarNative3")
    fmu = sweep_inputs.fmus[case.fmu]
    x86 = sweep_inputs.x86
    out = cross_platform.write_case_files(case, fmu, x86, tmp_path / "case")

    def args(token: str, out_csv: Path) -> str:
        return "\t".join(["-q", "-s", repr(case.step), "-e", repr(case.stop), "fmi3",
                          str(x86.binary(fmu.root, case.fmu)), str(fmu.resources), token,
                          str(out.parent / "params.csv"), str(out.parent / "inputs.csv"),
                          str(out_csv), fmu.spec("car.speed")])
    runs = tmp_path / "runs.txt"
    runs.write_text(args("not-the-token", tmp_path / "bad.csv") + "\n\n"
                    + args(fmu.token, tmp_path / "good.csv") + "\n")
    proc = subprocess.run([str(x86.host), "-b", str(runs)], capture_output=True, text=True)
    assert proc.returncode == 2, proc.stderr
    assert f"csv_host: {runs}:1: exit status 2" in proc.stderr
    assert f"{runs}:3" not in proc.stderr                   # the good run (line 3) passed
    speed = [float(line.split(",")[1]) for line in
             (tmp_path / "good.csv").read_text().splitlines()[1:]]
    assert np.array_equal(bits(speed), bits(sweep_inputs.reference[case.key]["car.speed"]))
    assert not (tmp_path / "bad.csv").exists()
    runs.write_text("\n")
    proc = subprocess.run([str(x86.host), "-b", str(runs)], capture_output=True, text=True)
    assert proc.returncode == 3 and f"csv_host: {runs}: no run" in proc.stderr


def test_windows_paths_with_a_space_and_a_percent(sweep_inputs, tmp_path):
    """The FMUs unpacked under a folder named "a b%20c": the Windows host passes the FMI 2
    resource location percent-encoded (file:///Z:/.../a%20b%2520c/resources/), the FMI 3 one
    as a plain Z:\\ path, the profile file by its Z:\\ path; the runs give the sweep's results
    (within ULP_BOUNDS of the x86-64 ones)."""
    windows = platform_or_skip(sweep_inputs, WINDOWS_X86_64)
    names = ("RailCarNative", "RailCarNative3")
    fmus = {n: NativeFmu.unpack(sweep_inputs.native_dir / f"{n}.fmu", tmp_path / "a b%20c" / n)
            for n in names}
    cases = [c for c in sweep_inputs.cases if c.fmu in names and c.scenario == "steep_grades"]
    assert "track.grade_profile" in cases[0].parameters
    got = cross_platform.run_platform(windows, cases, fmus, tmp_path / "runs")
    bounds = ULP_BOUNDS[WINDOWS_X86_64.tuple]
    for case in cases:
        diffs = cross_platform.compare(sweep_inputs.reference[case.key], got[case.key])
        assert all(d.ulps <= bounds.get(n, 0) for n, d in diffs.items()), case.key


POW_SQUARE = Path(__file__).resolve().parents[1] / "fmu_cases" / "pow_square.c"


def test_libm_pow_of_a_square_depends_on_the_library(sweep_inputs, tmp_path):
    """Why the core squares by x * x (models/fpmath.py) and never calls libm's pow: pow(x, 2.0)
    over 10^6 values x = 1 / (g m), m from 10 t to 200 t (theta1, whose square est.mass_std
    divides by): glibc's differs from x * x for some (832 measured), mingw-w64's (linked
    -static, as in the DLL) for none; glibc on aarch64 (under qemu, when it is here) as on
    x86-64. While the core called pow, est.mass_std differed under Wine by up to 3 ulps."""
    windows = platform_or_skip(sweep_inputs, WINDOWS_X86_64)
    platforms = [sweep_inputs.x86, windows]
    try:
        platforms.append(cross_platform.build_platform(LINUX_AARCH64, tmp_path / "arm"))
    except Unavailable as exc:
        print(f"pow_square not run on aarch64: {exc}")
    counts = {}
    for platform in platforms:
        out = tmp_path / f"pow_square_{platform.target.tuple}{'.exe' if platform.windows else ''}"
        cc = toolchain.target_compiler(platform.target)
        static = ["-static"] if platform.windows else []
        cmd = [*cc, *HOST_FLAGS, *static, str(POW_SQUARE), "-o", str(out), "-lm"]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stderr}"
        run = subprocess.run([*platform.prefix, platform.path(out), "1000000"],
                             capture_output=True, text=True, env=platform.env, timeout=120)
        assert run.returncode == 0, run.stderr
        counts[platform.target.tuple] = [int(x) for x in run.stdout.split()]
    print(counts)       # [values, pow(x, 2) != x * x, of them more than one ulp apart]
    assert all(c[0] == 1_000_000 for c in counts.values())
    assert counts["x86_64-linux"][1] > 100 and counts["x86_64-linux"][2] == 0
    assert counts["x86_64-windows"][1:] == [0, 0]
    if "aarch64-linux" in counts:
        assert counts["aarch64-linux"] == counts["x86_64-linux"]


# ------------------------------------------- the commands of docs/native_fmus.md, as written

DOC = ROOT / "docs" / "native_fmus.md"
# each block of the page marked <!-- tested: NAME --> and the platform whose binary it builds
DOC_BLOCKS = {"windows-mingw": WINDOWS_X86_64, "aarch64-cross": LINUX_AARCH64}
DOC_SCENARIOS = ("steep_grades", "station_day")


def doc_commands(block: str) -> list[str]:
    """The command lines of the page's ```bash block marked <!-- tested: block -->."""
    text = DOC.read_text(encoding="utf-8")
    m = re.search(rf"<!-- tested: {re.escape(block)} -->\s*```bash\n(.*?)```", text, re.S)
    assert m, f"{DOC}: no ```bash block after <!-- tested: {block} -->"
    return [line for line in m.group(1).splitlines()
            if line.strip() and not line.lstrip().startswith("#")]


def run_doc_commands(block: str, cwd: Path, model: str) -> str:
    """Each line in bash from the unzipped FMU; the estimator's file is named after its
    modelIdentifier, as the page says. The output of all of them."""
    output = []
    for line in doc_commands(block):
        line = line.replace("RailCar.", f"{model}.")
        proc = subprocess.run(["bash", "-euo", "pipefail", "-c", line], cwd=cwd,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0 and not proc.stderr, (
            f"{DOC.name} [{block}]: {line}\n{proc.stderr}")
        output.append(proc.stdout)
    return "".join(output)


# one FMU per block, so that both models and both FMI versions are built (~10 s each)
@pytest.mark.parametrize("block, name", [("windows-mingw", "RailCarEstimatorNative3"),
                                         ("aarch64-cross", "RailCarNative")])
def test_the_documented_build_runs_like_the_shipped_binary(sweep_inputs, block, name, tmp_path):
    """The page's commands, as written, from an unzipped FMU whose binary for that platform is
    removed: compile sources/, put the library in its binaries/ folder (both FMI versions'
    folders), zip the FMU again (<!-- tested: repack -->); the rebuilt FMU, unzipped, runs two
    library scenarios through the platform's host bit-identical to the shipped binary."""
    target = DOC_BLOCKS[block]
    compiler_or_skip(target)
    platform = platform_or_skip(sweep_inputs, target)
    model, _ = NATIVE[name]
    shipped = sweep_inputs.fmus[name]
    work = tmp_path / "fmu"
    with zipfile.ZipFile(sweep_inputs.native_dir / f"{name}.fmu") as z:
        z.extractall(work)
    for folder in {target.fmi2_folder, target.tuple}:
        shutil.rmtree(work / "binaries" / folder, ignore_errors=True)
    output = run_doc_commands(block, work, model)
    if target is WINDOWS_X86_64:            # the page's objdump line: the DLL's imports
        assert {d.lower() for d in re.findall(r"DLL Name: (\S+)", output)} == WINDOWS_DLLS, output
    run_doc_commands("repack", work, model)
    made = sorted(tmp_path.glob("*.fmu"))
    assert len(made) == 1, f"the repack block made {made}, not one FMU beside the folder"
    rebuilt = NativeFmu.unpack(made[0], tmp_path / "rebuilt")
    assert platform.binary(rebuilt.root, name).is_file()
    cases = [c for c in sweep_inputs.cases if c.fmu == name and c.scenario in DOC_SCENARIOS]
    got = {}
    for label, fmu in (("shipped", shipped), ("rebuilt", rebuilt)):
        got[label] = cross_platform.run_platform(platform, cases, {name: fmu},
                                                 tmp_path / label)
    for case in cases:
        assert_same(got["shipped"][case.key], got["rebuilt"][case.key], f"{block} {case.key}")



# ------------------------------------------- the native AtoControllers on one span, everywhere

# The ATO's core calls libm for one result: pow(x, 1.0 / 3.0), the cube root of the cruise
# speed at which the resistance's v^2 term balances a power (models/core/ato_motion.c,
# ato_span.c; Python's ``** (1 / 3)`` there). glibc's pow on x86-64 and on aarch64 and
# mingw-w64's may round it differently, and the planner's decisions (a mode, an EP stage) could
# then follow a different branch. The largest difference each output may show from the linux
# x86-64 binary, per platform, in ulps (integers and Booleans: their difference); every output
# not listed, the time column and the step statuses included, must be bit-identical at every
# step. Measured 2026-11-27 on ato_nominal's span (1355 steps, both FMI versions): all
# bit-identical under qemu (aarch64) and under Wine (Windows x86-64), so no bound is needed; a
# platform whose pow differs on this span gets its outputs listed here with the measured bound.
ATO_ULP_BOUNDS = {
    "aarch64-linux": {},
    "x86_64-windows": {},
}
ATO_SPAN = {"span.stop": 2150.0, "span.length": 2200.0, "span.schedule": 135.0}
"""ato_nominal's span (test_native_ato_fmu.py's profiles fixture); its grade and speed-limit
files are test_ato_fmu.py's GRADE_CSV and LIMIT_CSV, written by the ato_span fixture and passed
by absolute path, in each platform's spelling (Wine: Z:\\...)."""
STEP_ATO = 0.1      # [s] the closed loop's step (test_ato_fmu.py)


def _number_text(value, word: str) -> str:
    return repr(float(value)) if word == "real" else str(int(value))


@pytest.fixture(scope="module")
def ato_span(native_dir, hosts, tmp_path_factory) -> SimpleNamespace:
    """The native AtoControllers unpacked, the inputs the Python controller saw at each step of
    its closed loop on ato_nominal's span, and the linux x86-64 host's outputs: the reference."""
    import test_ato_fmu
    folder = tmp_path_factory.mktemp("ato_cross_platform")
    seen, commands, ctrl = test_ato_fmu.closed_loop_on_chain()
    assert ctrl.finished and len(seen) > 1000
    (folder / "grade.csv").write_text(test_ato_fmu.GRADE_CSV)
    (folder / "limits.csv").write_text(test_ato_fmu.LIMIT_CSV)
    profiles = {"span.grade_profile": folder / "grade.csv",
                "span.speed_limit_profile": folder / "limits.csv"}
    fmus = {n: NativeFmu.unpack(native_dir / f"{n}.fmu", folder / "fmus" / n) for n in ATO_NATIVE}
    x86 = platform_or_skip(hosts, LINUX_X86_64)
    inputs = SimpleNamespace(folder=folder, fmus=fmus, seen=seen, commands=commands,
                             parameters={**ATO_SPAN, **profiles})
    inputs.reference = run_ato(x86, inputs, "x86_64")
    return inputs


def run_ato(platform: Platform, span: SimpleNamespace, label: str) -> dict[str, dict]:
    """Both native AtoControllers over the span in one host process (csv_host -b); FMU ->
    output name -> values per row (the time column under "time", the step statuses under
    "status")."""
    lines, outs = [], {}
    for name, fmu in span.fmus.items():
        work = span.folder / "runs" / label / name
        work.mkdir(parents=True, exist_ok=True)
        params = ["vr,type,value"] + [
            f"{fmu.vars[k][0]},{fmu.vars[k][1]},{platform.path(v) if isinstance(v, Path) else v}"
            for k, v in span.parameters.items()]
        (work / "params.csv").write_text("\n".join(params) + "\n")
        names = list(span.seen[0])
        rows = [",".join(["time [s]", *(fmu.spec(n) for n in names)])]
        rows += [",".join([repr(k * STEP_ATO), *(_number_text(inputs[n], fmu.vars[n][1])
                                                 for n in names)])
                 for k, inputs in enumerate(span.seen)]
        (work / "inputs.csv").write_text("\n".join(rows) + "\n")
        out = work / "out.csv"
        if out.exists():
            out.unlink()
        folder = platform.target.fmi2_folder if fmu.version == 2 else platform.target.tuple
        binary = fmu.root / "binaries" / folder / f"{NATIVE[name][0]}{platform.target.extension}"
        lines.append("\t".join(["-q", "-s", repr(STEP_ATO), "-e", repr(len(span.seen) * STEP_ATO),
                                f"fmi{fmu.version}", platform.path(binary),
                                platform.path(fmu.resources), fmu.token,
                                platform.path(work / "params.csv"),
                                platform.path(work / "inputs.csv"), platform.path(out),
                                *(fmu.spec(n) for n in fmu.outputs)]))
        outs[name] = out
    runs = span.folder / "runs" / label / "runs.txt"
    runs.write_text("\n".join(lines) + "\n")
    proc = subprocess.run(platform.command(runs), capture_output=True, text=True,
                          env=platform.env, timeout=600)
    assert proc.returncode == 0, f"{' '.join(platform.command(runs))}:\n{proc.stderr[-4000:]}"
    got = {}
    for name, out in outs.items():
        fmu = span.fmus[name]
        _, times, columns, status = read_output(out, fmu, fmu.outputs)
        assert len(times) == len(span.seen) + 1, f"{label} {name}: {len(times)} rows"
        got[name] = {"time": times, "status": status, **columns}
    return got



def test_the_x86_64_host_gives_the_python_atocontrollers_commands(ato_span):
    """The reference is right: through the host, both native AtoControllers give the commands
    the Python controller gave in its closed loop, step for step, and stop at the mark."""
    for name, got in ato_span.reference.items():
        expected = {"traction_force_demand": [c.traction for c in ato_span.commands],
                    "brake_force_demand": [c.brake for c in ato_span.commands],
                    "ato.mode": [c.mode for c in ato_span.commands],
                    "ato.planned_speed": [c.planned_speed for c in ato_span.commands]}
        for output, values in expected.items():
            assert_same({output: np.array(values)}, {output: got[output][1:]}, f"{name} {output}")
        assert got["ato.finished"][-1] == 1 and not got["status"].any(), name
    assert_same(ato_span.reference["AtoControllerNative"],
                ato_span.reference["AtoControllerNative3"], "FMI 2 vs FMI 3 on x86-64")


@pytest.mark.parametrize("target", FOREIGN, ids=[t.tuple for t in FOREIGN])
def test_the_native_atocontrollers_on_the_foreign_binary(hosts, ato_span, target):
    """AtoControllerNative and AtoControllerNative3 for ``target`` (one host process under qemu
    or Wine) against the linux x86-64 binaries over ato_nominal's span: every output and the
    step statuses at every step bit-identical, but the outputs of ATO_ULP_BOUNDS[target]."""
    platform = platform_or_skip(hosts, target)
    started = time.perf_counter()
    got = run_ato(platform, ato_span, target.tuple)
    bounds = ATO_ULP_BOUNDS[target.tuple]
    report, beyond = [f"{target.tuple}: the native AtoControllers in {time.perf_counter() - started:.1f} s"], []
    for name, reference in ato_span.reference.items():
        diffs = cross_platform.compare(reference, got[name])
        report += [f"  {name} {output}: {d.ulps:g} ulp at {d.rows} step(s) from {d.first_row}"
                   for output, d in diffs.items() if d.rows]
        beyond += [f"{name} {output}: {d.ulps:g} ulp > {bounds.get(output, 0)}"
                   for output, d in diffs.items() if d.ulps > bounds.get(output, 0)]
    print("\n".join(report))
    assert not beyond, "\n".join(["beyond the bounds:", *beyond, *report])


# ------------------------------------------- FMU states on every platform (csv_host -k)

STATE_SCENARIOS = ("steep_grades", "headwind_change")
"""The RailCar and estimator cases whose FMU states are checked: est.method 2 (the default: the
slope window is in the state), steep_grades naming a grade-profile file (a String in the state),
headwind_change with est.forgetting set. The AtoControllers: ato_nominal's span."""
STATE_OUTCOME = {
    "aarch64-linux": "portable",
    "x86_64-windows": "refused",
}
"""What a state serialized by the linux x86-64 binary does on each foreign platform, measured
2026-11-28. aarch64 (LP64, little-endian, the same struct layout): the same bytes, and
deserialized there it replays bit for bit.
Windows x86-64 (LLP64: long has 4 bytes): other bytes from the header's type sizes on (every
struct with a long is laid out otherwise; the state is the machine's representation by design,
glue_common.c), refused by fmi2DeSerializeFMUstate / fmi3DeserializeFMUState naming the type
sizes and "(another platform)", the instance left as the FMI's Error state allows (no crash)."""


def ato_state_cases(span: SimpleNamespace) -> list:
    """ato_nominal's span as cross_platform Cases (the inputs the Python controller saw), one per
    native AtoController."""
    names = tuple(span.seen[0])
    rows = np.array([[float(inputs[n]) for n in names] for inputs in span.seen])
    times = np.arange(len(span.seen)) * STEP_ATO
    return [cross_platform.Case("ato_nominal", name, dict(span.parameters), names, times, rows,
                                STEP_ATO, len(span.seen) * STEP_ATO) for name in ATO_NATIVE]


@pytest.fixture(scope="module")
def state_runs(sweep_inputs, ato_span) -> SimpleNamespace:
    """Every native FMU's state round trip (csv_host -k, the state taken mid-run) on the linux
    x86-64 binaries, in one host process: the reference bytes."""
    cases = [c for c in sweep_inputs.cases if c.scenario in STATE_SCENARIOS]
    cases += ato_state_cases(ato_span)
    fmus = {**sweep_inputs.fmus, **ato_span.fmus}
    folder = sweep_inputs.folder / "states"
    started = time.perf_counter()
    own, _, proc = cross_platform.run_state_round_trips(sweep_inputs.x86, cases, fmus, folder)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return SimpleNamespace(cases=cases, fmus=fmus, folder=folder, x86=own, proc=proc,
                           seconds=time.perf_counter() - started, span=ato_span,
                           platform=sweep_inputs.x86)


def assert_round_trips(runs: dict, cases: list, label: str) -> None:
    """Each case's passes B (from the bytes) and C (the state taken with get) equal pass A bit for
    bit, and the report is whole: the row, the size of the bytes written."""
    assert sorted(runs) == sorted(c.key for c in cases), label
    for case in cases:
        run = runs[case.key]
        assert run.identical(), f"{label} {case.key}: {run.report}"
        assert run.out_written and run.state is not None, f"{label} {case.key}"
        assert int(run.report["row"]) == run.row == cross_platform.state_row(case)
        assert int(run.report["serialized_size"]) == len(run.state) > 1000, case.key
        assert run.state[:8] == b"RCFMUST\0", case.key


def test_fmu_states_round_trip_on_the_x86_64_binary(state_runs):
    """All six native FMUs (two library scenarios each for RailCar and the estimator, FMI 2 and
    3; the AtoControllers mid-span on ato_nominal): the state taken mid-run, serialized,
    deserialized and set, and the rows from there replayed bit for bit; the state taken with get
    set again, likewise. The reference for the foreign platforms."""
    assert {c.fmu for c in state_runs.cases} == set(NATIVE)
    assert_round_trips(state_runs.x86, state_runs.cases, "x86_64-linux")
    for case in state_runs.cases:
        row = cross_platform.state_row(case)
        assert 0.4 < row / len(case.times) < 0.6, case.key
        if case.fmu in ATO_NATIVE:          # mid-span: on the move, far from both ends
            seen = state_runs.span.seen[row]
            assert 0.2 * ATO_SPAN["span.stop"] < seen["filter.position"] < 0.8 * ATO_SPAN["span.stop"]
            assert seen["filter.speed"] > 5.0, case.key
    print(f"x86_64-linux: {len(state_runs.cases)} state round trips in {state_runs.seconds:.1f} s")


def test_the_same_calls_serialize_the_same_bytes(state_runs, tmp_path):
    """Every case run again in a second x86-64 host process (another address layout) serializes
    the same bytes: a state holds no uninitialised padding (the AtoController's tuning once held
    the upper half of a heap pointer there) and no address."""
    again, _, proc = cross_platform.run_state_round_trips(state_runs.platform, state_runs.cases,
                                                          state_runs.fmus, tmp_path)
    assert proc.returncode == 0, proc.stderr[-4000:]
    for case in state_runs.cases:
        first, second = state_runs.x86[case.key].state, again[case.key].state
        assert first == second, f"{case.key}: {cross_platform.state_field_difference(first, second)}"


@pytest.mark.parametrize("target", FOREIGN, ids=[t.tuple for t in FOREIGN])
def test_fmu_states_on_the_foreign_binary(sweep_inputs, state_runs, target):
    """On ``target``'s binaries (one host process under qemu or Wine): every case's state round
    trip bit for bit, as on x86-64; the bytes serialized there against the x86-64 ones; and the
    x86-64 bytes deserialized there (csv_host -L): STATE_OUTCOME says which of "portable" (the
    same bytes, and pass B from them bit for bit) or "refused" (other bytes from the header's
    type sizes on, and the deserialize refused naming them, pass A whole, no crash) is the
    platform's."""
    platform = platform_or_skip(sweep_inputs, target)
    cases = state_runs.cases
    foreign = {c.key: state_runs.folder / LINUX_X86_64.tuple / c.key / "state.bin" for c in cases}
    started = time.perf_counter()
    own, loaded, proc = cross_platform.run_state_round_trips(platform, cases, state_runs.fmus,
                                                             state_runs.folder, foreign)
    seconds = time.perf_counter() - started
    assert_round_trips(own, cases, target.tuple)
    outcome = STATE_OUTCOME[target.tuple]
    report = [f"{target.tuple}: {len(cases)} state round trips and {len(loaded)} x86-64 states "
              f"loaded in {seconds:.1f} s (exit status {proc.returncode})"]
    for case in cases:
        mine, reference = own[case.key].state, state_runs.x86[case.key].state
        report.append(f"  {case.key}: bytes against x86-64: "
                      f"{cross_platform.state_field_difference(reference, mine)}; x86-64's "
                      f"deserialized here: {loaded[case.key].report.get('pass_b') or loaded[case.key].report.get('failed')}")
    text = "\n".join(report)
    print(text)
    assert sorted(loaded) == sorted(c.key for c in cases)
    for case in cases:
        mine, reference = own[case.key].state, state_runs.x86[case.key].state
        run = loaded[case.key]
        assert run.out_written, f"{case.key}: pass A not written\n{text}"
        if outcome == "portable":
            assert mine == reference, text
            assert run.identical(), f"{case.key}: {run.report}\n{text}"
        else:
            assert mine[:16] == reference[:16] and mine[16:24] != reference[16:24], text
            assert "pass_b" not in run.report and "pass_c" not in run.report, run.report
            call = "fmi2DeSerializeFMUstate" if NATIVE[case.fmu][1] == 2 else "fmi3DeserializeFMUState"
            assert f"{call} returned Error: {call}: the FMU state was written where double, " \
                   "long, void *, int, size_t have 8, 8, 8, 4, 8 bytes; here they have 8, 4, 8, " \
                   "4, 8 (another platform)" in run.report.get("failed", ""), run.report
    assert proc.returncode == (0 if outcome == "portable" else 2), proc.stderr[-4000:]


def test_a_corrupt_state_is_refused_and_another_runs_state_is_seen(state_runs, tmp_path):
    """csv_host -L with bytes that are not this run's state, on x86-64 (the checks are the
    platform's own): one byte flipped in the model's part (the checksum sees it), the bytes cut
    short, another FMU's state: each refused by fmi3DeserializeFMUState with its reason, pass A
    written, the run stopped there (no pass B). A whole state of the same FMU from another
    scenario's run (steep_grades' at its row, for headwind_change) is accepted, and
    the host's comparison sees pass B leave pass A at the state's row, while pass C (the state
    taken with get) stays identical. One host process; its exit status 2."""
    case = next(c for c in state_runs.cases
                if c.fmu == "RailCarEstimatorNative3" and c.scenario == "headwind_change")
    good = state_runs.x86[case.key].state
    flipped = bytearray(good)
    flipped[len(good) // 2] ^= 0x01
    bad = {"flipped": bytes(flipped), "truncated": good[:-100],
           "other_fmu": state_runs.x86["headwind_change.RailCarNative3"].state,
           "other_run": state_runs.x86["steep_grades.RailCarEstimatorNative3"].state}
    reasons = {"flipped": "the FMU state is corrupt (checksum mismatch",
               "truncated": "(truncated)",
               "other_fmu": "the FMU state belongs to another FMU"}
    cases, foreign = [], {}
    for label, data in bad.items():       # one case per bad state: one host process
        (tmp_path / f"{label}.bin").write_bytes(data)
        cases.append(dataclasses.replace(case, scenario=f"{case.scenario}_{label}"))
        foreign[cases[-1].key] = tmp_path / f"{label}.bin"
    own, loaded, proc = cross_platform.run_state_round_trips(state_runs.platform, cases,
                                                             state_runs.fmus, tmp_path, foreign)
    assert proc.returncode == 2, proc.stderr
    for label, run_case in zip(bad, cases):
        run = loaded[run_case.key]
        assert own[run_case.key].identical(), own[run_case.key].report
        assert run.out_written, label
        assert f"state_runs.txt:{2 * cases.index(run_case) + 2}: exit status 2" in proc.stderr
        if label == "other_run":
            row = cross_platform.state_row(case)
            assert run.report["pass_b"].startswith(f"differs row {row} column "), run.report
            assert run.report["pass_c"] == "identical" and "failed" not in run.report
            continue
        assert "pass_b" not in run.report, (label, run.report)
        assert "fmi3DeserializeFMUState returned Error" in run.report.get("failed", ""), run.report
        assert reasons[label] in run.report["failed"], (label, run.report)


# ------------------------------------------------------------- a machine without a compiler

def test_a_missing_cross_compiler_is_printed_with_its_package(monkeypatch, capsys):
    """No platform is left out silently: without mingw the build says so, naming the package."""
    real_which = shutil.which
    monkeypatch.setattr(toolchain.shutil, "which",
                        lambda cmd, *a, **k: None if "mingw32" in cmd else real_which(cmd, *a, **k))
    here = toolchain.available_targets()
    out = capsys.readouterr().out
    assert WINDOWS_X86_64 not in here
    assert ("SKIPPED platform x86_64-windows: x86_64-w64-mingw32-gcc not found "
            "(apt-get install mingw-w64)") in out
    with pytest.raises(RuntimeError, match=r"x86_64-w64-mingw32-gcc not found \(apt-get install mingw-w64\)"):
        native_fmi3.compile_binary(Path("unused.dll"), target=WINDOWS_X86_64)


def test_a_missing_qemu_or_wine_names_its_package(monkeypatch, tmp_path):
    """No foreign check is left out silently: without qemu-aarch64 or Wine the sweep's host
    cannot be set up, and the reason (the skip's message) names the package to install."""
    real_which = shutil.which
    monkeypatch.setattr(cross_platform.shutil, "which", lambda cmd, *a, **k: (
        None if cmd == "qemu-aarch64" else real_which(cmd, *a, **k)))
    with pytest.raises(Unavailable, match=r"qemu-aarch64 not found \(apt-get install qemu-user\)"):
        cross_platform.build_platform(LINUX_AARCH64, tmp_path)
    monkeypatch.setattr(cross_platform, "wine_command", lambda: None)
    with pytest.raises(Unavailable, match=r"no Wine \(apt-get install wine64\)"):
        cross_platform.build_platform(WINDOWS_X86_64, tmp_path)
    monkeypatch.setattr(cross_platform.toolchain, "target_compiler", lambda target: None)
    with pytest.raises(Unavailable, match=r"apt-get install mingw-w64"):
        cross_platform.host_compile_command(WINDOWS_X86_64, tmp_path / "x.exe")


def test_the_documented_native_build_is_the_tested_cross_build():
    """The page's `cc` block (for the machine the library is for: an ARM Linux machine, any
    Unix) is the tested aarch64 cross build with the native compiler: one command, the same
    flags, so testing the cross build tests it."""
    native_build = doc_commands("unix-cc")
    cross_build = doc_commands("aarch64-cross")
    assert len(native_build) == 1 and native_build[0].startswith("cc ")
    assert cross_build[0].split() == ["aarch64-linux-gnu-gcc", *native_build[0].split()[1:]]
    # and it is the build's own recipe: the flags the shipped binaries are compiled with
    for flag in ("-std=c99", "-O2", "-ffp-contract=off", "-shared", "-fPIC", "-pthread", "-lm"):
        assert flag in native_build[0].split(), flag
