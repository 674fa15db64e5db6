"""The native FMUs are source FMUs: a user on another platform compiles the shipped sources/ with
fmpy's own build (``fmpy compile X.fmu``: fmpy.build.build_platform_binary, CMake on
fmpy/c-code/CMakeLists.txt) and must get the shipped binary's results bit for bit.

Each of the four native FMUs of the session build (RailCarNative, RailCarEstimatorNative,
RailCarNative3, RailCarEstimatorNative3) is copied without binaries/, compiled by the fmpy CLI
in a fresh folder (all warnings, warnings as errors), and run on two library scenarios next to
the shipped FMU and the pythonfmu FMU: every output bit-identical.

What fmpy 0.3.32 does with the build descriptions (read in .venv/.../fmpy/build.py and
model_description.py, and pinned below):
- it takes the file list of the first SourceFileSet, the FMI 3 ``language`` (C99 -> CMake
  C_STANDARD 99, which CMake turns into -std=gnu99) and PreprocessorDefinitions, and builds
  CMake's Release configuration: -O3 -DNDEBUG -fPIC; FMI 2 <SourceFiles> gives no -std at all;
- it drops the FMI 3 ``compilerOptions`` (read_build_description never reads it) and the
  <Library> elements: no -ffp-contract=off, no -lm.
GCC contracts a*b+c into fused multiply-adds by default in its GNU dialects (-std=gnu*,
-ffp-contract=fast; off only in the ISO modes -std=c99 etc., GCC manual "Optimize Options").
x86-64 has no FMA without -mfma, so here the results are bit-identical anyway; on aarch64, where
every core has FMA, they would not be. The control builds show it on this machine: -mfma breaks
bit-identity, and a pragma guard at the top of every .c restores it under -mfma.
"""
from __future__ import annotations

import os
import re
import subprocess
import sys
import zipfile
from pathlib import Path

import fmpy
import numpy as np
import pytest
from fmpy import extract, read_model_description

from conftest import OK, ROOT, FmuFile, Slave
from harness.run.runner import FmuRunner
from harness.run.scenario import load_scenario
from test_native_fmi3 import Slave3, _Md3
from test_native_fmi3 import Fmi3Runner

STEMS = ("steep_grades", "etcs_noisy_sensors")
LIBRARY = ROOT / "scenarios" / "library"
NATIVE = {  # native FMU -> (its pythonfmu twin, FMI version)
    "RailCarNative": ("RailCar", "2.0"),
    "RailCarEstimatorNative": ("RailCarEstimator", "2.0"),
    "RailCarNative3": ("RailCar", "3.0"),
    "RailCarEstimatorNative3": ("RailCarEstimator", "3.0"),
}
EST_INPUTS = ("traction_force", "brake_force", "sensor.speed", "sensor.position",
              "sensor.track_speed", "sensor.track_time")

# The shipped sources turn contraction off themselves: every .c of the core includes
# rc_fp_contract.h first. The control removes that line, to show what it prevents.
GUARD_LINE = b'#include "rc_fp_contract.h"'
CONTROLS = {  # build -> (native FMU, CFLAGS, sources with the guard removed)
    "fma": ("RailCarNative", "-mfma", True),
    "fma_guarded": ("RailCarNative", "-mfma", False),
}
FMA = re.compile(r"\bvf(n?)m(add|sub)")          # x86 fused multiply-add instructions


def bits(a) -> np.ndarray:
    return np.ascontiguousarray(a, dtype=np.float64).view(np.int64)


def _binary_dir(fmi_version: str) -> str:
    """Where fmpy puts (and looks for) the binary on this machine."""
    return fmpy.platform if fmi_version == "2.0" else fmpy.platform_tuple


def _model_identifier(name: str) -> str:
    return NATIVE[name][0]


def _shipped_binary(path: Path, fmi_version: str) -> bytes:
    with zipfile.ZipFile(path) as z:
        return z.read(f"binaries/{_binary_dir(fmi_version)}/{_model_identifier(path.stem)}.so")


