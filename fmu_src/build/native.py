"""The native RailCar, RailCarEstimator (issue 18) and AtoController (issue 30) FMUs: the C core
behind our FMI 2.0 glue.
Over 600 lines: the three FMUs' table generators and builds share this module's helpers.

    python -m fmu_src.build.native            write fmu_src/c/native_railcar_table.h,
                                              native_estimator_table.h and native_ato_table.h
    python -m fmu_src.build.native --check    exit 1 if one of them is out of date
    python -m fmu_src.build.native --build D  build D/RailCarNative.fmu and D/RailCarEstimatorNative.fmu
                                              and D/AtoControllerNative.fmu

Each FMU is a ``NativeSpec`` (RAILCAR_SPEC, ESTIMATOR_SPEC). Its header is generated from the
one variable table (``fmu_src/variables.py``) and from the Python chain's own configuration
path, so that the C backends (``fmu_src/c/native_railcar.c``, ``native_estimator.c``, sharing
``native_common.c``) cannot drift from the pythonfmu FMUs:

- the variables by value reference (= their order in ``variables_for(...)``): name, type,
  causality, variability, start value;
- for every number of the flat configuration the C core reads (RailCar:
  ``models.compiled._config_values``, read by ``rc_chain_config_from_values``; RailCarEstimator:
  ``estimator_config_values``, what ``CompiledEstimatorChain`` hands
  ``rc_estchain_config_from_values``), the parameter it comes from, or the start time, or the
  constant it always is. This is found by construction, not written by hand: each parameter is
  set to a marker value, the configuration is rebuilt, and the one index that changes must
  hold the marker itself; every index must be explained;
- the inputs in the chain's do_step order and the outputs in the core's order.

``build_native_fmu(dest)`` / ``build_native_estimator_fmu(dest)`` compile the glue, the backend
and ``models/core/*.c`` once per platform of ``toolchain.TARGETS`` this machine has a compiler
for (``binaries/linux64/<modelIdentifier>.so``, ``binaries/win64/<modelIdentifier>.dll``,
``binaries/aarch64-linux/<modelIdentifier>.so``; a platform without one is skipped with a
printed message naming the compiler and its package) and zip the FMU: the
pythonfmu FMU's modelDescription.xml (``model_description.fmi2``: same modelIdentifier, variables
and value references) with its own GUID, ``needsExecutionTool="false"`` and its C sources under
``sources/`` (listed in SourceFiles), the pythonfmu FMU's profiles under ``resources/``, and
``documentation/_main.html``: the platforms it carries and how to compile ``sources/``
(FMI 2.0 <SourceFiles> has no place for options, include folders or libraries).
"""
from __future__ import annotations

import argparse
import hashlib
import html
import math
import os
import sys
import tempfile
import threading
import uuid
import zipfile
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from fmu_src.adapter import chain_config, estimator_settings, track_settings
from fmu_src.variables import ATO, ESTIMATOR, RAILCAR, variables_for

from . import model_description
from .model_description import LOG_CATEGORIES
from .dist import DIST, current_pythonfmu, description_of, fmu_guid, native_path
from .toolchain import (C_DIR, CORE_DIR, LINUX_X86_64, ROOT, Target, available_targets,
                        compile_c, fmi_headers, missing_compiler, target_compiler)

GENERATION_TOOL = "fmu_src/build/native.py (C core, no Python)"
BASE_FLAGS = ["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror", "-O2", "-ffp-contract=off",
              "-shared", "-Wl,--no-undefined"]
"""Every platform's flags; each ``toolchain.Target`` adds its own (``-fPIC -pthread``, ``-static``)."""
C_FLAGS = [*BASE_FLAGS, *LINUX_X86_64.flags]
"""The linux x86-64 flags (benchmarks compile with them)."""
CONFIG_CONSTANT, CONFIG_START_TIME = -1, -2
COMMON_SOURCES = ["fmi2_glue.c", "glue_common.c", "native_common.c", "native_state.c",
                  "native_state_read.c"]
COMMON_HEADERS = ["fmi2_glue.h", "glue_common.h", "native_common.h", "native_state_read.h"]
FMI2_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")

