"""Build dist/RailCar.fmu, dist/RailCarEstimator.fmu, dist/AtoController.fmu and the native FMUs; validate them.

    python build.py [--dest dist] [--pythonfmu-binary] [--no-native]

Each FMU is built by pythonfmu in a subprocess (a Python process caches the FMU's modules, so
building and loading in one process can run stale code). The model description is then
completed from ``fmu_src/variables.py``: UnitDefinitions and ``unit``/``min``/``max`` on every
Real, a DefaultExperiment, and a GUID derived from the sources (same sources => same GUID).

The Linux binary pythonfmu ships (``binaries/linux64/<model>.so``) is replaced by ours, compiled
here from ``fmu_src/c/`` (C99, the Python C API, FMI 2 headers from fmpy): it reports errors as
fmi2Error instead of crashing the host after fmi2Fatal. Without a C compiler (or with
``--pythonfmu-binary``) pythonfmu's binary stays, with a loud warning. The win64 DLL is always
pythonfmu's (it cannot be built or tested here).
With a C compiler the native FMUs (no Python at run time, docs/native_fmus.md) are built beside
them into ``dist/native/``: RailCarNative.fmu and RailCarEstimatorNative.fmu (FMI 2.0) and
RailCarNative3.fmu and RailCarEstimatorNative3.fmu (FMI 3.0), from the C model core (``fmu_src/native.py``,
``fmu_src/native_fmi3.py``); ``--no-native`` skips them.
The build fails unless ``fmpy.validation.validate_fmu`` reports no problem for every FMU.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

from fmu_src.variables import ATO, UNITS, variables_for  # noqa: E402

FMUS = {"RailCar": "fmu_src/railcar.py", "RailCarEstimator": "fmu_src/railcar_estimator.py",
        "AtoController": "fmu_src/ato_controller.py"}
PROJECT_FILES = ["fmu_src", "models", "scenarios/profiles"]
DEFAULT_EXPERIMENT = {"startTime": "0", "stopTime": "200", "stepSize": "0.1"}

# Our FMI 2 binary: sources, flags, and the marker string it carries (tests look for it).
C_SOURCES = ["fmu_src/c/fmi2_glue.c", "fmu_src/c/glue_common.c", "fmu_src/c/pyslave.c"]
C_FLAGS = ["-std=c99", "-Wall", "-Wextra", "-Werror", "-O2", "-fPIC", "-shared",
           "-fvisibility=hidden", "-pthread"]
BINARY_MARKER = b"railcar-fmu fmi2 binary 1"
LINUX_BINARY = "binaries/linux64/{model}.so"


def source_files() -> list[Path]:
    files = []
    for folder in PROJECT_FILES:
        files += [p for p in sorted((ROOT / folder).rglob("*")) if p.is_file() and "__pycache__" not in p.parts]
    return files


def source_guid(model_name: str) -> str:
    """A GUID from the model name, pythonfmu's version and every bundled source file."""
    import pythonfmu
    h = hashlib.sha256(f"{model_name}|pythonfmu {pythonfmu.__version__}".encode())
    for p in source_files():
        h.update(str(p.relative_to(ROOT)).encode())
        h.update(p.read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16], version=5)) + "}"


