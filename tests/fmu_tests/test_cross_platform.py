"""The native FMUs on every desktop (issue 28): each of the four native FMUs of the session build
(RailCarNative, RailCarEstimatorNative: FMI 2.0; RailCarNative3, RailCarEstimatorNative3: FMI
3.0) carries a binary for every platform of ``fmu_src.build.toolchain.TARGETS`` (linux x86-64,
Windows x86-64, linux aarch64) whose compiler this machine has, and its ``sources/`` alone
compile for each of them with all warnings as errors.

- sources/ is unpacked into a fresh folder and compiled with nothing else: no -I to fmpy's
  headers, no define; the Windows DLL needs only what Windows ships (KERNEL32.dll, msvcrt.dll);
- the aarch64 binary runs under qemu-aarch64 through the C host tests/fmu_cases/csv_host.c
  (cross-compiled for aarch64) on one library scenario, bit-identical to the x86-64 binary;
- the Windows DLL runs under Wine through tests/fmu_cases/step_host.c (built with mingw-w64),
  with Windows resource locations, against the Linux binary through the same host: bit-identical
  but for one output within one unit in the last place (ULP_OUTPUTS).

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
import zipfile
from pathlib import Path

import numpy as np
import pytest

from csv_host_cases import NativeFmu, bits, compile_host, run_host
from fmu_src.build import native_fmi3, toolchain
from fmu_src.build.toolchain import LINUX_AARCH64, TARGETS, WINDOWS_X86_64
from test_native_csv_host import RailCarRuns, railcar_case, replay_inputs

NATIVE = {  # native FMU -> (modelIdentifier, FMI version)
    "RailCarNative": ("RailCar", 2),
    "RailCarEstimatorNative": ("RailCarEstimator", 2),
    "RailCarNative3": ("RailCar", 3),
    "RailCarEstimatorNative3": ("RailCarEstimator", 3),
}
STRICT = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-ffp-contract=off",
          "-shared", "-Wl,--no-undefined"]
WINDOWS_DLLS = {"kernel32.dll", "msvcrt.dll"}      # shipped with every Windows
AARCH64_SYSROOT = Path("/usr/aarch64-linux-gnu")    # Debian's libc6-arm64-cross
QEMU = "qemu-aarch64"
SCENARIO = "steep_grades"


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

@pytest.mark.parametrize("target", TARGETS, ids=[t.tuple for t in TARGETS])
@pytest.mark.parametrize("name", NATIVE)
def test_sources_alone_compile_with_warnings_as_errors(native_dir, name, target, tmp_path):
    cc = compiler_or_skip(target)
    src = tmp_path / "sources"
    with zipfile.ZipFile(native_dir / f"{name}.fmu") as z:
        for n in z.namelist():
            if n.startswith("sources/") and not n.endswith("/"):
                z.extract(n, tmp_path)
    out = tmp_path / f"{NATIVE[name][0]}{target.extension}"
    cmd = [*cc, *STRICT, *target.flags, "-I", str(src), *sorted(str(p) for p in src.glob("*.c")),
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


# ------------------------------------------------------------- the aarch64 binary, under qemu

@pytest.fixture(scope="module")
def aarch64_host(tmp_path_factory) -> Path:
    """csv_host cross-compiled for aarch64, behind a script that runs it under qemu-aarch64
    with the aarch64 C library (run_host calls it like the native host)."""
    cc = compiler_or_skip(LINUX_AARCH64)
    if shutil.which(QEMU) is None:
        pytest.skip(f"not checked on this machine: {QEMU} not found (apt-get install qemu-user)")
    if not (AARCH64_SYSROOT / "lib").is_dir():
        pytest.skip(f"not checked on this machine: no {AARCH64_SYSROOT}/lib "
                    "(apt-get install libc6-arm64-cross)")
    folder = tmp_path_factory.mktemp("csv_host_aarch64")
    binary = compile_host(cc, native_fmi3.fmi_headers(), folder / "csv_host")
    assert "aarch64" in subprocess.run(["file", str(binary)], capture_output=True,
                                       text=True).stdout
    wrapper = folder / "csv_host_qemu"
    wrapper.write_text(f'#!/bin/sh\nexec {QEMU} -L {AARCH64_SYSROOT} {binary} "$@"\n')
    wrapper.chmod(0o755)
    return wrapper


@pytest.fixture(scope="module")
def x86_host(tmp_path_factory) -> Path:
    cc = toolchain.find_compiler()
    assert cc, "no C compiler"
    return compile_host(cc, native_fmi3.fmi_headers(),
                        tmp_path_factory.mktemp("csv_host") / "csv_host")


@pytest.mark.parametrize("version", [2, 3])
def test_aarch64_binary_under_qemu_is_bit_identical_to_x86_64(aarch64_host, x86_host, native_dir,
                                                              built_fmus, tmp_path, version):
    """One library scenario, closed-loop inputs of the pythonfmu RailCar replayed through the
    x86-64 and the aarch64 binary of the same FMU: every output at every row, bit for bit (the
    sources are compiled with -ffp-contract=off; aarch64 would fuse a*b+c otherwise)."""
    name = "RailCarNative" if version == 2 else "RailCarNative3"
    fmu = NativeFmu.unpack(native_dir / f"{name}.fmu", tmp_path / "fmu")
    arm = dataclasses.replace(fmu, binary=tmp_path / "fmu" / binary_name(LINUX_AARCH64, name))
    assert arm.binary.is_file()
    runs = RailCarRuns(built_fmus["RailCar"])
    try:
        sc, ref = runs(SCENARIO)
    finally:
        runs.runner.close()
    times, rows = replay_inputs(sc, ref)
    params, inputs = railcar_case(tmp_path, fmu, sc, times, rows)
    got = {}
    for label, host, which in (("x86_64", x86_host, fmu), ("aarch64", aarch64_host, arm)):
        run = run_host(host, which, params, inputs, tmp_path / f"{label}.csv", fmu.outputs,
                       step=sc.step_s, stop=sc.duration_s, timeout=600)
        assert run.returncode == 0, f"{label}: {run.stderr}"
        assert len(run.time) == len(times) + 1
        got[label] = run
    assert np.array_equal(bits(got["x86_64"].time), bits(got["aarch64"].time))
    differing = [n for n in fmu.outputs
                 if not np.array_equal(bits(got["x86_64"].columns[n]),
                                       bits(got["aarch64"].columns[n]))]
    assert differing == [], {n: float(np.max(np.abs(got["x86_64"].columns[n]
                                                     - got["aarch64"].columns[n])))
                             for n in differing}


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


# ------------------------------------------------------------- the Windows binary, under Wine

STEP_HOST = Path(__file__).resolve().parents[1] / "fmu_cases" / "step_host.c"
HOST_FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]
# constant inputs (traction_force_demand, wind_speed), 600 steps of 0.1 s: the car accelerates
# and the estimator runs through its start-up
STEP_INPUTS = {"traction_force_demand": 60000.0, "wind_speed": 3.5}
# Under Wine one output is not bit-identical: est.mass_std (sqrt(variance) / (g theta0^2)),
# from step 110 on, by at most one unit in the last place (largest difference 2.2e-16, 1.8e-16
# relative, measured here); every other output is bit-identical. The DLL carries mingw-w64's
# own maths library (-static): its pow, exp, expm1 and log1p are not glibc's and may round
# differently in the last bit (sqrt is not the cause: inlined with -fno-math-errno, the same
# difference remains).
ULP_OUTPUTS = {"est.mass_std": 4.5e-16}     # largest relative difference allowed


def _wine() -> str | None:
    for candidate in ("wine64", "wine"):
        if shutil.which(candidate):
            return shutil.which(candidate)
    return "/usr/lib/wine/wine64" if Path("/usr/lib/wine/wine64").is_file() else None


def _windows_path(p: Path) -> str:
    """Wine's drive Z: is the root of the Linux file system."""
    return "Z:" + str(p).replace("/", "\\")