# ---------------------------------------------------------------------------- the builds

def _source_copy(shipped: Path, dest: Path, unguard: bool) -> Path:
    """The shipped FMU without binaries/ (without the contraction guard if ``unguard``)."""
    dest.parent.mkdir(parents=True)
    with zipfile.ZipFile(shipped) as zin, zipfile.ZipFile(dest, "w", zipfile.ZIP_DEFLATED) as zout:
        for info in zin.infolist():
            if info.filename.startswith("binaries/"):
                continue
            data = zin.read(info.filename)
            if unguard and info.filename.startswith("sources/") and info.filename.endswith(".c"):
                data = data.replace(GUARD_LINE, b"")
            zout.writestr(info, data)
    with zipfile.ZipFile(dest) as z:
        names = z.namelist()
    assert not [n for n in names if n.startswith("binaries")], names
    assert "sources/native_common.c" in names
    return dest


@pytest.fixture(scope="module")
def compiled(built_fmus, tmp_path_factory) -> dict:
    """build name -> (compiled FMU, fmpy's verbose build log). All six builds run at once,
    each `python -m fmpy compile --all-warnings --warning-as-error` on a copy without binaries/
    (CMake's make prints every command with VERBOSE=1)."""
    native_dir = built_fmus["RailCar"].parent / "native"
    root = tmp_path_factory.mktemp("fmpy_compile")
    jobs = {**{name: (name, None, False) for name in NATIVE}, **CONTROLS}
    procs = {}
    for build, (name, cflags, unguard) in jobs.items():
        fmu = _source_copy(native_dir / f"{name}.fmu", root / build / f"{name}.fmu", unguard)
        env = {k: v for k, v in os.environ.items() if k not in ("CFLAGS", "CPPFLAGS", "LDFLAGS")}
        env.update(VERBOSE="1", TMPDIR=str(fmu.parent))
        if cflags:
            env["CFLAGS"] = cflags
        procs[build] = (fmu, subprocess.Popen(
            [sys.executable, "-m", "fmpy", "compile", "--all-warnings", "--warning-as-error",
             str(fmu)], cwd=fmu.parent, env=env, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True))
    out = {}
    for build, (fmu, proc) in procs.items():
        log, _ = proc.communicate(timeout=300)
        assert proc.returncode == 0, f"fmpy compile {build} failed:\n{log}"
        out[build] = (fmu, log)
    return out


@pytest.fixture(scope="module")
def shipped(built_fmus) -> dict[str, Path]:
    native_dir = built_fmus["RailCar"].parent / "native"
    return {name: native_dir / f"{name}.fmu" for name in NATIVE}


def _compile_lines(log: str) -> list[str]:
    return [ln for ln in log.splitlines() if " -c " in ln and ln.split()[0].endswith("cc")]


def _link_line(log: str) -> str:
    links = [ln for ln in log.splitlines() if " -shared " in ln]
    assert len(links) == 1, log
    return links[0]


def _objdump(so: bytes, tmp_path: Path, name: str) -> str:
    path = tmp_path / name
    path.write_bytes(so)
    return subprocess.run(["objdump", "-d", str(path)], capture_output=True, text=True,
                          check=True).stdout


@pytest.mark.parametrize("name", NATIVE)
def test_fmpy_compiles_the_listed_sources_into_the_platform_binary(compiled, shipped, name,
                                                                     tmp_path):
    fmu, log = compiled[name]
    model, version = NATIVE[name]
    md = read_model_description(str(fmu))
    assert md.fmiVersion == version
    listed = md.buildConfigurations[0].sourceFileSets[0].sourceFiles
    with zipfile.ZipFile(fmu) as z:
        binaries = [n for n in z.namelist() if n.startswith("binaries/") and not n.endswith("/")]
        so = z.read(f"binaries/{_binary_dir(version)}/{model}.so")
    assert binaries == [f"binaries/{_binary_dir(version)}/{model}.so"]
    compiled_files = sorted(Path(ln.split(" -c ")[1].strip()).name for ln in _compile_lines(log))
    assert compiled_files == sorted(listed) and len(listed) >= 19
    assert so != _shipped_binary(shipped[name], version)           # a new binary: -O3, not -O2
    # bit-identity below rests on this: no fused multiply-add in the x86-64 binary
    assert not FMA.search(_objdump(so, tmp_path, "compiled.so"))


