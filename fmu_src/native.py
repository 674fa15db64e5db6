"""The native RailCar FMU (issue 18): the C core behind our FMI 2.0 glue, no Python at run time.

    python -m fmu_src.native            write fmu_src/c/native_railcar_table.h
    python -m fmu_src.native --check    exit 1 if that header is out of date
    python -m fmu_src.native --build D  build D/RailCarNative.fmu

The header is generated from the one variable table (``fmu_src/variables.py``) and from the Python
chain's own configuration path, so that the C backend (``fmu_src/c/native_railcar.c``) cannot
drift from the pythonfmu FMU:

- the RailCar variables by value reference (= their order in ``variables_for("RailCar")``):
  name, type, causality, variability, start value;
- for every number of ``models.compiled._config_values`` (the flat configuration the C core's
  ``rc_chain_config_from_values`` reads), the parameter it comes from, or the start time, or the
  constant it always is. This is found by construction, not written by hand: each parameter is
  set to a marker value, ``fmu_src.adapter.chain_config`` + ``_config_values`` are run, and the
  one index that changes must hold the marker itself; every index must be explained;
- the inputs in ``RailCarChain.do_step``'s order and the outputs in ``OUTPUT_NAMES`` order.

``build_native_fmu(dest)`` compiles the glue, the backend and ``models/core/*.c`` into
``binaries/linux64/RailCar.so`` and zips ``RailCarNative.fmu``: the modelDescription.xml of the
pythonfmu ``RailCar.fmu`` (same modelIdentifier, variables and value references) with a new GUID,
``needsExecutionTool="false"``, and its C sources under ``sources/`` (listed in SourceFiles).
"""
from __future__ import annotations

import argparse
import hashlib
import importlib.util
import math
import shlex
import subprocess
import sys
import tempfile
import uuid
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

from .adapter import chain_config
from .variables import RAILCAR, variables_for

ROOT = Path(__file__).resolve().parent.parent
C_DIR = ROOT / "fmu_src" / "c"
CORE_DIR = ROOT / "models" / "core"
TABLE_HEADER = C_DIR / "native_railcar_table.h"
NATIVE_NAME = "RailCarNative"
MODEL_IDENTIFIER = "RailCar"
GLUE_SOURCES = ["fmi2_glue.c", "native_railcar.c"]
GLUE_HEADERS = ["fmi2_glue.h", "native_railcar_table.h"]
C_FLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-ffp-contract=off", "-fPIC",
           "-shared", "-fvisibility=hidden", "-pthread", "-Wl,--no-undefined"]
INPUTS = ("traction_force_demand", "brake_force_demand", "wind_speed", "car.payload")
"""RailCarChain.do_step's inputs, in its order (fmu_src/railcar.py)."""
LOG_CATEGORIES = ("logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal",
                  "logAll")
"""pythonfmu's LogCategories (RailCar.fmu's modelDescription.xml); build_native_fmu checks them."""
CONFIG_CONSTANT, CONFIG_START_TIME = -1, -2

_GLUE = {"Real": "GLUE_REAL", "Integer": "GLUE_INTEGER", "String": "GLUE_STRING"}
_CAUSALITY = {"parameter": "GLUE_PARAMETER", "input": "GLUE_INPUT", "output": "GLUE_OUTPUT"}
_VARIABILITY = {"fixed": "GLUE_FIXED", "continuous": "GLUE_CONTINUOUS", "discrete": "GLUE_DISCRETE"}


# ------------------------------------------------------------------------------ the mapping

def _config(values: dict, start_time: float) -> list:
    from models.compiled import _config_values
    return list(_config_values(chain_config(values), start_time))