_GLUE = {"Real": "GLUE_REAL", "Integer": "GLUE_INTEGER", "String": "GLUE_STRING"}
_CAUSALITY = {"parameter": "GLUE_PARAMETER", "input": "GLUE_INPUT", "output": "GLUE_OUTPUT"}
_VARIABILITY = {"fixed": "GLUE_FIXED", "continuous": "GLUE_CONTINUOUS", "discrete": "GLUE_DISCRETE"}


# ------------------------------------------------------------------------------ the mapping

def _config(values: dict, start_time: float) -> list:
    from models.compiled import _config_values
    return list(_config_values(chain_config(values), start_time))


def estimator_config_values(values: dict, start_time: float = 0.0) -> list:
    """RailCarEstimator's parameter values -> the numbers models.compiled.CompiledEstimatorChain
    hands the C core (rc_estchain_config_from_values), as fmu_src/railcar_estimator.py builds
    its chain (estimator_settings, track_settings). The start time is not one of them."""
    from models.compiled import _estimator_values
    ident, filt, station = estimator_settings(values)
    track = track_settings(values)
    return [*_estimator_values(ident, filt), station.dwell, station.speed_threshold,
            station.position_threshold, track.base, track.resolution, track.jitter]


def _output_names(fmu: str) -> tuple:
    from models.compiled import ESTIMATOR_OUTPUT_NAMES, OUTPUT_NAMES
    return OUTPUT_NAMES if fmu == RAILCAR else ESTIMATOR_OUTPUT_NAMES


@dataclass(frozen=True)
class NativeSpec:
    """One native FMU: its variable table, flat configuration, inputs, outputs and files."""
    fmu: str                    # fmu_src/variables.py's name = modelIdentifier
    native_name: str            # <native_name>.fmu
    prefix: str                 # of the generated C names
    header: str                 # the generated table header in fmu_src/c
    backend: str                # the backend's C file in fmu_src/c
    inputs: tuple               # the chain's do_step inputs, in its order
    outside: tuple              # parameters the flat configuration does not carry
    config: Callable            # (values, start_time) -> the flat configuration


RAILCAR_SPEC = NativeSpec(
    RAILCAR, "RailCarNative", "NRC", "native_railcar_table.h", "native_railcar.c",
    ("traction_force_demand", "brake_force_demand", "wind_speed", "car.payload"),
    ("est.slope_window", "track.grade_profile", "track.speed_profile"), _config)
ESTIMATOR_SPEC = NativeSpec(
    ESTIMATOR, "RailCarEstimatorNative", "NES", "native_estimator_table.h", "native_estimator.c",
    ("traction_force", "brake_force", "sensor.speed", "sensor.position", "sensor.track_speed",
     "sensor.track_time"),
    ("est.slope_window", "track.grade_profile", "track.speed_profile"), estimator_config_values)
SPECS = (RAILCAR_SPEC, ESTIMATOR_SPEC)

# the generated headers (module attributes: a test points one at a stale copy)
TABLE_HEADER = C_DIR / RAILCAR_SPEC.header
ESTIMATOR_TABLE_HEADER = C_DIR / ESTIMATOR_SPEC.header


def config_sources(spec: NativeSpec = RAILCAR_SPEC) -> tuple[list[int], list[float]]:
    """For each index of the flat configuration: the vr it comes from, CONFIG_START_TIME or
    CONFIG_CONSTANT; and the constants (0.0 where a vr or the start time is the source).
    Derived by perturbing each parameter alone; AssertionError if an index is unexplained."""
    table = variables_for(spec.fmu)
    base_values = {v.name: v.start for v in table}
    base = spec.config(base_values, 0.0)
    source: list[int | None] = [None] * len(base)

    def changed(values: dict, start_time: float, marker, what: str) -> list[int]:
        cfg = spec.config(values, start_time)
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


def _vr(name: str, causality: str, fmu: str = RAILCAR) -> int:
    for vr, v in enumerate(variables_for(fmu)):
        if v.name == name and v.causality == causality:
            return vr
    raise KeyError(f"{fmu} has no {causality} '{name}'")


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


