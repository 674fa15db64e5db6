"""Systems of FMUs as SSP 1.0 packages (.ssp): write one, read one back, checked against the FMUs.

A system is a few co-simulation FMUs (components), connections from an output of one to an input
of another, by variable NAME, and per component a set of start values (parameters, and inputs
that nothing drives). ``write_ssp`` packs it as an SSP 1.0 archive that our own master
(harness.systems.master) and libcosim (harness.systems.libcosim) both load:

    SystemStructure.ssd        the system: components, their connectors (every input and output
                               of the FMU, with type and unit), connections, units, the step
    resources/<Name>.fmu       each component's FMU (its own file name)
    resources/<Name>.ssv       each component's parameter set, bound by ssd:ParameterBinding; every
                               set has the one name PARAMETER_SET (below)
    resources/profiles/<file>  each profile file a parameter names (a ``PackedFile`` value): the
                               SSV holds this path, relative to the .ssd as SSP resolves a
                               relative URI; the masters hand the FMU the unpacked copy

What libcosim 0.11 (the libcosimpy 0.0.6 build) reads decides the details (docs/systems.md): the
namespace prefixes must be literally ``ssd:``, ``ssc:``, ``ssv:`` (it looks up prefixed tag
names), the step is the ``osp:FixedStepAlgorithm baseStepSize`` annotation of
``ssd:DefaultExperiment`` (SSP 1.0 itself has no step size; a second annotation of ours,
ORDER_ANNOTATION, holds a Gauss-Seidel step order that only our master runs), and a parameter set is taken from an
``.ssv`` file named relative to the .ssd, or inline. libcosim only warns about a parameter it
cannot apply and silently drops nothing else it does not know; ``read_ssp`` refuses all of it:
an unknown component or variable, a type or unit that does not match the FMU, an output bound as
a parameter, a missing FMU, malformed XML (the reader is harness.systems.ssp_read). Every error is an
``SspError`` naming the file, the element and the variable. fmpy's SSP reader (fmpy.ssp.ssd.read_ssd) validates the same file
against the SSP 1.0 schema.

Every component's parameter set is named PARAMETER_SET, so that the three masters apply them all.
Ours and libcosim apply each component's bound set whatever its name. ecos (harness.systems.ecos)
reads the same per-component bindings but gathers the sets BY NAME into system-wide sets
(component, parameter) -> value, and applies the one set it is told to (``init(parameter_set=...)``,
the CLI's ``--parameterSet``): sets named after their components (car, est) would be two sets of which
ecos applies at most one. ecos reads no binding at the system level, so one system-wide .ssv would
not do. The name is kept on read (LoadedSystem.parameter_sets) for the ecos runner to check.
"""
from __future__ import annotations

import io
import math
import re
import zipfile
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Mapping, Sequence
from xml.etree import ElementTree as ET

from harness.textio import InputError, did_you_mean

__all__ = ["PARAMETER_SET", "ORDER_ANNOTATION", "SSD_NAME", "PACKED_DIR", "PackedFile", "packed_member", "Component", "Connection", "LoadedSystem", "SspError", "SystemSpec", "Where",
           "write_ssp", "ssp_type", "unit_of", "split_name"]

SSD_NAME = "SystemStructure.ssd"
NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
      "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
      "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
      "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations",
      "rc": "urn:railcar-fmu:ssp"}                       # our own annotation's elements
OSP_ANNOTATION = "com.opensimulationplatform"
ORDER_ANNOTATION = "org.railcar-fmu.master"       # our master's Gauss-Seidel step order
PARAMETER_SET = "start_values"    # the name of every component's parameter set (ecos applies sets by name)
TYPES = ("Real", "Integer", "Boolean", "String")
PACKED_DIR = "resources/profiles/"                      # where a packed file lives in the .ssp
NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*\Z")       # no dot: "Component.variable" splits at the first
INT32 = (-2**31, 2**31 - 1)


class SspError(InputError):
    """A system that cannot be written or read; the message names the file, element and variable."""


# --------------------------------------------------------------------------------- the model