@pytest.fixture(scope="module")
def step_hosts(tmp_path_factory) -> dict:
    """step_host built for Linux x86-64 and for Windows (mingw-w64), and the Wine command."""
    compiler_or_skip(WINDOWS_X86_64)
    wine = _wine()
    if wine is None:
        pytest.skip("not checked on this machine: no Wine (apt-get install wine64)")
    folder = tmp_path_factory.mktemp("step_host")
    headers = native_fmi3.fmi_headers()
    hosts = {}
    for label, cc, out, libs in (("linux", toolchain.find_compiler(), folder / "step_host", ["-ldl"]),
                                 ("windows", [WINDOWS_X86_64.compiler], folder / "step_host.exe", [])):
        cmd = [*cc, *HOST_FLAGS, "-I", str(headers), str(STEP_HOST), "-o", str(out), *libs]
        proc = subprocess.run(cmd, capture_output=True, text=True)
        assert proc.returncode == 0, f"{' '.join(cmd)}\n{proc.stderr}"
        hosts[label] = out
    env = dict(os.environ, WINEPREFIX=str(folder / "wineprefix"), WINEDEBUG="-all")
    return {"hosts": hosts, "wine": wine, "env": env}


def _step_rows(stdout: str) -> np.ndarray:
    rows = [line.split()[1:] for line in stdout.replace("\r", "").splitlines()]
    return np.array([[int(x, 16) for x in r] for r in rows], dtype=np.uint64).view(np.float64)