def generate_header(spec: NativeSpec = RAILCAR_SPEC) -> str:
    """The table header of ``spec`` (default RailCar's native_railcar_table.h)."""
    from models.compiled import INTEGER_OUTPUTS
    P, fmu = spec.prefix, spec.fmu
    output_names = _output_names(fmu)
    table = variables_for(fmu)
    sources, constants = config_sources(spec)
    outputs = [v.name for v in table if v.causality == "output"]
    assert sorted(outputs) == sorted(output_names), f"{fmu}'s outputs are not the core's"
    for name in output_names:
        assert (table[_vr(name, "output", fmu)].type == "Integer") == (name in INTEGER_OUTPUTS), name
    inputs = [v.name for v in table if v.causality == "input"]
    assert sorted(inputs) == sorted(spec.inputs), f"{fmu}'s inputs are not do_step's"
    used = {s for s in sources if s >= 0}
    unused = [v.name for vr, v in enumerate(table)
              if v.causality == "parameter" and vr not in used]
    assert sorted(unused) == sorted(spec.outside), (
        f"parameters the flat configuration does not carry: {unused}")
    guard = spec.header.upper().replace(".", "_")
    config_what = ("models/compiled.py _config_values" if fmu == RAILCAR else
                   "models/compiled.py CompiledEstimatorChain's configuration")

    lines = [
        f"/* {spec.header} -- GENERATED by `python -m fmu_src.build.native` from",
        " * fmu_src/variables.py and models/compiled.py. Do not edit:",
        " * `python -m fmu_src.build.native --check` (tests/fmu_tests/test_native_*fmu.py) fails when it is stale. */",
        f"#ifndef {guard}",
        f"#define {guard}",
        "",
        '#include "native_common.h"',
        "",
        f"#define {P}_NVARS {len(table)}",
        "",
        "/* indexed by value reference */",
        f"static const native_var {P}_VARS[{P}_NVARS] = {{",
    ]
    for vr, v in enumerate(table):
        start = "0.0, " + _c_string(v.start) if v.type == "String" else f"{_c_double(v.start)}, NULL"
        lines.append(f"    /* {vr:2d} */ {{{_c_string(v.name)}, {_GLUE[v.type]}, "
                     f"{_CAUSALITY[v.causality]}, {_VARIABILITY[v.variability]}, {start}}},")
    lines += ["};", "",
              f"/* {config_what}: index -> value reference of the parameter",
              " * it is, NATIVE_CONFIG_START_TIME (fmi2SetupExperiment's startTime) or",
              f" * NATIVE_CONFIG_CONSTANT ({P}_CONFIG_CONST[index]) */",
              f"#define {P}_NCONFIG {len(sources)}",
              f"static const int {P}_CONFIG_VR[{P}_NCONFIG] = {{"]
    for k, s in enumerate(sources):
        what = (table[s].name if s >= 0 else "start time" if s == CONFIG_START_TIME else "constant")
        name = "NATIVE_CONFIG_CONSTANT" if s == CONFIG_CONSTANT else (
            "NATIVE_CONFIG_START_TIME" if s == CONFIG_START_TIME else str(s))
        lines.append(f"    /* {k:2d} */ {name},   /* {what} */")
    lines += ["};", f"static const double {P}_CONFIG_CONST[{P}_NCONFIG] = {{"]
    for k, c in enumerate(constants):
        lines.append(f"    /* {k:2d} */ {_c_double(c)},")
    lines += ["};", "",
              f"/* the chain's do_step inputs: {', '.join(spec.inputs)} */",
              f"#define {P}_NINPUTS {len(spec.inputs)}",
              f"static const int {P}_INPUT_VRS[{P}_NINPUTS] = {{"
              + ", ".join(str(_vr(n, "input", fmu)) for n in spec.inputs) + "};",
              "",
              "/* the core's output order (models/compiled.py) -> value reference */",
              f"#define {P}_NOUTPUTS {len(output_names)}",
              f"static const int {P}_OUTPUT_VRS[{P}_NOUTPUTS] = {{"]
    for name in output_names:
        lines.append(f"    {_vr(name, 'output', fmu)},   /* {name} */")
    lines += ["};", "",
              "/* parameters outside the flat configuration */",
              f"#define {P}_VR_SLOPE_WINDOW {_vr('est.slope_window', 'parameter', fmu)}",
              f"#define {P}_VR_GRADE_PROFILE {_vr('track.grade_profile', 'parameter', fmu)}",
              f"#define {P}_VR_SPEED_PROFILE {_vr('track.speed_profile', 'parameter', fmu)}",
              f"#define {P}_VR_FILTER_REJECTED {_vr('filter.rejected', 'output', fmu)}",
              "",
              f"#define {P}_NCATEGORIES {len(LOG_CATEGORIES)}",
              f"static const char *const {P}_LOG_CATEGORIES[{P}_NCATEGORIES] = {{"
              + ", ".join(_c_string(c) for c in LOG_CATEGORIES) + "};",
              "",
              f"static const native_model {P}_MODEL = {{",
              f"    {_c_string(fmu)}, {P}_VARS, {P}_NVARS, {P}_LOG_CATEGORIES, {P}_NCATEGORIES,",
              f"    {P}_CONFIG_VR, {P}_CONFIG_CONST, {P}_NCONFIG,",
              f"    {P}_VR_GRADE_PROFILE, {P}_VR_SPEED_PROFILE, {P}_OUTPUT_VRS, {P}_NOUTPUTS,",
              f"    {P}_VR_FILTER_REJECTED",
              "};",
              "", "#endif", ""]
    return "\n".join(lines)