@dataclass(frozen=True)
class PackedFile:
    """The value of a String parameter that names a file (a profile) to pack into the .ssp:
    ``source``, a file checked when the package is written, or ``data`` made at build (a limits
    CSV) under the file name ``name``. ``parameter`` names the key it came from, for errors
    (default: the parameter's own name). In the package the parameter's value is the member's
    path, PACKED_DIR + a file name (``packed_member``)."""
    source: Path | None = None
    data: bytes | None = None
    name: str = ""
    parameter: str = ""

    def __post_init__(self):
        if (self.source is None) == (self.data is None):
            raise ValueError("PackedFile: give source or data, one of them")
        if self.data is not None and not self.name:
            raise ValueError("PackedFile: data needs a file name")

    @property
    def file_name(self) -> str:
        return self.name or Path(self.source).name

    def __str__(self):
        return str(self.source) if self.source is not None else f"<{self.name}, made at build>"


def packed_member(value) -> bool:
    """Whether a String parameter's value names a file packed in the .ssp (PACKED_DIR...)."""
    return isinstance(value, str) and value.startswith(PACKED_DIR)


@dataclass(frozen=True)
class Component:
    """One FMU in a system. ``fmu``: the FMU file (writing), or its path inside the .ssp (read)."""
    name: str
    fmu: Path | str
    parameters: Mapping[str, object] = field(default_factory=dict)


@dataclass(frozen=True)
class Connection:
    """``start`` output -> ``end`` input, each "Component.variable"."""
    start: str
    end: str

    def __str__(self):
        return f"{self.start} -> {self.end}"


@dataclass(frozen=True)
class SystemSpec:
    name: str
    components: Sequence[Component]
    connections: Sequence[Connection]
    step: float                       # communication step [s]
    start: float = 0.0
    stop: float | None = None
    description: str = ""
    step_order: tuple[str, ...] = ()  # () Jacobi (libcosim's); else Gauss-Seidel in this order



@dataclass
class LoadedSystem:
    """What read_ssp gives: the system (component.fmu = the path inside the archive) and each
    component's model description (fmpy's), for value references and types by name."""
    path: Path
    spec: SystemSpec
    models: dict                      # component name -> fmpy ModelDescription
    parameter_sets: dict = field(default_factory=dict)   # component -> the name of its bound set

    def variable(self, full: str, what: str = ""):
        """The model variable of "Component.variable"; SspError naming ``what`` if unknown."""
        where = f"{self.path}: {what}" if what else str(self.path)
        comp, var = split_name(full, where)
        if comp not in self.models:
            raise SspError(f"{where}: no component named '{comp}'")
        return find_variable(self.models[comp], comp, var, where)


def split_name(full: str, where: str = "") -> tuple[str, str]:
    """"Component.variable" -> ("Component", "variable") (component names have no dot); an error
    starts with ``where``."""
    comp, dot, var = full.partition(".")
    if not dot or not comp or not var:
        raise SspError(f"{where}: '{full}': expected Component.variable" if where else
                       f"'{full}': expected Component.variable")
    return comp, var


class Where:
    """Where each part of a system was written, for the start of an error message: here the elements
    of an SSP file (``file``: the .ssp, or its SystemStructure.ssd). harness.systems.cli's
    TomlWhere names a description's keys, tables and lines instead, so that an error found while
    building a system from a TOML description names the TOML file, not the .ssp being written."""

    def __init__(self, file: str | Path):
        self.file = str(file)

    def system(self, key: str) -> str:
        """The system's ``name`` or ``step``."""
        return f"{self.file}: system name" if key == "name" else f"{self.file}: {key}"

    def component(self, name: str) -> str:
        return f"{self.file}: component '{name}'"

    def parameters(self, component: str) -> str:
        """The parameter set of ``component``."""
        return f"{self.file}: parameter binding of '{component}'"

    def parameter(self, component: str, name: str) -> str:
        return f"{self.file}: parameter binding {component}.{name}"

    def connection(self, number: int, conn: Connection) -> str:
        """The ``number``-th connection (from 1)."""
        return f"{self.file}: connection {number} ({conn})"


