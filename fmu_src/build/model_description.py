"""The one writer of modelDescription.xml, for every FMU we ship, from ``fmu_src/variables.py``.

- ``fmi2(fmu, ...)``: FMI 2.0 co-simulation, for the pythonfmu FMUs (RailCar, RailCarEstimator,
  AtoController) and the native FMI 2 ones (same variables, value references, units and start
  values; their own GUID, ``needsExecutionTool="false"`` and ``<SourceFiles>``);
- ``fmi3(fmu, ...)``: FMI 3.0 co-simulation, for the native FMI 3 FMUs.

What an FMU says about itself (``description``, ``author``) is its pythonfmu slave's class
attributes (``fmu_src/railcar.py`` ...). ``check_pythonfmu_description`` compares what pythonfmu
generated from the slave's registration with the table, so that the binary and the description
we write cannot disagree.
"""
from __future__ import annotations

import datetime
import importlib
from xml.etree import ElementTree as ET

from fmu_src.variables import ATO, ESTIMATOR, RAILCAR, UNITS, Var, variables_for

SLAVE_MODULES = {RAILCAR: "fmu_src.railcar", ESTIMATOR: "fmu_src.railcar_estimator",
                 ATO: "fmu_src.ato_controller"}
"""The pythonfmu slave of each FMU: a class named as the FMU (= modelIdentifier) in this module."""

DEFAULT_EXPERIMENT = {"startTime": "0", "stopTime": "200", "stepSize": "0.1"}

LOG_CATEGORIES = ("logStatusWarning", "logStatusDiscard", "logStatusError", "logStatusFatal",
                  "logAll")
"""pythonfmu's (Fmi2Slave.log_categories); the native glue's tables (native.generate_header) too."""

NO_DIRECT_FEEDTHROUGH = (ATO,)
"""FMUs whose outputs depend on no input of the same step: AtoController computes a command in
doStep from the inputs at its start and holds it for the next step, so a loop through RailCar is
no algebraic loop."""

FMI3_DESCRIPTION_SUFFIX = " (native C core, FMI 3.0 co-simulation)"

_FMI2_OPTIONS = {     # pythonfmu's defaults (FMI2_MODEL_OPTIONS), in its order
    "canHandleVariableCommunicationStepSize": "true", "canInterpolateInputs": "false",
    "canBeInstantiatedOnlyOncePerProcess": "false", "canGetAndSetFMUstate": "false",
    "canSerializeFMUstate": "false"}
_FMI2_NATIVE_STATE = {"canGetAndSetFMUstate": "true", "canSerializeFMUstate": "true"}
"""FMU states: the native glue saves the whole instance (fmu_src/c/native_state.c). The pythonfmu
FMUs keep pythonfmu's "false": their binary (fmu_src/c/pyslave.c) saves no state, and pythonfmu
0.7's own state (Fmi2Slave._get_fmu_state) holds only the registered variables, not the chain."""
_FMI3_OPTIONS = {     # the native FMI 3 FMUs only; FMU states as _FMI2_NATIVE_STATE
    "canBeInstantiatedOnlyOncePerProcess": "false", "canGetAndSetFMUState": "true",
    "canSerializeFMUState": "true", "providesDirectionalDerivatives": "false",
    "providesAdjointDerivatives": "false", "providesPerElementDependencies": "false",
    "canHandleVariableCommunicationStepSize": "true", "maxOutputDerivativeOrder": "0",
    "providesIntermediateUpdate": "false", "mightReturnEarlyFromDoStep": "false",
    "canReturnEarlyAfterIntermediateUpdate": "false", "hasEventMode": "false",
    "providesEvaluateDiscreteStates": "false"}
_FMI3_TYPE = {"Real": "Float64", "Integer": "Int32", "Boolean": "Boolean", "String": "String"}


def category_description(name: str, fmi: int) -> str:
    """The text of a log category: 'Log messages with fmi2Warning status.' ..."""
    if name == "logAll":
        return "Log all messages."
    return f"Log messages with fmi{fmi}{name.removeprefix('logStatus')} status."


def slave_metadata(fmu: str) -> tuple[str, str]:
    """(description, author) of ``fmu``: its pythonfmu slave's class attributes."""
    slave = getattr(importlib.import_module(SLAVE_MODULES[fmu]), fmu)
    return slave.description, slave.author