# ------------------------------------------------------------------- what fmpy makes of it

def test_fmpy_drops_the_fmi3_compiler_options_and_libraries(compiled, shipped, tmp_path):
    """FMI 3: buildDescription.xml asks for -ffp-contract=off and libm; fmpy's compile
    lines carry neither (-std=gnu99 from language="C99"), and the binary does not name libm, so a
    host that has not loaded libm cannot open it (a Python host has: fmpy runs it)."""
    fmu, log = compiled["RailCarNative3"]
    with zipfile.ZipFile(fmu) as z:
        xml = z.read("sources/buildDescription.xml").decode()
        so = z.read(f"binaries/{fmpy.platform_tuple}/RailCar.so")
    assert 'compilerOptions="-ffp-contract=off"' in xml and '<Library name="m"' in xml
    sfs = read_model_description(str(fmu)).buildConfigurations[0].sourceFileSets[0]
    assert sfs.language == "C99" and sfs.compilerOptions is None    # not read by fmpy
    for line in _compile_lines(log):
        assert "-std=gnu99" in line and "-O3" in line and "fp-contract" not in line, line
    assert " -lm" not in _link_line(log)
    for ln in _compile_lines(compiled["RailCarNative"][1]):       # FMI 2: no language at all
        assert "-std=" not in ln and "fp-contract" not in ln, ln

    def needed(data: bytes, name: str) -> list[str]:
        path = tmp_path / name
        path.write_bytes(data)
        dyn = subprocess.run(["readelf", "-d", str(path)], capture_output=True, text=True,
                             check=True).stdout
        return re.findall(r"\(NEEDED\)\s+Shared library: \[(.+?)\]", dyn)

    shipped_so = _shipped_binary(shipped["RailCarNative3"], "3.0")
    assert "libm.so.6" in needed(shipped_so, "shipped.so")
    assert "libm.so.6" not in needed(so, "fmpy.so")
    # a plain C host (no libm) opens the shipped binary, not fmpy's
    host = tmp_path / "host"
    (tmp_path / "host.c").write_text(
        "#include <dlfcn.h>\n#include <stdio.h>\n"
        "int main(int argc, char **argv) {\n    (void)argc;\n"
        "    void *h = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);\n"
        "    if (!h) { printf(\"%s\\n\", dlerror()); return 1; }\n"
        "    printf(\"opened\\n\");\n    return dlclose(h);\n}\n")
    subprocess.run(["cc", "-std=c99", "-Wall", "-Werror", str(tmp_path / "host.c"), "-o",
                    str(host), "-ldl"], check=True)
    ok = subprocess.run([str(host), str(tmp_path / "shipped.so")], capture_output=True, text=True)
    bad = subprocess.run([str(host), str(tmp_path / "fmpy.so")], capture_output=True, text=True)
    assert ok.returncode == 0 and ok.stdout == "opened\n", ok.stdout
    assert bad.returncode == 1 and "undefined symbol: " in bad.stdout, bad.stdout
    assert bad.stdout.split("undefined symbol: ")[1].strip() in {"exp", "expm1", "log1p", "pow",
                                                                 "sqrt", "fmod"}   # fmod: the ATO's relay


# ---------------------------------------------------------------- bit for bit: RailCar

@pytest.fixture(scope="module")
def scenarios():
    return {stem: load_scenario(LIBRARY / f"{stem}.toml") for stem in STEMS}