def config_sources() -> tuple[list[int], list[float]]:
    """For each index of _config_values: the vr it comes from, CONFIG_START_TIME or
    CONFIG_CONSTANT; and the constants (0.0 where a vr or the start time is the source).
    Derived by perturbing each parameter alone; AssertionError if an index is unexplained."""
    table = variables_for(RAILCAR)
    base_values = {v.name: v.start for v in table}
    base = _config(base_values, 0.0)
    source: list[int | None] = [None] * len(base)

    def changed(values: dict, start_time: float, marker, what: str) -> list[int]:
        cfg = _config(values, start_time)
        assert len(cfg) == len(base), what
        idx = [k for k, (a, b) in enumerate(zip(base, cfg)) if not (a == b and type(a) is type(b))]
        for k in idx:
            assert cfg[k] == marker and float(cfg[k]) == float(marker), (
                f"{what}: config index {k} is {cfg[k]!r}, not the value set ({marker!r}): "
                "not a plain copy, the native FMU cannot map it")
            assert source[k] is None, f"{what}: config index {k} also comes from {source[k]}"
        return idx

    for vr, var in enumerate(table):
        if var.causality != "parameter" or var.type == "String":
            continue
        marker = 1000 + 7 * vr if var.type == "Integer" else 1000.0 + 0.375 * vr
        for k in changed(dict(base_values, **{var.name: marker}), 0.0, marker, var.name):
            source[k] = vr
    for k in changed(base_values, 777.25, 777.25, "start time"):
        source[k] = CONFIG_START_TIME
    constants = [0.0] * len(base)
    for k, s in enumerate(source):
        if s is None:                     # touched by nothing: a constant of the Python side
            assert isinstance(base[k], (int, float)) and math.isfinite(base[k]), (k, base[k])
            source[k] = CONFIG_CONSTANT
            constants[k] = float(base[k])
    # every index explained, and the parameters the core reads elsewhere are known
    assert all(s is not None for s in source)
    return [int(s) for s in source], constants


def _vr(name: str, causality: str) -> int:
    for vr, v in enumerate(variables_for(RAILCAR)):
        if v.name == name and v.causality == causality:
            return vr
    raise KeyError(f"RailCar has no {causality} '{name}'")


def _c_string(s: str) -> str:
    out = []
    for ch in s.encode("utf-8"):
        c = chr(ch)
        if c in '"\\':
            out.append("\\" + c)
        elif 32 <= ch < 127:
            out.append(c)
        else:
            out.append(f"\\{ch:03o}")
    return '"' + "".join(out) + '"'


def _c_double(x: float) -> str:
    x = float(x)
    return f"{x.hex()} /* {x!r} */" if x != 0.0 else ("-0.0" if math.copysign(1, x) < 0 else "0.0")


