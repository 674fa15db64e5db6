"""Freeze the value references of every FMU the build makes into tests/fmu_tests/value_references.json.

    python -m fmu_src.build.value_references [--dist DIR] [--allow-breaking]

Value references are a contract with our users' models (fmu_src/variables.py): a saved system,
an SSP file or a user's master addresses a variable by its value reference, so a build whose
references moved breaks them silently. ``tests/fmu_tests/test_value_references.py`` compares the built FMUs'
modelDescription.xml with the frozen file; this script is the one explicit way to change that
file. It builds the FMUs into a temporary folder (``build.py``, as the tests' session build
does), or reads an existing build with ``--dist``, prints every added, removed and changed
entry and rewrites the file.

The only allowed change is a documented, appended addition (a new variable after the existing
ones of its FMU, with a CHANGELOG entry). Appending moves the FMI 3 FMUs' ``time`` variable,
which sits after the table (``fmu_src/build/model_description.py``): that move is expected and reported
as such. A removed or changed entry is a breaking change: the script refuses to write it
unless ``--allow-breaking`` is given.

The reading and comparing functions here are shared with the test.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .dist import run_build
from .toolchain import ROOT

FROZEN = ROOT / "tests" / "fmu_tests" / "value_references.json"
COMMAND = "python -m fmu_src.build.value_references"

FMU_FILES = {   # every FMU build.py makes: name -> path inside the build folder
    "RailCar": "RailCar.fmu",
    "RailCarEstimator": "RailCarEstimator.fmu",
    "AtoController": "AtoController.fmu",
    "RailCarNative": "native/RailCarNative.fmu",
    "RailCarEstimatorNative": "native/RailCarEstimatorNative.fmu",
    "RailCarNative3": "native/RailCarNative3.fmu",
    "RailCarEstimatorNative3": "native/RailCarEstimatorNative3.fmu",
    "AtoControllerNative": "native/AtoControllerNative.fmu",
    "AtoControllerNative3": "native/AtoControllerNative3.fmu",
}
FIELDS = ("vr", "causality", "variability", "type", "unit")
"""What is frozen of each variable (``unit`` is None where the variable has none)."""

INDEPENDENT = "independent"
"""The causality of FMI 3's ``time``: its value reference is the table's length, so it moves
when a variable is appended; it must stay after every other variable of its FMU."""

FMI2_TYPES = ("Real", "Integer", "Boolean", "String", "Enumeration")


def _variability(type_name: str, fmi_version: str, given: str | None) -> str:
    """The variability as written, else the standard's default (FMI 2: continuous; FMI 3:
    continuous for floats, discrete for the rest)."""
    if given is not None:
        return given
    if fmi_version.startswith("2") or type_name.startswith("Float"):
        return "continuous"
    return "discrete"


def read_model_description(fmu: Path) -> dict[str, dict]:
    """name -> {vr, causality, variability, type, unit} of one FMU's modelDescription.xml
    (FMI 2.0 or 3.0), in value-reference order."""
    with zipfile.ZipFile(fmu) as z:
        root = ET.fromstring(z.read("modelDescription.xml"))
    version = root.get("fmiVersion", "")
    variables = {}
    for sv in root.find("ModelVariables"):
        if version.startswith("2"):   # <ScalarVariable ...><Real unit=.../></ScalarVariable>
            typed = next(child for child in sv if child.tag in FMI2_TYPES)
        else:                         # <Float64 name=... unit=.../>
            typed = sv
        name = sv.get("name")
        if name in variables:
            raise ValueError(f"{fmu}: variable {name!r} appears twice in modelDescription.xml")
        variables[name] = {
            "vr": int(sv.get("valueReference")),
            "causality": sv.get("causality", "local"),
            "variability": _variability(typed.tag, version, sv.get("variability")),
            "type": typed.tag,
            "unit": typed.get("unit"),
        }
    return dict(sorted(variables.items(), key=lambda item: item[1]["vr"]))


def read_build(dist: Path) -> dict[str, dict[str, dict]]:
    """FMU name -> its variables, for every FMU of a build folder (``build.py --dest dist``);
    an FMU there that FMU_FILES does not name is an error (every built FMU is frozen)."""
    missing = [str(dist / rel) for rel in FMU_FILES.values() if not (dist / rel).is_file()]
    if missing:
        raise FileNotFoundError(f"the build in {dist} lacks {', '.join(missing)}")
    unknown = sorted({p.relative_to(dist).as_posix() for p in dist.rglob("*.fmu")} - set(FMU_FILES.values()))
    if unknown:
        raise ValueError(f"the build in {dist} makes {', '.join(unknown)}, which {Path(__file__).name}'s "
                         "FMU_FILES does not name: add it there and freeze its value references")
    return {name: read_model_description(dist / rel) for name, rel in FMU_FILES.items()}


def load_frozen(path: Path = FROZEN) -> dict[str, dict[str, dict]]:
    data = json.loads(path.read_text(encoding="utf-8"))
    return {name: variables for name, variables in data.items() if not name.startswith("_")}


def dump_frozen(build: dict[str, dict[str, dict]], path: Path = FROZEN) -> None:
    """One variable a line (reviewable diffs), variables in value-reference order."""
    lines = ["{", f'  "_about": {json.dumps(f"frozen value references of every built FMU; change only with: {COMMAND}")},']
    for i, (fmu, variables) in enumerate(build.items()):
        lines.append(f"  {json.dumps(fmu)}: {{")
        rows = [f"    {json.dumps(name)}: {json.dumps({k: entry[k] for k in FIELDS})}"
                for name, entry in variables.items()]
        lines.append(",\n".join(rows))
        lines.append("  }" + ("," if i < len(build) - 1 else ""))
    lines.append("}")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _describe(entry: dict) -> str:
    return ", ".join(f"{k} {entry[k]}" for k in FIELDS)


def compare(frozen: dict[str, dict[str, dict]], built: dict[str, dict[str, dict]]
            ) -> tuple[list[str], list[str], list[str]]:
    """(breaking, added, moved): one line per variable, naming the FMU and the variable.

    breaking: a frozen FMU or variable is gone, or one of its fields changed (for ``time``
    everything but the value reference, which must stay after every other variable);
    added: a built variable not frozen yet, appended (its vr after every frozen one) or
    breaking if it was inserted; moved: ``time`` whose value reference moved as expected."""
    breaking, added, moved = [], [], []
    for fmu in frozen.keys() - built.keys():
        breaking.append(f"{fmu}: the FMU is no longer built")
    for fmu in built.keys() - frozen.keys():
        added.append(f"{fmu}: a new FMU ({len(built[fmu])} variables)")
    for fmu in [f for f in built if f in frozen]:
        old, new = frozen[fmu], built[fmu]
        last_table_vr = max((e["vr"] for e in new.values() if e["causality"] != INDEPENDENT), default=-1)
        last_frozen_vr = max((e["vr"] for e in old.values() if e["causality"] != INDEPENDENT), default=-1)
        for name, was in old.items():
            if name not in new:
                breaking.append(f"{fmu}: {name} removed (was {_describe(was)})")
                continue
            now = new[name]
            changed = [k for k in FIELDS if was[k] != now[k]]
            if was["causality"] == INDEPENDENT and now["causality"] == INDEPENDENT and changed == ["vr"]:
                if now["vr"] > last_table_vr:
                    moved.append(f"{fmu}: {name} value reference {was['vr']} -> {now['vr']} "
                                 "(expected: it sits after the table)")
                    continue
            if changed:
                breaking.append(f"{fmu}: {name} " + "; ".join(f"{k} {was[k]!r} -> {now[k]!r}" for k in changed))
        for name, now in new.items():
            if name in old:
                continue
            if now["vr"] <= last_frozen_vr and now["causality"] != INDEPENDENT:
                breaking.append(f"{fmu}: {name} added at value reference {now['vr']}, inside the frozen "
                                f"range (up to {last_frozen_vr}): a new variable must be appended")
            else:
                added.append(f"{fmu}: {name} added ({_describe(now)})")
    return sorted(breaking), sorted(added), sorted(moved)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dist", type=Path, help="read this existing build folder instead of building")
    ap.add_argument("--allow-breaking", action="store_true",
                    help="write removed or changed entries too (breaks users' models: say so in the CHANGELOG)")
    args = ap.parse_args(argv)
    frozen = load_frozen() if FROZEN.is_file() else {}
    if args.dist is not None:
        built = read_build(args.dist)
    else:
        with tempfile.TemporaryDirectory() as tmp:
            dist = Path(tmp) / "dist"
            run_build(dist)                 # build.py in a subprocess: the current sources
            built = read_build(dist)
    breaking, added, moved = compare(frozen, built)
    for label, lines in (("BREAKING", breaking), ("added", added), ("moved", moved)):
        for line in lines:
            print(f"{label}: {line}")
    if breaking and not args.allow_breaking:
        print(f"not written: {len(breaking)} breaking change(s) above; a value reference is a contract "
              "with users' models. Append new variables instead, or rerun with --allow-breaking and "
              "document the break in CHANGELOG.md.", file=sys.stderr)
        return 1
    if not (breaking or added or moved):
        print(f"{FROZEN}: unchanged")
        return 0
    dump_frozen(built)
    print(f"wrote {FROZEN}: {len(added)} added, {len(moved)} moved, {len(breaking)} breaking")
    return 0


if __name__ == "__main__":
    sys.exit(main())