def _where(where: str | Path | Where) -> Where:
    return where if isinstance(where, Where) else Where(where)


# ------------------------------------------------------------------------- FMU variables

def ssp_type(variable) -> str:
    """The SSP connector type of an fmpy model variable (FMI 2 or 3)."""
    t = variable.type
    if t in ("Real", "Float64", "Float32"):
        return "Real"
    if t in ("Integer", "Enumeration") or t.startswith(("Int", "UInt")):
        return "Integer"
    if t in ("Boolean", "String"):
        return t
    return t                          # Binary, Clock: no SSP 1.0 connector type; refused by callers


def unit_of(variable) -> str:
    return variable.unit or (variable.declaredType.unit if variable.declaredType is not None
                             and getattr(variable.declaredType, "unit", None) else "") or ""


def find_variable(md, comp: str, name: str, where: str):
    """The variable ``name`` of component ``comp``'s model description; SspError naming ``where`` (and the
    closest names) if it has none."""
    for v in md.modelVariables:
        if v.name == name:
            return v
    raise SspError(f"{where}: component '{comp}' ({md.modelName}) has no variable '{name}'"
                   + did_you_mean(name, [v.name for v in md.modelVariables]))


def _interface(md) -> list:
    """The variables a component exposes as connectors: every input and output."""
    return [v for v in md.modelVariables if v.causality in ("input", "output")]


def _typed(value, typ: str, what: str):
    """``value`` (a Python value or the text of an SSV attribute) as a value of SSP type ``typ``."""
    bad = SspError(f"{what}: {value!r} is not a valid {typ}")
    if typ == "Real":
        try:
            x = float(value) if not isinstance(value, bool) else None
        except (TypeError, ValueError):
            x = None
        if x is None:
            raise bad
        if not math.isfinite(x):
            raise SspError(f"{what}: {value!r} is not a finite Real")
        return x
    if typ == "Integer":
        try:
            x = int(value) if not isinstance(value, (bool, float)) else \
                int(value) if isinstance(value, float) and value.is_integer() else None
        except (TypeError, ValueError):
            x = None
        if x is None:
            raise bad
        if not INT32[0] <= x <= INT32[1]:
            raise SspError(f"{what}: {value!r} is outside the 32-bit Integer range")
        return x
    if typ == "Boolean":
        if isinstance(value, bool):
            return value
        if str(value) in ("true", "1", "false", "0"):
            return str(value) in ("true", "1")
        raise bad
    if typ == "String":
        if not isinstance(value, (str, Path)):
            raise bad
        return str(value)
    raise SspError(f"{what}: type {typ} is not supported")


def _text(value, typ: str) -> str:
    if typ == "Real":
        return repr(float(value))     # shortest text that reads back to the same double
    if typ == "Boolean":
        return "true" if value else "false"
    return str(value)


# ------------------------------------------------------------------------------ checking