def generate_estimator_header() -> str:
    return generate_header(ESTIMATOR_SPEC)


# -------------------------------------------------------------------------------- building

def c_sources(spec: NativeSpec = RAILCAR_SPEC) -> list[Path]:
    """What the binary is compiled from: the glue, the shared backend part, the FMU's backend,
    every models/core/*.c."""
    return ([C_DIR / s for s in [*COMMON_SOURCES, spec.backend]]
            + sorted(CORE_DIR.glob("*.c")))


def c_headers(spec: NativeSpec = RAILCAR_SPEC) -> list[Path]:
    """Every header the sources include: ours, the core's, and the FMI 2 headers (fmpy's copy
    of the standard's), so that sources/ compiles with no other include folder."""
    return ([C_DIR / h for h in [*COMMON_HEADERS, spec.header]] + sorted(CORE_DIR.glob("*.h"))
            + [fmi_headers() / h for h in FMI2_HEADERS])


LINK_FLAGS = ("-shared", "-Wl,--no-undefined")
"""BASE_FLAGS that only the link reads."""
_OBJECTS: dict[tuple, Path] = {}
_OBJECTS_LOCK = threading.Lock()
_OBJECT_DIR: list[tempfile.TemporaryDirectory] = []


def _object_for(cc: list[str], flags: list[str], source: Path, what: str) -> Path:
    """``source`` compiled (-c) with ``cc`` and ``flags``, once per process: every native FMU of a
    build links the same core objects (six FMUs x three platforms compiled the ~30 core files 18
    times). Keyed by the command and the source's bytes, so a changed source is compiled again."""
    data = source.read_bytes()
    key = (tuple(cc), tuple(flags), str(source), hashlib.sha256(data).hexdigest())
    with _OBJECTS_LOCK:
        if key in _OBJECTS:
            return _OBJECTS[key]
        if not _OBJECT_DIR:
            _OBJECT_DIR.append(tempfile.TemporaryDirectory(prefix="railcar-objects-"))
        out = Path(_OBJECT_DIR[0].name) / f"{len(_OBJECTS)}_{source.stem}.o"
        _OBJECTS[key] = out
    try:
        compile_c([*cc, *flags, "-c", str(source), "-o", str(out)], f"{what}: {source.name}")
    except BaseException:
        with _OBJECTS_LOCK:
            _OBJECTS.pop(key, None)
        raise
    return out


def compile_for(target: Target, sources: list[Path], out: Path, what: str) -> Path:
    """Compile ``sources`` into the shared library ``out`` for ``target`` (each source's object
    compiled once per process, _object_for); RuntimeError with the compiler's output, or naming
    the compiler and its package when it is missing."""
    cc = target_compiler(target)
    if cc is None:
        raise RuntimeError(f"cannot build {what}: {missing_compiler(target)}")
    flags = [f for f in BASE_FLAGS if f not in LINK_FLAGS]
    flags += [*target.flags, "-I", str(C_DIR), "-I", str(CORE_DIR), "-I", str(fmi_headers())]
    objects = [_object_for(cc, flags, Path(s), f"{what} for {target.tuple}") for s in sources]
    compile_c([*cc, *LINK_FLAGS, *target.flags, *[str(o) for o in objects], "-o", str(out),
               *target.libraries], f"{what} for {target.tuple}")
    return out