def generation_time() -> str:
    """Now, as pythonfmu writes generationDateAndTime: UTC, to the second."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _unit_definitions(parent: ET.Element, units) -> None:
    defs = ET.SubElement(parent, "UnitDefinitions")
    for name in sorted(units):
        exponents, factor = UNITS[name]
        base = {k: str(e) for k, e in exponents.items()}
        if factor != 1.0:
            base["factor"] = repr(factor)
        ET.SubElement(ET.SubElement(defs, "Unit", name=name), "BaseUnit", base)


def _real_units(table) -> set[str]:
    return {v.unit for v in table if v.unit and v.type == "Real"}


def _bounds(v: Var) -> dict[str, str]:
    """unit, min and max of a Real (what the table gives)."""
    attrs = {}
    if v.unit:
        attrs["unit"] = v.unit
    if v.min is not None:
        attrs["min"] = repr(float(v.min))
    if v.max is not None:
        attrs["max"] = repr(float(v.max))
    return attrs


def _fmi2_start(v: Var) -> dict[str, str]:
    """The start attribute FMI 2 wants (none for a calculated output). Reals as repr: it
    round-trips the double."""
    if v.causality == "output" and v.initial == "calculated":
        return {}
    if v.type == "Real":
        return {"start": repr(float(v.start))}
    if v.type == "Integer":
        return {"start": str(int(v.start))}
    if v.type == "Boolean":
        return {"start": "true" if v.start else "false"}
    return {"start": str(v.start)}


def _fmi3_start(v: Var) -> str:
    if v.type == "Boolean":
        return "true" if v.start else "false"
    return repr(float(v.start)) if isinstance(v.start, float) else str(int(v.start))


def _serialise(root: ET.Element) -> bytes:
    ET.indent(root)
    return ET.tostring(root, encoding="UTF-8", xml_declaration=True)


def fmi2(fmu: str, guid: str, generation_tool: str, *, needs_execution_tool: bool = True,
         source_files: tuple[str, ...] = (), generated_at: str | None = None) -> bytes:
    """FMI 2.0 co-simulation modelDescription.xml of ``fmu`` (modelIdentifier = ``fmu``).

    ``needs_execution_tool``: true for the pythonfmu FMUs (they need Python), false for the
    native ones; ``source_files``: the C files listed in ``<SourceFiles>`` (a source FMU);
    ``generated_at``: generationDateAndTime (default: now)."""
    table = variables_for(fmu)
    description, author = slave_metadata(fmu)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "2.0", "modelName": fmu, "guid": guid, "generationTool": generation_tool,
        "generationDateAndTime": generated_at or generation_time(),
        "variableNamingConvention": "structured", "description": description, "author": author})
    cosim = ET.SubElement(root, "CoSimulation", {
        "needsExecutionTool": "true" if needs_execution_tool else "false", **_FMI2_OPTIONS,
        **({} if needs_execution_tool else _FMI2_NATIVE_STATE),     # native: the C glue
        "modelIdentifier": fmu, "canNotUseMemoryManagementFunctions": "true"})
    if source_files:
        # FMI 2.0 <SourceFiles> has no place for compiler options (FMI 3.0's
        # buildDescription.xml has, native_fmi3.build_description): bit-identity with the
        # Python reference needs -ffp-contract=off (native.C_FLAGS). The header comment of
        # sources/glue_common.c says so to whoever compiles them; the core's .c files also turn
        # contraction off themselves (rc_fp_contract.h).
        files = ET.SubElement(cosim, "SourceFiles")
        for name in source_files:
            ET.SubElement(files, "File", name=name)
    _unit_definitions(root, _real_units(table))
    cats = ET.SubElement(root, "LogCategories")
    for name in LOG_CATEGORIES:
        ET.SubElement(cats, "Category", name=name, description=category_description(name, 2))
    ET.SubElement(root, "DefaultExperiment", DEFAULT_EXPERIMENT)

    mv = ET.SubElement(root, "ModelVariables")
    for vr, v in enumerate(table):
        attrs = {"name": v.name, "valueReference": str(vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.causality == "output":
            attrs["initial"] = v.initial
        typed = _fmi2_start(v)
        if v.type == "Real":
            typed.update(_bounds(v))
        ET.SubElement(ET.SubElement(mv, "ScalarVariable", attrs), v.type, typed)

    structure = ET.SubElement(root, "ModelStructure")
    outputs = [(index, v) for index, v in enumerate(table, start=1) if v.causality == "output"]
    if outputs:
        unknowns = ET.SubElement(structure, "Outputs")
        for index, _ in outputs:
            ET.SubElement(unknowns, "Unknown", {"index": str(index), **(
                {"dependencies": ""} if fmu in NO_DIRECT_FEEDTHROUGH else {})})
    calculated = [index for index, v in outputs if v.initial == "calculated"]
    if calculated:      # FMI 2.0 section 2.2.8: every calculated output is an initial unknown
        unknowns = ET.SubElement(structure, "InitialUnknowns")
        for index in calculated:
            ET.SubElement(unknowns, "Unknown", index=str(index))
    return _serialise(root)


def fmi3(fmu: str, token: str, generation_tool: str) -> bytes:
    """FMI 3.0 co-simulation modelDescription.xml of ``fmu`` (a native FMU: needs no tool).

    The variables of the FMI 2 FMU with the same names and value references (= their order):
    Real as Float64, Integer as Int32, Boolean as Boolean (start "true"/"false"); parameters
    and inputs carry their start values, outputs are ``initial="calculated"`` (FMI 3 allows them
    no start value) and are listed as Output (``dependencies=""`` for NO_DIRECT_FEEDTHROUGH, as
    in fmi2) and InitialUnknown. "time", the independent variable FMI 3 requires, follows them
    (value reference = their number, as fmu_src/c/fmi3_glue.c expects). canGetAndSetFMUState
    and canSerializeFMUState say "true": every native backend saves FMU states (native_state.c,
    native_ato_state.c)."""
    table = variables_for(fmu)
    description, author = slave_metadata(fmu)
    root = ET.Element("fmiModelDescription", {
        "fmiVersion": "3.0", "modelName": fmu, "instantiationToken": token,
        "description": description + FMI3_DESCRIPTION_SUFFIX, "author": author,
        "generationTool": generation_tool, "variableNamingConvention": "structured"})
    ET.SubElement(root, "CoSimulation", {"modelIdentifier": fmu, "needsExecutionTool": "false",
                                         **_FMI3_OPTIONS})
    _unit_definitions(root, _real_units(table) | {"s"})          # "s": time's unit
    cats = ET.SubElement(root, "LogCategories")
    for name in LOG_CATEGORIES:
        ET.SubElement(cats, "Category", name=name, description=category_description(name, 3))
    ET.SubElement(root, "DefaultExperiment", DEFAULT_EXPERIMENT)

    mv = ET.SubElement(root, "ModelVariables")
    outputs = []
    for vr, v in enumerate(table):
        attrs = {"name": v.name, "valueReference": str(vr), "description": v.description,
                 "causality": v.causality, "variability": v.variability}
        if v.causality == "output":
            attrs["initial"] = "calculated"
            outputs.append(vr)
        elif v.type != "String":
            attrs["start"] = _fmi3_start(v)
        if v.type == "Real":
            attrs.update(_bounds(v))
        element = ET.SubElement(mv, _FMI3_TYPE[v.type], attrs)
        if v.type == "String" and v.causality != "output":
            ET.SubElement(element, "Start", value=str(v.start))
    if "time" in (v.name for v in table):
        raise ValueError(f"{fmu}: the table has a variable 'time', the name FMI 3's independent "
                         "variable takes (fmu_src/variables.py)")
    ET.SubElement(mv, "Float64", {
        "name": "time", "valueReference": str(len(table)), "causality": "independent",
        "variability": "continuous", "unit": "s",
        "description": "simulation time (the independent variable)"})
    structure = ET.SubElement(root, "ModelStructure")
    for vr in outputs:
        ET.SubElement(structure, "Output", {"valueReference": str(vr), **(
            {"dependencies": ""} if fmu in NO_DIRECT_FEEDTHROUGH else {})})
    for vr in outputs:
        ET.SubElement(structure, "InitialUnknown", valueReference=str(vr))
    return _serialise(root)


def check_pythonfmu_description(xml: bytes, fmu: str, where: str) -> None:
    """pythonfmu's modelDescription.xml of ``fmu`` (generated from what the slave registered)
    has the table's variables, in value-reference order, with the same causality, variability,
    type and initial, and the log categories we declare; RuntimeError naming the first
    difference and ``where`` (the FMU) otherwise."""
    root = ET.fromstring(xml)
    cosim = root.find("CoSimulation")
    if cosim is None or cosim.get("modelIdentifier") != fmu:
        raise RuntimeError(f"{where}: modelIdentifier is not {fmu}")
    cats = tuple(c.get("name") for c in root.iter("Category"))
    if cats != LOG_CATEGORIES:
        raise RuntimeError(f"{where}: the slave's LogCategories {cats} are not {LOG_CATEGORIES} "
                           "(fmu_src/build/model_description.py LOG_CATEGORIES, then regenerate "
                           "the native headers: python -m fmu_src.build.native)")
    registered = [(sv.get("name"), sv.get("valueReference"), sv.get("causality"),
                   sv.get("variability"), sv.get("initial"), sv[0].tag)
                  for sv in root.find("ModelVariables")]
    table = [(v.name, str(vr), v.causality, v.variability,
              v.initial if v.causality == "output" else None, v.type)
             for vr, v in enumerate(variables_for(fmu))]
    if registered != table:
        first = next((i for i, (a, b) in enumerate(zip(registered, table)) if a != b),
                     min(len(registered), len(table)))
        got = registered[first] if first < len(registered) else "nothing"
        want = table[first] if first < len(table) else "nothing"
        raise RuntimeError(f"{where}: the slave registers {got} at value reference {first}, "
                           f"fmu_src/variables.py has {want}")