@pytest.fixture(scope="module")
def python_runs(built_fmus, scenarios) -> dict:
    """stem -> the pythonfmu RailCar.fmu's run (the reference, and the estimators' inputs)."""
    with FmuRunner(built_fmus["RailCar"]) as runner:
        return {stem: runner.run(sc) for stem, sc in scenarios.items()}


def _railcar_run(path: Path, scenario):
    """The run, its log with the unzip folder written <FMU> (FMI 3 instantiation names it)."""
    runner = (FmuRunner if read_model_description(str(path)).fmiVersion == "2.0"
              else Fmi3Runner)(path)
    try:
        run = runner.run(scenario)
    finally:
        runner.close()
    return run, [line.replace(str(runner.unzipdir), "<FMU>") for line in run.log]


def _assert_same_signals(a, b, what: str) -> None:
    assert np.array_equal(bits(a.time), bits(b.time)), what
    assert a.signals.keys() == b.signals.keys(), what
    for name in a.signals:
        diff = np.flatnonzero(bits(a.signals[name]) != bits(b.signals[name]))
        assert diff.size == 0, (f"{what}: {name} differs first at row {diff[0]}: "
                                f"{a.signals[name][diff[0]]!r} vs {b.signals[name][diff[0]]!r}")


@pytest.mark.parametrize("stem", STEMS)
@pytest.mark.parametrize("name", ["RailCarNative", "RailCarNative3"])
def test_compiled_railcar_bit_identical(compiled, shipped, python_runs, scenarios, name, stem):
    got, got_log = _railcar_run(compiled[name][0], scenarios[stem])
    ship, ship_log = _railcar_run(shipped[name], scenarios[stem])
    assert len(got.time) > 1000
    _assert_same_signals(ship, got, f"{name} {stem}: compiled vs shipped")
    assert got_log == ship_log
    _assert_same_signals(python_runs[stem], got, f"{name} {stem}: compiled vs pythonfmu")


# ------------------------------------------------------------- bit for bit: the estimator

def _estimator_inputs(run):
    """RailCar's run as the estimator's inputs: row k = the measurements at t_k and the forces
    applied over [t_k, t_k+1] (as tests/fmu_tests/test_native_estimator_fmu.py feeds them)."""
    s = run.signals
    rows = np.column_stack([s["car.traction_force"][1:], s["car.brake_force"][1:],
                            s["sensor.speed"][:-1], s["sensor.position"][:-1],
                            s["sensor.track_speed"][:-1], s["sensor.track_time"][:-1]])
    return rows, run.time[:-1], np.diff(run.time)


def _open(path: Path, unzip_root: Path):
    md = read_model_description(str(path))
    unzipdir = extract(str(path), unzipdir=str(unzip_root / path.parent.name / path.stem))
    if md.fmiVersion == "3.0":
        return Slave3(FmuFile(path.stem, path, _Md3(md), unzipdir), "replay")
    return Slave(FmuFile(path.stem, path, md, unzipdir), "replay")


def _replay(path: Path, unzip_root: Path, parameters: dict, rows, times, steps):
    """Every output (float64 bit patterns, integers) after initialisation and after each step,
    the statuses, and the warnings and worse of the log."""
    with _open(path, unzip_root) as s:
        reals = [n for n in s.fmu_file.names("output") if s._type(n) == "Real"]
        ints = [n for n in s.fmu_file.names("output") if s._type(n) == "Integer"]
        rvr, ivr = [s.fmu_file.vr[n] for n in reals], [s.fmu_file.vr[n] for n in ints]
        in_vr = [s.fmu_file.vr[n] for n in EST_INPUTS]
        s.initialize(parameters)
        out = [list(bits(s.fmu.getReal(rvr))) + list(s.fmu.getInteger(ivr))]
        statuses = []
        for k in range(len(rows)):
            s.fmu.setReal(in_vr, [float(x) for x in rows[k]])
            statuses.append(s.do_step(float(times[k]), float(steps[k])))
            out.append(list(bits(s.fmu.getReal(rvr))) + list(s.fmu.getInteger(ivr)))
        log = [str(m) for m in s.messages if m.status != OK]
    return np.array(out, dtype=np.int64), reals + ints, statuses, log