def compile_platforms(targets, sources: list[Path], folder: Path, member: Callable,
                      what: str) -> dict[str, Path]:
    """``sources`` compiled for each of ``targets`` into ``folder`` at once (one compiler process
    a platform, as many at a time as this machine has cores: they are independent), as
    {member(target): the library}, in the order of ``targets``; the first failure raised."""
    targets = list(targets)
    with ThreadPoolExecutor(max_workers=max(1, min(len(targets), os.cpu_count() or 1))) as pool:
        built = list(pool.map(lambda t: compile_for(t, sources, folder / f"{t.tuple}{t.extension}",
                                                    what), targets))
    return {member(t): lib for t, lib in zip(targets, built)}


def platforms_page(title: str, folders: list[str], build_note: str) -> bytes:
    """documentation/ page of a native FMU: the binaries it carries and how to build others."""
    items = "".join(f"<li><code>binaries/{html.escape(f)}/</code></li>" for f in folders)
    return (f"<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>{html.escape(title)}"
            f"</title></head><body>\n<h1>{html.escape(title)}</h1>\n"
            f"<p>Binaries for these platforms:</p>\n<ul>{items}</ul>\n"
            f"<p>{build_note}</p>\n</body></html>\n").encode()


SOURCES_NOTE = (
    "Any other platform: compile every <code>.c</code> file of <code>sources/</code> into one "
    "shared library named after the modelIdentifier, with <code>sources/</code> as the include "
    "folder, C99, no preprocessor definitions, <code>-ffp-contract=off</code> (no fused "
    "multiply-add: bit-identity with the Python reference), linked with the maths library "
    "(<code>-lm</code>) and, on POSIX systems, <code>-pthread</code>; Windows needs no thread "
    "library. See docs/native_fmus.md of the project.")


def native_model_description(guid: str, spec: NativeSpec = RAILCAR_SPEC) -> bytes:
    """The pythonfmu FMU's description for the native binary: its own GUID, no Python tool
    needed, the sources listed; variables, value references and modelIdentifier the same."""
    return model_description.fmi2(spec.fmu, guid, GENERATION_TOOL, needs_execution_tool=False,
                                  source_files=tuple(p.name for p in c_sources(spec)))


def native_guid(xml: bytes, spec: NativeSpec = RAILCAR_SPEC, targets=None) -> str:
    """From the pythonfmu FMU's modelDescription.xml ``xml``, the platforms (default: those this
    machine can build) and every C file: a native FMU is current when it was built from that FMU
    and these sources for these platforms (fmu_src.build.dist)."""
    if targets is None:
        targets = available_targets(report=False)
    platforms = ",".join(t.tuple for t in targets)
    h = hashlib.sha256(f"{spec.native_name}|{platforms}|".encode() + xml)
    for p in [*c_sources(spec), *c_headers(spec)]:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16], version=5)) + "}"


def read_pythonfmu(path, fmu: str) -> tuple[bytes, list[tuple[str, bytes]]]:
    """The pythonfmu FMU's modelDescription.xml (checked: ``fmu``'s, with the table's
    variables) and its profiles (resources/profiles/: relative profile paths resolve there)."""
    with zipfile.ZipFile(path) as src:
        xml = src.read("modelDescription.xml")
        profiles = [(i.filename, src.read(i.filename)) for i in src.infolist()
                    if i.filename.startswith("resources/profiles/") and not i.is_dir()]
    model_description.check_pythonfmu_description(xml, fmu, f"{path} (stale build?)")
    return xml, profiles


def check_header(spec: NativeSpec) -> None:
    """RuntimeError unless the table header of ``spec`` is what generate_header writes now."""
    header = _header_path(spec)
    if not header.is_file() or header.read_text(encoding="utf-8") != generate_header(spec):
        raise RuntimeError(f"{_rel(header)} is out of date: run python -m fmu_src.build.native")