def check_system(spec: SystemSpec, models: Mapping[str, object], where: str | Path | Where) -> SystemSpec:
    """Check ``spec`` against the components' model descriptions; returns it with every
    parameter value converted to its variable's type. SspError names the element where ``where``
    (a file name: an SSP file's elements; or a Where) says it was written."""
    where = _where(where)
    if not NAME_RE.match(spec.name or ""):
        raise SspError(f"{where.system('name')} {spec.name!r}: letters, digits and _ only")
    if not (isinstance(spec.step, (int, float)) and math.isfinite(spec.step) and spec.step > 0):
        raise SspError(f"{where.system('step')} {spec.step!r}: expected a step > 0 [s]")
    if round(spec.step * 1e9) < 1:
        raise SspError(f"{where.system('step')} {spec.step!r} is below 1 ns")
    seen: set[str] = set()
    components = []
    for c in spec.components:
        if not NAME_RE.match(c.name or ""):
            raise SspError(f"{where.component(c.name)}: a component name has letters, digits and _ only (no dot)")
        if c.name in seen:
            raise SspError(f"{where.component(c.name)} appears twice")
        seen.add(c.name)
        md = models[c.name]
        if md.coSimulation is None:
            raise SspError(f"{where.component(c.name)} ({c.fmu}): not a co-simulation FMU")
        params = {}
        for name, value in c.parameters.items():
            v = find_variable(md, c.name, name, where.parameters(c.name))
            what = where.parameter(c.name, name)
            if v.causality not in ("parameter", "input"):
                raise SspError(f"{what}: '{name}' is an {v.causality}, not a parameter or input")
            if v.variability == "constant":
                raise SspError(f"{what}: '{name}' is a constant")
            typ = ssp_type(v)
            if typ not in TYPES:
                raise SspError(f"{what}: type {v.type} is not supported")
            if isinstance(value, PackedFile):
                if typ != "String":
                    raise SspError(f"{what}: a file to pack, but '{name}' is a {typ}, not a String")
                params[name] = value
                continue
            params[name] = _typed(value, typ, f"{what} ({typ})")
        components.append(Component(c.name, c.fmu, params))
    driven: dict[str, Connection] = {}
    for k, conn in enumerate(spec.connections, 1):
        what = where.connection(k, conn)
        ends = []
        for full, kind in ((conn.start, "output"), (conn.end, "input")):
            comp, name = split_name(full, what)
            if comp not in models:
                raise SspError(f"{what}: no component named '{comp}'")
            v = find_variable(models[comp], comp, name, what)
            if v.causality != kind:
                raise SspError(f"{what}: {full} is an {v.causality}; a connection goes from an "
                               f"output to an input")
            ends.append(v)
        (a, b) = ends
        if ssp_type(a) != ssp_type(b) or ssp_type(a) not in TYPES:
            raise SspError(f"{what}: type mismatch: {conn.start} is {a.type}, {conn.end} is {b.type}")
        if unit_of(a) != unit_of(b):
            raise SspError(f"{what}: unit mismatch: {conn.start} [{unit_of(a) or '-'}], {conn.end} "
                           f"[{unit_of(b) or '-'}] (no unit conversion)")
        if conn.end in driven:
            raise SspError(f"{what}: {conn.end} is already driven by {driven[conn.end].start}")
        driven[conn.end] = conn
    order = tuple(spec.step_order)
    if order and sorted(order) != sorted(c.name for c in components):
        raise SspError(f"{where.system('step_order')} {list(order)}: name every component once "
                       f"({', '.join(c.name for c in components)})")
    return SystemSpec(spec.name, tuple(components), tuple(spec.connections), float(spec.step),
                      float(spec.start), None if spec.stop is None else float(spec.stop), spec.description,
                      order)


# ------------------------------------------------------------------------------- writing

def _unit_element(parent, name: str, base) -> None:
    u = ET.SubElement(parent, "ssc:Unit", name=name)
    attrs = {}
    if base is not None:
        for k in ("kg", "m", "s", "A", "K", "mol", "cd", "rad"):
            if getattr(base, k, 0):
                attrs[k] = str(getattr(base, k))
        if getattr(base, "factor", 1.0) != 1.0:
            attrs["factor"] = repr(float(base.factor))
        if getattr(base, "offset", 0.0) != 0.0:
            attrs["offset"] = repr(float(base.offset))
    ET.SubElement(u, "ssc:BaseUnit", attrs)


def _units_of(md) -> dict:
    return {u.name: u.baseUnit for u in (md.unitDefinitions or [])}


def _ssv(comp: Component, md) -> bytes:
    root = ET.Element("ssv:ParameterSet", {"xmlns:ssv": NS["ssv"], "xmlns:ssc": NS["ssc"],
                                           "version": "1.0", "name": PARAMETER_SET})
    params = ET.SubElement(root, "ssv:Parameters")
    units = {}
    for name, value in comp.parameters.items():
        v = find_variable(md, comp.name, name, "")
        typ = ssp_type(v)
        p = ET.SubElement(params, "ssv:Parameter", name=name)
        attrs = {"value": _text(value, typ)}
        if typ == "Real" and unit_of(v):
            attrs["unit"] = units.setdefault(unit_of(v), unit_of(v))
        ET.SubElement(p, f"ssv:{typ}", attrs)
    if units:
        u = ET.SubElement(root, "ssv:Units")
        defs = _units_of(md)
        for name in sorted(units):
            _unit_element(u, name, defs.get(name))
    return _xml(root)