@pytest.mark.parametrize("version", [2, 3])
def test_windows_binary_under_wine_matches_linux(step_hosts, native_dir, tmp_path, version):
    """The win64 / x86_64-windows RailCar DLL, loaded by a Windows host under Wine with a
    Windows resource location (FMI 2: file:///Z:/..., FMI 3: Z:\\...\\), against the Linux
    binary through the same host built for Linux: 601 rows of every real output."""
    from fmpy import read_model_description
    name = "RailCarNative" if version == 2 else "RailCarNative3"
    fmu_path = native_dir / f"{name}.fmu"
    md = read_model_description(str(fmu_path))
    token = md.guid if version == 2 else md.instantiationToken
    with zipfile.ZipFile(fmu_path) as z:
        z.extractall(tmp_path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    outputs = [v.name for v in md.modelVariables
               if v.causality == "output" and v.type in ("Real", "Float64")]
    args = ["0.1", "600", *[f"{vr[n]}={x!r}" for n, x in STEP_INPUTS.items()], "--",
            *[str(vr[n]) for n in outputs]]
    kind = f"fmi{version}"
    resources = tmp_path / "resources"
    linux_resources = resources.as_uri() if version == 2 else f"{resources}/"
    windows_resources = ("file:///" + _windows_path(resources).replace("\\", "/") if version == 2
                         else _windows_path(resources) + "\\")
    runs = {
        "linux": [str(step_hosts["hosts"]["linux"]), kind,
                  str(tmp_path / binary_name(toolchain.LINUX_X86_64, name)), linux_resources,
                  token, *args],
        "windows": [step_hosts["wine"], str(step_hosts["hosts"]["windows"]), kind,
                    _windows_path(tmp_path / binary_name(WINDOWS_X86_64, name)),
                    windows_resources, token, *args],
    }
    got = {}
    for label, cmd in runs.items():
        proc = subprocess.run(cmd, capture_output=True, text=True, env=step_hosts["env"],
                              timeout=300)
        assert proc.returncode == 0, f"{label}: {' '.join(cmd)}\n{proc.stderr}"
        got[label] = _step_rows(proc.stdout)
        assert got[label].shape == (601, len(outputs)), label
    linux, windows = got["linux"], got["windows"]
    assert linux[-1, outputs.index("car.speed")] > 10.0          # the car did move
    for j, output in enumerate(outputs):
        same = np.array_equal(linux[:, j].view(np.int64), windows[:, j].view(np.int64))
        if output in ULP_OUTPUTS:
            rel = np.max(np.abs(linux[:, j] - windows[:, j]) / np.abs(linux[:, j]))
            assert rel <= ULP_OUTPUTS[output], (output, rel)
        else:
            assert same, (output, np.max(np.abs(linux[:, j] - windows[:, j])))