def generate_header() -> str:
    from models.compiled import INTEGER_OUTPUTS, OUTPUT_NAMES
    table = variables_for(RAILCAR)
    sources, constants = config_sources()
    outputs = [v.name for v in table if v.causality == "output"]
    assert sorted(outputs) == sorted(OUTPUT_NAMES), "RailCar's outputs are not OUTPUT_NAMES"
    for name in OUTPUT_NAMES:
        assert (table[_vr(name, "output")].type == "Integer") == (name in INTEGER_OUTPUTS), name
    inputs = [v.name for v in table if v.causality == "input"]
    assert sorted(inputs) == sorted(INPUTS), "RailCar's inputs are not do_step's"
    used = {s for s in sources if s >= 0}
    unused = [v.name for vr, v in enumerate(table)
              if v.causality == "parameter" and vr not in used]
    assert sorted(unused) == ["est.slope_window", "track.grade_profile", "track.speed_profile"], (
        f"parameters the flat configuration does not carry: {unused}")

    lines = [
        "/* native_railcar_table.h -- GENERATED by `python -m fmu_src.native` from",
        " * fmu_src/variables.py and models/compiled.py (_config_values, OUTPUT_NAMES). Do not edit:",
        " * `python -m fmu_src.native --check` (tests/test_native_fmu.py) fails when it is stale. */",
        "#ifndef NATIVE_RAILCAR_TABLE_H",
        "#define NATIVE_RAILCAR_TABLE_H",
        "",
        '#include "fmi2_glue.h"',
        "",
        "typedef struct {",
        "    const char *name;",
        "    GlueType type;",
        "    GlueCausality causality;",
        "    GlueVariability variability;",
        "    double start;               /* Real and Integer */",
        "    const char *start_string;   /* String */",
        "} nrc_var;",
        "",
        f"#define NRC_NVARS {len(table)}",
        "",
        "/* indexed by value reference */",
        "static const nrc_var NRC_VARS[NRC_NVARS] = {",
    ]
    for vr, v in enumerate(table):
        start = "0.0, " + _c_string(v.start) if v.type == "String" else f"{_c_double(v.start)}, NULL"
        lines.append(f"    /* {vr:2d} */ {{{_c_string(v.name)}, {_GLUE[v.type]}, "
                     f"{_CAUSALITY[v.causality]}, {_VARIABILITY[v.variability]}, {start}}},")
    lines += ["};", "",
              "/* models/compiled.py _config_values: index -> value reference of the parameter it is,",
              " * NRC_CONFIG_START_TIME (fmi2SetupExperiment's startTime) or NRC_CONFIG_CONSTANT",
              " * (NRC_CONFIG_CONST[index]) */",
              f"#define NRC_CONFIG_CONSTANT ({CONFIG_CONSTANT})",
              f"#define NRC_CONFIG_START_TIME ({CONFIG_START_TIME})",
              f"#define NRC_NCONFIG {len(sources)}",
              "static const int NRC_CONFIG_VR[NRC_NCONFIG] = {"]
    for k, s in enumerate(sources):
        what = (table[s].name if s >= 0 else "start time" if s == CONFIG_START_TIME else "constant")
        name = "NRC_CONFIG_CONSTANT" if s == CONFIG_CONSTANT else (
            "NRC_CONFIG_START_TIME" if s == CONFIG_START_TIME else str(s))
        lines.append(f"    /* {k:2d} */ {name},   /* {what} */")
    lines += ["};", "static const double NRC_CONFIG_CONST[NRC_NCONFIG] = {"]
    for k, c in enumerate(constants):
        lines.append(f"    /* {k:2d} */ {_c_double(c)},")
    lines += ["};", "",
              "/* RailCarChain.do_step's inputs: traction_force_demand, brake_force_demand, "
              "wind_speed, car.payload */",
              "static const int NRC_INPUT_VRS[4] = {"
              + ", ".join(str(_vr(n, "input")) for n in INPUTS) + "};",
              "",
              "/* rc_chain_outputs' order (models/compiled.py OUTPUT_NAMES) -> value reference */",
              f"#define NRC_NOUTPUTS {len(OUTPUT_NAMES)}",
              "static const int NRC_OUTPUT_VRS[NRC_NOUTPUTS] = {"]
    for name in OUTPUT_NAMES:
        lines.append(f"    {_vr(name, 'output')},   /* {name} */")
    lines += ["};", "",
              "/* parameters outside the flat configuration */",
              f"#define NRC_VR_SLOPE_WINDOW {_vr('est.slope_window', 'parameter')}",
              f"#define NRC_VR_GRADE_PROFILE {_vr('track.grade_profile', 'parameter')}",
              f"#define NRC_VR_SPEED_PROFILE {_vr('track.speed_profile', 'parameter')}",
              f"#define NRC_VR_FILTER_REJECTED {_vr('filter.rejected', 'output')}",
              "",
              f"#define NRC_NCATEGORIES {len(LOG_CATEGORIES)}",
              "static const char *const NRC_LOG_CATEGORIES[NRC_NCATEGORIES] = {"
              + ", ".join(_c_string(c) for c in LOG_CATEGORIES) + "};",
              "", "#endif", ""]
    return "\n".join(lines)


# -------------------------------------------------------------------------------- building

def _build_py():
    spec = importlib.util.spec_from_file_location("_railcar_build_native", ROOT / "build.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def c_sources() -> list[Path]:
    """What the binary is compiled from: the glue, the backend, every models/core/*.c."""
    return [C_DIR / s for s in GLUE_SOURCES] + sorted(CORE_DIR.glob("*.c"))


def c_headers() -> list[Path]:
    return [C_DIR / h for h in GLUE_HEADERS] + sorted(CORE_DIR.glob("*.h"))


def compile_native(out: Path) -> Path:
    """binaries/linux64/RailCar.so from the C sources; RuntimeError with the compiler's output."""
    build = _build_py()
    cc = build.find_compiler()
    if cc is None:
        raise RuntimeError("no C compiler found (set CC or install gcc)")
    cmd = [*cc, *C_FLAGS, "-I", str(C_DIR), "-I", str(CORE_DIR), "-I", str(build.fmi2_headers()),
           *[str(s) for s in c_sources()], "-o", str(out), "-lm"]
    proc = subprocess.run(cmd, capture_output=True, text=True)
    if proc.returncode != 0:
        raise RuntimeError(f"compiling the native FMU failed:\n{shlex.join(cmd)}\n"
                           f"{proc.stdout}{proc.stderr}")
    return out


def native_model_description(xml: bytes, guid: str) -> bytes:
    """RailCar.fmu's description for the native binary: new GUID, no Python tool needed, the
    sources listed; variables, value references and modelIdentifier unchanged."""
    root = ET.fromstring(xml)
    cosim = root.find("CoSimulation")
    assert cosim is not None and cosim.get("modelIdentifier") == MODEL_IDENTIFIER
    cats = tuple(c.get("name") for c in root.iter("Category"))
    if cats != LOG_CATEGORIES:
        raise RuntimeError(f"RailCar.fmu's LogCategories {cats} are not {LOG_CATEGORIES} "
                           "(fmu_src/native.py LOG_CATEGORIES, then regenerate the header)")
    names = [sv.get("name") for sv in root.find("ModelVariables")]
    vrs = [int(sv.get("valueReference")) for sv in root.find("ModelVariables")]
    table = variables_for(RAILCAR)
    if names != [v.name for v in table] or vrs != list(range(len(table))):
        raise RuntimeError("RailCar.fmu's variables are not fmu_src/variables.py's (stale build?)")
    root.set("guid", guid)
    root.set("generationTool", "fmu_src/native.py (C core, no Python)")
    cosim.set("needsExecutionTool", "false")
    for old in cosim.findall("SourceFiles"):
        cosim.remove(old)
    files = ET.SubElement(cosim, "SourceFiles")
    for src in c_sources():
        ET.SubElement(files, "File", name=src.name)
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def native_guid(xml: bytes) -> str:
    h = hashlib.sha256(f"{NATIVE_NAME}|".encode() + xml)
    for p in [*c_sources(), *c_headers()]:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16], version=5)) + "}"