@pytest.mark.parametrize("stem", STEMS)
@pytest.mark.parametrize("name", ["RailCarEstimatorNative", "RailCarEstimatorNative3"])
def test_compiled_estimator_bit_identical(compiled, shipped, built_fmus, python_runs, scenarios,
                                          name, stem, tmp_path):
    rows, times, steps = _estimator_inputs(python_runs[stem])
    md = read_model_description(str(built_fmus["RailCarEstimator"]))
    own = {v.name for v in md.modelVariables if v.causality == "parameter"}
    params = {n: v for n, v in scenarios[stem].parameters.items() if n in own}
    assert "track.grade_profile" in params
    runs = {key: _replay(path, tmp_path, params, rows, times, steps)
            for key, path in (("compiled", compiled[name][0]), ("shipped", shipped[name]),
                              ("python", built_fmus["RailCarEstimator"]))}
    out, names, statuses, log = runs["compiled"]
    assert statuses == [OK] * len(rows) and len(rows) > 1000
    assert not np.array_equal(out[1], out[-1])                   # the estimates moved
    for key in ("shipped", "python"):
        ref, ref_names, ref_statuses, ref_log = runs[key]
        assert ref_names == names and ref_statuses == statuses and ref_log == log, key
        diff = np.argwhere(ref != out)
        assert diff.size == 0, (f"{name} {stem}: compiled vs {key}: {names[diff[0][1]]} "
                                f"differs first at row {diff[0][0]}")


# ---------------------------------------------------- FMA contraction, and the guard against it

def test_contraction_breaks_bit_identity_and_the_guard_restores_it(compiled, shipped,
                                                                   scenarios, tmp_path):
    """What an aarch64 user's `fmpy compile` would do to sources without the guard (fused
    multiply-adds: GCC's gnu dialect contracts whenever the target has FMA), here with
    CFLAGS=-mfma: the comparison above sees it from the first step. The shipped sources, guard
    included, built the same way have no FMA instruction and are bit-identical."""
    if not re.search(r"^flags\s*:.*\bfma\b", Path("/proc/cpuinfo").read_text(), re.M):
        pytest.skip("this CPU has no FMA: the -mfma control binaries cannot run here")
    fma, guarded = compiled["fma"][0], compiled["fma_guarded"][0]
    assert "-mfma" in _compile_lines(compiled["fma"][1])[0]
    assert "-mfma" in _compile_lines(compiled["fma_guarded"][1])[0]
    with zipfile.ZipFile(fma) as z:
        fma_so = z.read(f"binaries/{fmpy.platform}/RailCar.so")
    with zipfile.ZipFile(guarded) as z:
        guarded_so = z.read(f"binaries/{fmpy.platform}/RailCar.so")
    n_fma = len(FMA.findall(_objdump(fma_so, tmp_path, "fma.so")))
    assert n_fma > 20, n_fma
    assert not FMA.search(_objdump(guarded_so, tmp_path, "guarded.so"))
    sc = scenarios["steep_grades"]
    ship = _railcar_run(shipped["RailCarNative"], sc)[0]
    contracted = _railcar_run(fma, sc)[0]
    assert len(contracted.time) == len(ship.time) > 1000
    first = {n: np.flatnonzero(bits(ship.signals[n]) != bits(contracted.signals[n]))
             for n in ship.signals}
    differ = sorted(n for n, rows in first.items() if rows.size)
    assert "car.speed" in differ and len(differ) >= 10, differ
    assert min(first[n][0] for n in differ) <= 5        # measured: car.position at row 1
    # rounding, not a wrong model: measured 1.8e-15 m/s and 1.1e-13 m at most
    for n in ("car.speed", "car.position"):
        assert np.max(np.abs(ship.signals[n] - contracted.signals[n])) < 1e-9, n
    _assert_same_signals(ship, _railcar_run(guarded, sc)[0], "guarded -mfma build vs shipped")