def _header_path(spec: NativeSpec) -> Path:
    return TABLE_HEADER if spec is RAILCAR_SPEC else ESTIMATOR_TABLE_HEADER


def _rel(p: Path) -> Path:
    try:
        return p.relative_to(ROOT)
    except ValueError:
        return p


def build_inputs(spec: NativeSpec, fmu_name: str, python_fmu=None, targets=None) -> tuple:
    """What every native build (FMI 2 here, FMI 3 in native_fmi3) starts from: the table header
    checked, the platforms (default: those with a compiler here; none is an error naming
    ``fmu_name``) and the pythonfmu twin (default: dist/'s, built when missing or stale)."""
    check_header(spec)
    if targets is None:
        targets = available_targets()
    if not targets:
        raise RuntimeError(f"{fmu_name}: no platform has a compiler here")
    if python_fmu is None:
        python_fmu = current_pythonfmu(spec.fmu)
    return targets, python_fmu


def build_native(spec: NativeSpec, dest_dir, python_fmu=None, targets=None) -> Path:
    """Compile and zip ``dest_dir/<spec.native_name>.fmu``; ``python_fmu`` is its pythonfmu
    twin, which its GUID follows and whose profiles it carries (default: dist/'s, built by
    fmu_src.build.dist.current_pythonfmu when missing or stale); ``targets``: the platforms
    (default: every one of toolchain.TARGETS this machine has a compiler for, the others
    printed). Refuses to build when the table header is out of date."""
    targets, python_fmu = build_inputs(spec, spec.native_name, python_fmu, targets)
    dest = Path(dest_dir)
    dest.mkdir(parents=True, exist_ok=True)
    target = dest / f"{spec.native_name}.fmu"
    names = [p.name for p in [*c_sources(spec), *c_headers(spec)]]
    assert len(set(names)) == len(names), "two C files of the same name: sources/ is flat"
    with tempfile.TemporaryDirectory() as tmp:
        binaries = compile_platforms(
            targets, c_sources(spec), Path(tmp),
            lambda t: f"binaries/{t.fmi2_folder}/{spec.fmu}{t.extension}",
            f"the native FMU {spec.native_name}")
        python_xml, profiles = read_pythonfmu(python_fmu, spec.fmu)
        xml = native_model_description(native_guid(python_xml, spec, targets), spec)
        write_fmu2(target, Path(tmp), xml, binaries, spec.native_name, targets,
                   [*c_sources(spec), *c_headers(spec)], profiles)
    return target


def write_fmu2(target: Path, tmp: Path, xml, binaries: dict, native_name: str, targets,
               files: list, profiles) -> None:
    """A native FMI 2.0 FMU at ``target`` (zipped in ``tmp`` first): its description, the
    ``binaries`` (member -> compiled file), the platforms page, ``files`` under sources/ and the
    ``profiles`` (member, bytes: relative profile paths resolve there first)."""
    tmp_fmu = tmp / target.name
    with zipfile.ZipFile(tmp_fmu, "w", zipfile.ZIP_DEFLATED) as z:
        z.writestr("modelDescription.xml", xml)
        for name, binary in binaries.items():
            z.writestr(name, binary.read_bytes())
        z.writestr("documentation/_main.html", platforms_page(
            f"{native_name}.fmu (FMI 2.0)", [t.fmi2_folder for t in targets], SOURCES_NOTE))
        for p in files:
            z.writestr(f"sources/{p.name}", p.read_bytes())
        for name, data in profiles:
            z.writestr(name, data)
    target.write_bytes(tmp_fmu.read_bytes())


def native_is_stale(name: str, dist: Path = DIST) -> bool:
    """True if DIST/native/<name>Native.fmu is missing or was not built from DIST/<name>.fmu and
    the current C sources (its GUID is fmu_src.build.native.native_guid of both)."""
    xml = description_of(Path(dist) / f"{name}.fmu")
    if xml is None:
        return True
    if name == ATO:
        return fmu_guid(native_path(name, dist)) != native_ato_guid(xml, available_targets(report=False))
    spec = {s.fmu: s for s in SPECS}[name]
    return fmu_guid(native_path(name, dist)) != native_guid(xml, spec)