def complete_model_description(xml: bytes, model_name: str) -> bytes:
    """Units, bounds, DefaultExperiment and GUID, from the variable table."""
    root = ET.fromstring(xml)
    root.set("guid", source_guid(model_name))
    table = {v.name: v for v in variables_for(model_name)}

    used_units = sorted({v.unit for v in table.values() if v.unit and v.type == "Real"})
    unit_defs = ET.Element("UnitDefinitions")
    for name in used_units:
        exps, factor = UNITS[name]
        unit = ET.SubElement(unit_defs, "Unit", name=name)
        base = {k: str(e) for k, e in exps.items()}
        if factor != 1.0:
            base["factor"] = repr(factor)
        ET.SubElement(unit, "BaseUnit", base)
    children = list(root)
    cosim_index = [i for i, c in enumerate(children) if c.tag == "CoSimulation"][0]
    root.insert(cosim_index + 1, unit_defs)

    for old in root.findall("DefaultExperiment"):
        root.remove(old)
    children = list(root)
    mv_index = [i for i, c in enumerate(children) if c.tag == "ModelVariables"][0]
    root.insert(mv_index, ET.Element("DefaultExperiment", DEFAULT_EXPERIMENT))

    calculated = []
    for index, sv in enumerate(root.find("ModelVariables"), start=1):
        var = table[sv.get("name")]
        if var.causality == "output" and var.initial == "calculated":
            calculated.append(index)
        real = sv.find("Real")
        if real is None:
            continue
        if real.get("start") is not None:    # pythonfmu writes 16 digits: repr round-trips
            real.set("start", repr(float(var.start)))
        if var.unit:
            real.set("unit", var.unit)
        if var.min is not None:
            real.set("min", repr(float(var.min)))
        if var.max is not None:
            real.set("max", repr(float(var.max)))
    structure = root.find("ModelStructure")
    if model_name == ATO:   # a command is computed in doStep from the inputs at its start and held
        for unknown in structure.find("Outputs"):   # for the next step: no direct feedthrough, so
            unknown.set("dependencies", "")          # a loop through RailCar is no algebraic loop
    if calculated:      # FMI 2.0 section 2.2.8: every calculated output is an initial unknown
        unknowns = ET.SubElement(structure, "InitialUnknowns")
        for index in calculated:
            ET.SubElement(unknowns, "Unknown", index=str(index))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def _warn(message: str) -> None:
    bar = "!" * 78
    print(f"{bar}\nWARNING: {message}\n{bar}", file=sys.stderr)
    print(f"WARNING: {message}")


def find_compiler() -> list[str] | None:
    """$CC, else the compiler Python was built with, else cc/gcc/clang; None if there is none."""
    candidates = [os.environ.get("CC"), sysconfig.get_config_var("CC"), "cc", "gcc", "clang"]
    for cc in candidates:
        cmd = shlex.split(cc) if cc else []
        if cmd and shutil.which(cmd[0]):
            return cmd
    return None


def fmi2_headers() -> Path:
    """The FMI 2.0 headers fmpy ships (fmpy/c-code/fmi2Functions.h ...)."""
    import fmpy
    folder = Path(fmpy.__file__).resolve().parent / "c-code"
    if not (folder / "fmi2Functions.h").is_file():
        raise SystemExit(f"FMI 2 headers not found in {folder} (is fmpy installed?)")
    return folder


def compile_binary(out_dir: Path) -> Path | None:
    """Compile our FMI 2 binary for linux64 into ``out_dir``; None (with a warning) when it
    cannot be built here, so that pythonfmu's binary stays. A compiler error fails the build."""
    if not (sys.platform.startswith("linux") and platform.machine() in ("x86_64", "AMD64")):
        _warn(f"our FMI 2 binary is built for linux64 only (this is {sys.platform}/"
              f"{platform.machine()}): the FMUs keep pythonfmu's binary, which crashes the host "
              "after an initialisation error (see README, Limits)")
        return None
    cc = find_compiler()
    if cc is None:
        _warn("no C compiler found (set CC or install gcc): the FMUs keep pythonfmu's binary, "
              "which reports errors as fmi2Fatal and crashes the host when such an instance is "
              "freed (see README, Limits)")
        return None
    out = out_dir / "fmi2_python.so"
    cmd = [*cc, *C_FLAGS, "-I", sysconfig.get_paths()["include"], "-I", str(fmi2_headers()),
           *[str(ROOT / s) for s in C_SOURCES], "-o", str(out)]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise SystemExit(f"compiling the FMI 2 binary failed:\n{shlex.join(cmd)}\n"
                         f"{proc.stdout}{proc.stderr}")
    if BINARY_MARKER not in out.read_bytes():
        raise SystemExit(f"{out}: the compiled binary does not carry its marker {BINARY_MARKER!r}")
    return out


