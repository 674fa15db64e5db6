"""Reading an SSP package (harness.systems.ssp) back, checked against its FMUs at every element.

Accepts what harness.systems.ssp writes, and what libcosim 0.11 also reads: ssd:Component elements with
ssd:Connectors and ssd:ParameterBindings (an .ssv file in the package, or an inline
ssv:ParameterSet), ssd:Connections without transformations, and the step as the
osp:FixedStepAlgorithm annotation. Anything else that would change the numbers (a parameter
mapping, a transformation, a sub-system, another algorithm) is refused rather than ignored.
Every error is an SspError naming the file, the element and the variable.

A String parameter whose value is a path below resources/profiles/ names a file packed in the
package (harness.systems.ssp.PackedFile): it must be there, a file, and the path plain (no "..",
not absolute). ``unpack_files`` writes those files out and gives the system with each such value
the unpacked copy's absolute path, which is what the masters hand the FMUs.
"""
from __future__ import annotations

import zipfile
from dataclasses import replace
from pathlib import Path
from xml.etree import ElementTree as ET

from harness.systems.ssp import (NS, ORDER_ANNOTATION, OSP_ANNOTATION, PACKED_DIR, SSD_NAME, TYPES, packed_member, Component, Connection, LoadedSystem, SspError,
                  SystemSpec, check_system, find_variable, read_model_description_of, ssp_type, unit_of)

__all__ = ["read_ssp", "unpack_files"]


def _parse(data: bytes, where: str):
    try:
        return ET.fromstring(data)
    except ET.ParseError as e:
        raise SspError(f"{where}: malformed XML: {e}") from None


def _tag(ns: str, name: str) -> str:
    return f"{{{NS[ns]}}}{name}"


def _attr(el, name: str, where: str) -> str:
    value = el.get(name)
    if value is None or value == "":
        raise SspError(f"{where}: <{_local(el.tag)}> has no '{name}' attribute")
    return value


def _local(tag: str) -> str:
    return tag.rsplit("}", 1)[-1]


def _connector_type(el, where: str) -> tuple[str, str]:
    for child in el:
        if child.tag.startswith(f"{{{NS['ssc']}}}"):
            typ = _local(child.tag)
            if typ not in TYPES:
                raise SspError(f"{where}: connector type ssc:{typ} is not supported")
            return typ, child.get("unit", "")
    raise SspError(f"{where}: no type (ssc:Real, ssc:Integer, ssc:Boolean, ssc:String)")


def _parameter_set(el, where: str) -> tuple[str, list[tuple[str, str, str, str]]]:
    """The set's name, and (name, type, value text, unit) of each ssv:Parameter of an
    ssv:ParameterSet element."""
    if el.tag != _tag("ssv", "ParameterSet"):
        raise SspError(f"{where}: expected an ssv:ParameterSet, found <{_local(el.tag)}>")
    set_name = _attr(el, "name", where)           # libcosim needs it; ecos applies sets by it
    out = []
    params = el.find("ssv:Parameters", NS)
    for p in (params if params is not None else []):
        name = _attr(p, "name", where)
        typed = [c for c in p if c.tag.startswith(f"{{{NS['ssv']}}}")]
        if len(typed) != 1 or _local(typed[0].tag) not in TYPES:
            raise SspError(f"{where}: parameter '{name}': expected one of ssv:Real, ssv:Integer, "
                           f"ssv:Boolean, ssv:String")
        value = typed[0].get("value")
        if value is None:
            raise SspError(f"{where}: parameter '{name}' has no value")
        out.append((name, _local(typed[0].tag), value, typed[0].get("unit", "")))
    return set_name, out


def _step_order(root, where: str) -> tuple[str, ...]:
    """Our master's Gauss-Seidel step order (an ORDER_ANNOTATION), () if none: Jacobi. An
    annotation of that type without one rc:StepOrder (another namespace, say) is refused, never
    taken for Jacobi."""
    notes = root.findall(f"ssd:DefaultExperiment/ssd:Annotations/ssc:Annotation[@type='{ORDER_ANNOTATION}']", NS)
    if not notes:
        return ()
    orders = [o for n in notes for o in n]
    if len(notes) > 1 or len(orders) != 1 or orders[0].tag != _tag("rc", "StepOrder"):
        raise SspError(f"{where}: ssd:DefaultExperiment: the {ORDER_ANNOTATION} annotation must hold one "
                       f"<rc:StepOrder components=\"...\"> (xmlns:rc=\"{NS['rc']}\")")
    return tuple(_attr(orders[0], "components", f"{where}: ssd:DefaultExperiment").split())