def _xml(root) -> bytes:
    ET.indent(root, space="  ")
    return b'<?xml version="1.0" encoding="UTF-8"?>\n' + ET.tostring(root, encoding="utf-8") + b"\n"


def _ssd(spec: SystemSpec, models: Mapping[str, object], sources: Mapping[str, str]) -> bytes:
    root = ET.Element("ssd:SystemStructureDescription", {
        "xmlns:ssd": NS["ssd"], "xmlns:ssc": NS["ssc"], "xmlns:ssv": NS["ssv"],
        "xmlns:osp": NS["osp"], "version": "1.0", "name": spec.name})
    system = ET.SubElement(root, "ssd:System", name=spec.name)
    if spec.description:
        system.set("description", spec.description)
    elements = ET.SubElement(system, "ssd:Elements")
    units: dict[str, object] = {}
    for c in spec.components:
        md = models[c.name]
        e = ET.SubElement(elements, "ssd:Component", name=c.name, source=sources[c.name],
                          type="application/x-fmu-sharedlibrary")
        connectors = ET.SubElement(e, "ssd:Connectors")
        defs = _units_of(md)
        for v in _interface(md):
            typ = ssp_type(v)
            if typ not in TYPES:
                continue
            k = ET.SubElement(connectors, "ssd:Connector", name=v.name, kind=v.causality)
            attrs = {}
            if typ == "Real" and unit_of(v):
                attrs["unit"] = unit_of(v)
                units.setdefault(unit_of(v), defs.get(unit_of(v)))
            ET.SubElement(k, f"ssc:{typ}", attrs)
        if c.parameters:
            b = ET.SubElement(e, "ssd:ParameterBindings")
            ET.SubElement(b, "ssd:ParameterBinding", source=f"resources/{c.name}.ssv",
                          type="application/x-ssp-parameter-set")
    if spec.connections:
        conns = ET.SubElement(system, "ssd:Connections")
        for conn in spec.connections:
            (sc, sv), (ec, ev) = split_name(conn.start), split_name(conn.end)
            ET.SubElement(conns, "ssd:Connection", startElement=sc, startConnector=sv,
                          endElement=ec, endConnector=ev)
    if units:
        u = ET.SubElement(root, "ssd:Units")
        for name in sorted(units):
            _unit_element(u, name, units[name])
    exp = ET.SubElement(root, "ssd:DefaultExperiment", startTime=repr(spec.start))
    if spec.stop is not None:
        exp.set("stopTime", repr(spec.stop))
    annotations = ET.SubElement(exp, "ssd:Annotations")
    ann = ET.SubElement(annotations, "ssc:Annotation", type=OSP_ANNOTATION)
    ET.SubElement(ET.SubElement(ann, "osp:Algorithm"), "osp:FixedStepAlgorithm",
                  baseStepSize=repr(spec.step))
    if spec.step_order:          # our master only: libcosim has no such algorithm
        rc = ET.SubElement(annotations, "ssc:Annotation", type=ORDER_ANNOTATION)
        ET.SubElement(rc, "rc:StepOrder", {"xmlns:rc": NS["rc"], "components": " ".join(spec.step_order)})
    return _xml(root)


def read_model_description_of(data_or_path, where: str):
    """fmpy's model description of an FMU (bytes or a path); SspError naming ``where`` if unreadable."""
    from fmpy import read_model_description
    try:
        src = io.BytesIO(data_or_path) if isinstance(data_or_path, bytes) else str(data_or_path)
        return read_model_description(src, validate=False)
    except Exception as e:
        raise SspError(f"{where}: not a readable FMU ({type(e).__name__}: {e})") from None