def rewrite_fmu(path: Path, model_name: str, binary: Path | None = None) -> None:
    """Complete the model description; swap in our linux64 binary; drop our C sources."""
    tmp = path.with_suffix(".tmp")
    linux_binary = LINUX_BINARY.format(model=model_name)
    swapped = False
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            if item.filename.startswith("resources/fmu_src/c/"):
                continue                     # compiled into the binary, not needed at run time
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = complete_model_description(data, model_name)
            elif item.filename == linux_binary and binary is not None:
                data = binary.read_bytes()
                swapped = True
            dst.writestr(item, data)
    if binary is not None and not swapped:
        tmp.unlink()
        raise SystemExit(f"{path}: pythonfmu wrote no {linux_binary} to replace")
    tmp.replace(path)


def build_one(model_name: str, script: str, dest: Path, binary: Path | None = None) -> Path:
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    with tempfile.TemporaryDirectory() as out:
        cmd = [sys.executable, "-m", "pythonfmu", "build", "-f", script, "-d", out, *PROJECT_FILES]
        proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"pythonfmu build of {model_name} failed:\n{proc.stdout}\n{proc.stderr}")
        built = Path(out) / f"{model_name}.fmu"
        dest.mkdir(parents=True, exist_ok=True)
        target = dest / f"{model_name}.fmu"
        target.write_bytes(built.read_bytes())
    rewrite_fmu(target, model_name, binary)
    return target


def validate(path: Path) -> list[str]:
    from fmpy.validation import validate_fmu
    return list(validate_fmu(str(path)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dest", default=str(ROOT / "dist"), help="output folder (default: dist/)")
    ap.add_argument("--pythonfmu-binary", action="store_true",
                    help="keep pythonfmu's linux64 binary instead of compiling ours (for comparisons)")
    ap.add_argument("--no-native", action="store_true",
                    help="skip the native FMUs (dist/native/, built from the C model core)")
    args = ap.parse_args(argv)
    dest = Path(args.dest)
    failed = False
    with tempfile.TemporaryDirectory() as tmp:
        if args.pythonfmu_binary:
            _warn("--pythonfmu-binary: the FMUs keep pythonfmu's linux64 binary (fmi2Fatal on any "
                  "Python exception; the host crashes when such an instance is freed)")
            binary = None
        else:
            binary = compile_binary(Path(tmp))
        which = ("our FMI 2 binary (fmu_src/c)" if binary is not None
                 else "pythonfmu's binary (WARNING: see above)")
        built = {}
        for name, script in FMUS.items():
            path = built[name] = build_one(name, script, dest, binary)
            failed |= not report(path, validate(path), f"linux64: {which}")
        if binary is not None and not args.no_native:
            from fmu_src import native, native_fmi3
            for path in (native.build_native_fmu(dest / "native", built["RailCar"]),
                         native.build_native_estimator_fmu(dest / "native", built["RailCarEstimator"]),
                         native_fmi3.build_native3_fmu(dest / "native", built["RailCar"]),
                         native_fmi3.build_native3_estimator_fmu(dest / "native",
                                                                 built["RailCarEstimator"])):
                failed |= not report(path, validate(path), "native: no Python at run time")
    return 1 if failed else 0


def report(path: Path, problems: list[str], what: str) -> bool:
    """Print the FMU's validation; True when it has no problem."""
    if problems:
        print(f"{path}: fmpy.validation found {len(problems)} problem(s):")
        for p in problems:
            print(f"  - {p}")
        return False
    print(f"built {path} (validate_fmu: no problems; {what})")
    return True


if __name__ == "__main__":
    sys.exit(main())