def _step(root, where: str) -> tuple[float | None, float, float | None]:
    exp = root.find("ssd:DefaultExperiment", NS)
    if exp is None:
        return None, 0.0, None
    try:
        start = float(exp.get("startTime", "0"))
        stop = float(exp.get("stopTime")) if exp.get("stopTime") is not None else None
    except ValueError:
        raise SspError(f"{where}: ssd:DefaultExperiment: startTime/stopTime are not numbers") from None
    step = None
    for algo in exp.iterfind(f"ssd:Annotations/ssc:Annotation[@type='{OSP_ANNOTATION}']/osp:Algorithm/*", NS):
        if algo.tag != _tag("osp", "FixedStepAlgorithm"):
            raise SspError(f"{where}: ssd:DefaultExperiment: algorithm <{_local(algo.tag)}> is not "
                           f"supported (osp:FixedStepAlgorithm only)")
        text = _attr(algo, "baseStepSize", f"{where}: ssd:DefaultExperiment")
        try:
            step = float(text)
        except ValueError:
            raise SspError(f"{where}: ssd:DefaultExperiment: baseStepSize {algo.get('baseStepSize')!r} "
                           f"is not a number") from None
    return step, start, stop


def read_ssp(path: str | Path, step: float | None = None) -> LoadedSystem:
    """Read and check an .ssp package; ``step`` overrides the one in the file (needed if it has
    none)."""
    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise SspError(f"{where}: no such file")
    try:
        z = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as e:
        raise SspError(f"{where}: not an SSP package (a zip archive): {e}") from None
    with z:
        names = set(z.namelist())
        if SSD_NAME not in names:
            raise SspError(f"{where}: no {SSD_NAME} in the package")
        ssd_where = f"{where}: {SSD_NAME}"
        root = _parse(z.read(SSD_NAME), ssd_where)
        if root.tag != _tag("ssd", "SystemStructureDescription"):
            raise SspError(f"{ssd_where}: root element <{root.tag}> is not ssd:SystemStructureDescription "
                           f"(namespace {NS['ssd']})")
        for attr in ("name", "version"):            # libcosim needs both
            _attr(root, attr, ssd_where)
        system = root.find("ssd:System", NS)
        if system is None:
            raise SspError(f"{ssd_where}: no ssd:System")
        name = _attr(system, "name", ssd_where)
        models, components, declared, set_names = {}, [], {}, {}
        for el in system.iterfind("ssd:Elements/*", NS):
            if el.tag != _tag("ssd", "Component"):
                raise SspError(f"{ssd_where}: element <{_local(el.tag)}> is not supported (ssd:Component only)")
            cname = _attr(el, "name", ssd_where)
            cwhere = f"{ssd_where}: component '{cname}'"
            source = _attr(el, "source", cwhere)
            if source not in names:
                raise SspError(f"{cwhere}: FMU '{source}' is not in the package")
            if cname in models:
                raise SspError(f"{ssd_where}: component '{cname}' appears twice")
            md = models[cname] = read_model_description_of(z.read(source), f"{cwhere} ({source})")
            declared[cname] = _check_connectors(el, md, cname, cwhere)
            params = {}
            bindings = el.findall("ssd:ParameterBindings/ssd:ParameterBinding", NS)
            if len(bindings) > 1:       # libcosim applies only the first: refused, not guessed
                raise SspError(f"{cwhere}: {len(bindings)} ssd:ParameterBinding elements; one is supported")
            for b in bindings:
                if b.get("prefix"):
                    raise SspError(f"{cwhere}: ssd:ParameterBinding prefix is not supported")
                if b.get("source"):
                    src = b.get("source")
                    if src not in names:
                        raise SspError(f"{cwhere}: parameter set '{src}' is not in the package")
                    swhere = f"{where}: {src}"
                    set_names[cname], entries = _parameter_set(_parse(z.read(src), swhere), swhere)
                else:
                    swhere = f"{cwhere}: inline parameter set"
                    sets = b.findall("ssd:ParameterValues/*", NS)
                    if len(sets) != 1:
                        raise SspError(f"{swhere}: expected one ssv:ParameterSet in ssd:ParameterValues, "
                                       f"found {len(sets)}")
                    set_names[cname], entries = _parameter_set(sets[0], swhere)
                for pname, typ, text, unit in entries:
                    v = find_variable(md, cname, pname, f"{swhere}: parameter '{pname}'")
                    if ssp_type(v) != typ:
                        raise SspError(f"{swhere}: parameter '{pname}': type mismatch: ssv:{typ} for "
                                       f"{cname}.{pname}, which is {v.type}")
                    if unit and unit != unit_of(v):
                        raise SspError(f"{swhere}: parameter '{pname}': unit '{unit}', the FMU's is "
                                       f"'{unit_of(v) or '-'}'")
                    if pname in params:
                        raise SspError(f"{swhere}: parameter '{pname}' is bound twice")
                    if typ == "String" and text.startswith("resources/"):
                        _check_packed(text, names, z, f"{swhere}: parameter '{pname}'")
                    params[pname] = text
                if b.find("ssd:ParameterMapping", NS) is not None:
                    raise SspError(f"{cwhere}: ssd:ParameterMapping is not supported")
            components.append(Component(cname, source, params))
        connections = []
        for k, c in enumerate(system.iterfind("ssd:Connections/ssd:Connection", NS), 1):
            cw = f"{ssd_where}: connection {k}"
            ends = [(_attr(c, "startElement", cw), _attr(c, "startConnector", cw)),
                    (_attr(c, "endElement", cw), _attr(c, "endConnector", cw))]
            for comp, conn in ends:
                if comp not in models:
                    raise SspError(f"{cw} ({comp}.{conn}): no component named '{comp}'")
                if conn not in declared[comp]:
                    raise SspError(f"{cw} ({comp}.{conn}): component '{comp}' declares no connector "
                                   f"'{conn}'")
            if len(c):
                raise SspError(f"{cw}: <{_local(c[0].tag)}> is not supported (no transformations)")
            connections.append(Connection(f"{ends[0][0]}.{ends[0][1]}", f"{ends[1][0]}.{ends[1][1]}"))
        file_step, start, stop = _step(root, ssd_where)
        order = _step_order(root, ssd_where)
    if step is None:
        step = file_step
    if step is None:
        raise SspError(f"{ssd_where}: no step size (ssd:DefaultExperiment's osp:FixedStepAlgorithm "
                       f"baseStepSize); pass one")
    spec = check_system(SystemSpec(name, components, connections, step, start, stop,
                                   system.get("description", ""), order), models, ssd_where)
    return LoadedSystem(path, spec, models, set_names)