def build_native_fmu(dest_dir, railcar_fmu=None) -> Path:
    """``dest_dir/RailCarNative.fmu`` from the pythonfmu ``railcar_fmu`` (see build_native)."""
    return build_native(RAILCAR_SPEC, dest_dir, railcar_fmu)


def build_native_estimator_fmu(dest_dir, estimator_fmu=None) -> Path:
    """``dest_dir/RailCarEstimatorNative.fmu`` from the pythonfmu ``estimator_fmu``."""
    return build_native(ESTIMATOR_SPEC, dest_dir, estimator_fmu)


# ------------------------------------------------------------- the native AtoController (issue 30)
# fmu_src/c/native_ato.c, the C core's LineController (models/core/ato_line.h) behind the FMI 2.0
# glue. It has no flat configuration (NativeSpec): native_ato.c reads its parameters by value
# reference (the generated NAT_VR_* names) and builds the controller itself, so it has its own
# table header, sources (no native_common.c, native_state.c: its FMU states are its own,
# native_ato_state.c, sharing the instance through native_ato.h) and build.

ATO_NATIVE_NAME = "AtoControllerNative"
ATO_TABLE_HEADER = C_DIR / "native_ato_table.h"
ATO_SOURCES = ["fmi2_glue.c", "glue_common.c", "native_ato.c", "native_ato_profiles.c",
               "native_ato_state.c", "native_state_read.c"]
ATO_HEADERS = ["fmi2_glue.h", "glue_common.h", "native_ato.h", "native_ato_profiles.h",
               "native_state_read.h"]
_GLUE_ATO = {**_GLUE, "Boolean": "GLUE_BOOLEAN"}


def _c_identifier(name: str) -> str:
    """'ato.grid_step' -> 'ATO_GRID_STEP' (the NAT_VR_<...> defines)."""
    return "".join(c.upper() if c.isalnum() else "_" for c in name)


def generate_ato_header() -> str:
    """native_ato_table.h: AtoController's variables by value reference (fmu_src/variables.py),
    a NAT_VR_<NAME> define for each, and the log categories."""
    table = variables_for(ATO)
    idents = [_c_identifier(v.name) for v in table]
    assert len(set(idents)) == len(idents), "two AtoController variables with one C name"
    lines = [
        "/* native_ato_table.h -- GENERATED by `python -m fmu_src.build.native` from",
        " * fmu_src/variables.py. Do not edit: `python -m fmu_src.build.native --check`",
        " * (tests/fmu_tests/test_native_ato_fmu.py) fails when it is stale. */",
        "#ifndef NATIVE_ATO_TABLE_H",
        "#define NATIVE_ATO_TABLE_H",
        "",
        '#include "glue_common.h"',
        "",
        "typedef struct {                 /* one variable, indexed by vr */",
        "    const char *name;",
        "    GlueType type;",
        "    GlueCausality causality;",
        "    GlueVariability variability;",
        "    double start;                /* Real, Integer and Boolean (0/1) */",
        "    const char *start_string;    /* String */",
        "} nat_var;",
        "",
        f"#define NAT_NVARS {len(table)}",
        "static const nat_var NAT_VARS[NAT_NVARS] = {",
    ]
    for vr, v in enumerate(table):
        if v.type == "String":
            start = "0.0, " + _c_string(v.start)
        else:
            start = f"{_c_double(float(v.start))}, NULL"
        lines.append(f"    /* {vr:2d} */ {{{_c_string(v.name)}, {_GLUE_ATO[v.type]}, "
                     f"{_CAUSALITY[v.causality]}, {_VARIABILITY[v.variability]}, {start}}},")
    lines += ["};", ""]
    lines += [f"#define NAT_VR_{ident} {vr}" for vr, ident in enumerate(idents)]
    lines += ["",
              f"#define NAT_NCATEGORIES {len(LOG_CATEGORIES)}",
              "static const char *const NAT_LOG_CATEGORIES[NAT_NCATEGORIES] = {"
              + ", ".join(_c_string(c) for c in LOG_CATEGORIES) + "};",
              "", "#endif", ""]
    return "\n".join(lines)


def ato_c_sources() -> list[Path]:
    """The native AtoController's binary: the FMI 2 glue, its backend, every models/core/*.c."""
    return [C_DIR / s for s in ATO_SOURCES] + sorted(CORE_DIR.glob("*.c"))