def build_native_fmu(dest_dir, railcar_fmu=None) -> Path:
    """Compile and zip ``dest_dir/RailCarNative.fmu``; ``railcar_fmu`` is the pythonfmu
    RailCar.fmu whose description it takes (default: dist/, built by harness.fmus.ensure_built
    when missing or stale). Refuses to build when the table header is out of date."""
    if not TABLE_HEADER.is_file() or TABLE_HEADER.read_text(encoding="utf-8") != generate_header():
        raise RuntimeError(f"{TABLE_HEADER.relative_to(ROOT)} is out of date: run "
                           "python -m fmu_src.native")
    if railcar_fmu is None:
        from harness.fmus import ensure_built
        railcar_fmu = ensure_built(quiet=True)["RailCar"]
    dest = Path(dest_dir)
    dest.mkdir(parents=True, exist_ok=True)
    target = dest / f"{NATIVE_NAME}.fmu"
    names = [p.name for p in [*c_sources(), *c_headers()]]
    assert len(set(names)) == len(names), "two C files of the same name: sources/ is flat"
    with tempfile.TemporaryDirectory() as tmp:
        binary = compile_native(Path(tmp) / f"{MODEL_IDENTIFIER}.so")
        with zipfile.ZipFile(railcar_fmu) as src:
            xml = src.read("modelDescription.xml")
            profiles = [(i.filename, src.read(i.filename)) for i in src.infolist()
                        if i.filename.startswith("resources/profiles/") and not i.is_dir()]
        xml = native_model_description(xml, native_guid(xml))
        tmp_fmu = Path(tmp) / target.name
        with zipfile.ZipFile(tmp_fmu, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr("modelDescription.xml", xml)
            z.writestr(f"binaries/linux64/{MODEL_IDENTIFIER}.so", binary.read_bytes())
            for p in [*c_sources(), *c_headers()]:
                z.writestr(f"sources/{p.name}", p.read_bytes())
            for name, data in profiles:          # relative profile paths resolve here first
                z.writestr(name, data)
        target.write_bytes(tmp_fmu.read_bytes())
    return target


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if the header is out of date")
    ap.add_argument("--build", metavar="DEST", help="build DEST/RailCarNative.fmu")
    args = ap.parse_args(argv)
    text = generate_header()
    rel = TABLE_HEADER.relative_to(ROOT)
    if args.check:
        if not TABLE_HEADER.is_file() or TABLE_HEADER.read_text(encoding="utf-8") != text:
            print(f"{rel} is out of date: run python -m fmu_src.native", file=sys.stderr)
            return 1
        print(f"{rel} is up to date")
        return 0
    if not TABLE_HEADER.is_file() or TABLE_HEADER.read_text(encoding="utf-8") != text:
        TABLE_HEADER.write_text(text, encoding="utf-8")
        print(f"wrote {rel}")
    if args.build:
        print(f"built {build_native_fmu(args.build)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
