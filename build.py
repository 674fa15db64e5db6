"""Build dist/RailCar.fmu and dist/RailCarEstimator.fmu and validate them.

    python build.py [--dest dist]

Each FMU is built by pythonfmu in a subprocess (a Python process caches the FMU's modules, so
building and loading in one process can run stale code). The model description is then
completed from ``fmu_src/variables.py``: UnitDefinitions and ``unit``/``min``/``max`` on every
Real, a DefaultExperiment, and a GUID derived from the sources (same sources => same GUID).
The build fails unless ``fmpy.validation.validate_fmu`` reports no problem.
"""
from __future__ import annotations

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

from fmu_src.variables import UNITS, variables_for  # noqa: E402

FMUS = {"RailCar": "fmu_src/railcar.py", "RailCarEstimator": "fmu_src/railcar_estimator.py"}
PROJECT_FILES = ["fmu_src", "models", "scenarios/profiles"]
DEFAULT_EXPERIMENT = {"startTime": "0", "stopTime": "200", "stepSize": "0.1"}


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

    for sv in root.find("ModelVariables"):
        var = table[sv.get("name")]
        real = sv.find("Real")
        if real is None:
            continue
        if var.unit:
            real.set("unit", var.unit)
        if var.min is not None:
            real.set("min", repr(float(var.min)))
        if var.max is not None:
            real.set("max", repr(float(var.max)))
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def rewrite_fmu(path: Path, model_name: str) -> None:
    tmp = path.with_suffix(".tmp")
    with zipfile.ZipFile(path) as src, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as dst:
        for item in src.infolist():
            data = src.read(item.filename)
            if item.filename == "modelDescription.xml":
                data = complete_model_description(data, model_name)
            dst.writestr(item, data)
    tmp.replace(path)


def build_one(model_name: str, script: str, dest: Path) -> Path:
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
    rewrite_fmu(target, model_name)
    return target


def validate(path: Path) -> list[str]:
    from fmpy.validation import validate_fmu
    return list(validate_fmu(str(path)))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dest", default=str(ROOT / "dist"), help="output folder (default: dist/)")
    args = ap.parse_args(argv)
    dest = Path(args.dest)
    failed = False
    for name, script in FMUS.items():
        path = build_one(name, script, dest)
        problems = validate(path)
        if problems:
            failed = True
            print(f"{path}: fmpy.validation found {len(problems)} problem(s):")
            for p in problems:
                print(f"  - {p}")
        else:
            print(f"built {path} (validate_fmu: no problems)")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