def ato_c_headers() -> list[Path]:
    return ([C_DIR / h for h in ATO_HEADERS] + [ATO_TABLE_HEADER] + sorted(CORE_DIR.glob("*.h"))
            + [fmi_headers() / h for h in FMI2_HEADERS])


def native_ato_guid(xml: bytes, targets) -> str:
    """native_guid's rule for the AtoController: its pythonfmu description, platforms, C files."""
    platforms = ",".join(t.tuple for t in targets)
    h = hashlib.sha256(f"{ATO_NATIVE_NAME}|{platforms}|".encode() + xml)
    for p in [*ato_c_sources(), *ato_c_headers()]:
        h.update(p.name.encode())
        h.update(p.read_bytes())
    return "{" + str(uuid.UUID(bytes=h.digest()[:16], version=5)) + "}"


def check_ato_header() -> None:
    """RuntimeError unless native_ato_table.h is what generate_ato_header writes now."""
    if ATO_TABLE_HEADER.read_text(encoding="utf-8") != generate_ato_header():
        raise RuntimeError(f"{_rel(ATO_TABLE_HEADER)} is out of date: run python -m "
                           "fmu_src.build.native")


def ato_build_inputs(fmu_name: str, python_fmu=None, targets=None) -> tuple:
    """build_inputs for the native AtoController (FMI 2 here, FMI 3 in native_fmi3): its table
    header checked, the platforms and the pythonfmu AtoController.fmu."""
    check_ato_header()
    if targets is None:
        targets = available_targets()
    if not targets:
        raise RuntimeError(f"{fmu_name}: no platform has a compiler here")
    if python_fmu is None:
        python_fmu = current_pythonfmu(ATO)
    return targets, python_fmu


def build_native_ato(dest_dir, python_fmu=None, targets=None) -> Path:
    """``dest_dir/AtoControllerNative.fmu`` (FMI 2.0) from the pythonfmu AtoController.fmu
    ``python_fmu`` (default dist/'s): build_native's recipe with native_ato.c. Its description
    says canGetAndSetFMUstate="true" and canSerializeFMUstate="true": native_ato_state.c saves and
    restores the whole controller (its FMU states)."""
    targets, python_fmu = ato_build_inputs(ATO_NATIVE_NAME, python_fmu, targets)
    dest = Path(dest_dir)
    dest.mkdir(parents=True, exist_ok=True)
    target = dest / f"{ATO_NATIVE_NAME}.fmu"
    sources = ato_c_sources()
    python_xml, profiles = read_pythonfmu(python_fmu, ATO)
    xml = model_description.fmi2(ATO, native_ato_guid(python_xml, targets), GENERATION_TOOL,
                                 needs_execution_tool=False,
                                 source_files=tuple(p.name for p in sources))
    with tempfile.TemporaryDirectory() as tmp:
        binaries = compile_platforms(targets, sources, Path(tmp),
                                     lambda t: f"binaries/{t.fmi2_folder}/{ATO}{t.extension}",
                                     f"the native FMU {ATO_NATIVE_NAME}")
        write_fmu2(target, Path(tmp), xml, binaries, ATO_NATIVE_NAME, targets,
                   [*sources, *ato_c_headers()], profiles)
    return target


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a header is out of date")
    ap.add_argument("--build", metavar="DEST",
                    help="build DEST/RailCarNative.fmu and DEST/RailCarEstimatorNative.fmu")
    args = ap.parse_args(argv)
    stale = 0
    headers = [(_header_path(spec), generate_header(spec)) for spec in SPECS]
    headers.append((ATO_TABLE_HEADER, generate_ato_header()))
    for header, text in headers:
        current = header.is_file() and header.read_text(encoding="utf-8") == text
        if args.check:
            if not current:
                print(f"{_rel(header)} is out of date: run python -m fmu_src.build.native",
                      file=sys.stderr)
                stale = 1
            else:
                print(f"{_rel(header)} is up to date")
        elif not current:
            header.write_text(text, encoding="utf-8")
            print(f"wrote {_rel(header)}")
    if args.check:
        return stale
    if args.build:
        for spec in SPECS:
            print(f"built {build_native(spec, args.build)}")
        print(f"built {build_native_ato(args.build)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