def read_packed_source(f: PackedFile, what: str) -> bytes:
    """The bytes of a file to pack, checked as the FMUs check a profile (fmu_src.adapter.
    read_profile_text): a regular file of at most PROFILE_MAX_BYTES; SspError naming ``what``
    (the parameter) and the path."""
    import os
    import stat
    from fmu_src.adapter import PROFILE_MAX_BYTES
    path = Path(f.source)
    cannot = f"{what}: profile file {path}"
    try:
        st = os.stat(path)
        if not stat.S_ISREG(st.st_mode):
            kind = "a folder" if stat.S_ISDIR(st.st_mode) else "not a regular file"
            raise SspError(f"{cannot}: it is {kind}; a profile is a regular file (packed into the .ssp)")
        if st.st_size > PROFILE_MAX_BYTES:
            raise SspError(f"{cannot}: {st.st_size} bytes, more than the {PROFILE_MAX_BYTES} a profile may have")
        return path.read_bytes()
    except FileNotFoundError:
        raise SspError(f"{cannot}: not found") from None
    except OSError as e:
        raise SspError(f"{cannot}: cannot read: {e.strerror or e}") from None


def _pack_files(spec: SystemSpec, where: Where) -> tuple[SystemSpec, dict[str, bytes]]:
    """Every PackedFile value read (checked) and given its member name; the spec with those
    names as the values, and member -> bytes. One file named by several parameters (the car's and
    the ATO's grade) is packed once; two different files of one name get _2, _3, ... ."""
    packed: dict[str, bytes] = {}
    by_source: dict[object, str] = {}
    components = []
    for c in spec.components:
        params = {}
        for name, value in c.parameters.items():
            if not isinstance(value, PackedFile):
                params[name] = value
                continue
            what = where.parameter(c.name, value.parameter or name)
            data = value.data if value.data is not None else read_packed_source(value, what)
            key = Path(value.source).resolve() if value.source is not None else ("data", data, value.file_name)
            member = by_source.get(key)
            if member is None:
                stem, suffix = Path(value.file_name).stem, Path(value.file_name).suffix
                member, k = PACKED_DIR + value.file_name, 1
                while member in packed and packed[member] != data:
                    k += 1
                    member = f"{PACKED_DIR}{stem}_{k}{suffix}"
                by_source[key] = member
                packed[member] = data
            params[name] = member
        components.append(Component(c.name, c.fmu, params))
    return replace(spec, components=tuple(components)), packed


def write_ssp(spec: SystemSpec, path: str | Path, where: Where | None = None) -> Path:
    """Check ``spec`` against its FMUs and write it as an .ssp package at ``path``. Errors in the
    system name the element where ``where`` says it was written (default: in the .ssp)."""
    path = Path(path)
    where = where or Where(path)
    models, sources, used = {}, {}, {}
    for c in spec.components:
        fmu = Path(c.fmu)
        if not fmu.is_file():
            raise SspError(f"{where.component(c.name)}: FMU file not found: {fmu}")
        models[c.name] = read_model_description_of(fmu, f"{where.component(c.name)} ({fmu})")
        source = f"resources/{fmu.name}"
        if source in used and Path(used[source]).resolve() != fmu.resolve():
            raise SspError(f"{where.component(c.name)}: this and another component use two FMU files named "
                           f"{fmu.name} (an .ssp holds one file of a name)")
        used[source], sources[c.name] = fmu, source
    spec = check_system(spec, models, where)
    spec, packed = _pack_files(spec, where)
    tmp = path.with_name(path.name + ".part")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as z:
            z.writestr(SSD_NAME, _ssd(spec, models, sources))
            for source, fmu in used.items():
                z.write(fmu, source, compress_type=zipfile.ZIP_STORED)
            for c in spec.components:
                if c.parameters:
                    z.writestr(f"resources/{c.name}.ssv", _ssv(c, models[c.name]))
            for member, data in packed.items():
                z.writestr(member, data)
        tmp.replace(path)
    except OSError as e:
        tmp.unlink(missing_ok=True)
        raise SspError(f"{path}: cannot write: {e.strerror or e}") from None
    return path