def _check_packed(member: str, names: set, z: zipfile.ZipFile, where: str) -> None:
    """A parameter that names a file in the package: a plain path below PACKED_DIR to a file
    that is there."""
    parts = member.split("/")
    if not packed_member(member) or any(p in ("", ".", "..") for p in parts) or "\\" in member:
        raise SspError(f"{where}: '{member}': a packed file is a plain path below {PACKED_DIR}")
    if member not in names or z.getinfo(member).is_dir():
        raise SspError(f"{where}: '{member}' is not a file in the package")


def unpack_files(system: LoadedSystem, folder: str | Path) -> LoadedSystem:
    """Write every packed file the parameters name below ``folder`` (at its path in the package:
    ``folder``/resources/profiles/...) and return the system with those values the copies'
    absolute paths. Each master calls it before it instantiates the FMUs."""
    folder = Path(folder).resolve()
    components = []
    with zipfile.ZipFile(system.path) as z:
        for c in system.spec.components:
            params = dict(c.parameters)
            for name, value in c.parameters.items():
                if packed_member(value):
                    target = folder / value
                    if not target.is_file():
                        target.parent.mkdir(parents=True, exist_ok=True)
                        target.write_bytes(z.read(value))
                    params[name] = str(target)
            components.append(Component(c.name, c.fmu, params))
    return replace(system, spec=replace(system.spec, components=tuple(components)))


def _check_connectors(el, md, cname: str, where: str) -> set[str]:
    """The connectors an ssd:Component declares, each checked against its FMU's variable."""
    names = set()
    for k in el.iterfind("ssd:Connectors/ssd:Connector", NS):
        name = _attr(k, "name", where)
        kw = f"{where}: connector '{name}'"
        kind = _attr(k, "kind", kw)
        v = find_variable(md, cname, name, kw)
        if kind != v.causality:
            raise SspError(f"{kw}: kind '{kind}', but the FMU's variable is an {v.causality}")
        typ, unit = _connector_type(k, kw)
        if typ != ssp_type(v):
            raise SspError(f"{kw}: type mismatch: ssc:{typ}, the FMU's variable is {v.type}")
        if unit and unit != unit_of(v):
            raise SspError(f"{kw}: unit '{unit}', the FMU's is '{unit_of(v) or '-'}'")
        names.add(name)
    return names
