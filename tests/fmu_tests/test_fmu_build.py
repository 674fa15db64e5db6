"""Build and model-description checks of RailCar.fmu, RailCarEstimator.fmu and AtoController.fmu.

The FMUs under test are built once per session by ``build.py`` in a subprocess (conftest), i.e.
exactly what ``python build.py`` writes to ``dist/``, from the current sources.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import re
import zipfile
from pathlib import Path
from xml.etree import ElementTree as ET

import fmpy
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from conftest import FMU_NAMES, ROOT, build_fmus

# At collection, before any FMU runs in this process: an FMU loaded first would put its own
# bundled copy of fmu_src (resources/fmu_src, ROOT = the unzipped FMU) in sys.modules.
from fmu_src.build import dist, model_description, native, native_fmi3, pythonfmu_fmus  # noqa: E402
from fmu_src.variables import UNITS, variables_for  # noqa: E402

# ----------------------------------------------------------------------------- the contract
# Hard-coded from shared/spec/FMU_INTERFACE.md (the contract: names and units never change).
# Units are written as in the contract; CONTRACT_UNITS gives the ASCII spelling used in
# modelDescription.xml and the SI base unit (exponents, factor) each must declare.
BOTH = ("RailCar", "RailCarEstimator")
R, E, A = ("RailCar",), ("RailCarEstimator",), ("AtoController",)

CONTRACT = [
    # name, fmus, causality, type, contract unit (None: no unit)
    ("track.grade_profile", BOTH, "parameter", "String", None),
    ("track.speed_profile", BOTH, "parameter", "String", None),
    ("track.station_dwell", BOTH, "parameter", "Real", "s"),
    # RailCar
    ("traction_force_demand", R, "input", "Real", "N"),
    ("brake_force_demand", R, "input", "Real", "N"),
    ("wind_speed", R, "input", "Real", "m/s"),
    ("car.mass", R, "parameter", "Real", "t"),
    ("car.A0", R, "parameter", "Real", "N/kN"),
    ("car.A1", R, "parameter", "Real", "N/kN/(m/s)"),
    ("car.A2", R, "parameter", "Real", "N/kN/(m/s)²"),
    ("car.speed", R, "output", "Real", "m/s"),
    ("car.position", R, "output", "Real", "m"),
    ("car.acceleration", R, "output", "Real", "m/s²"),
    ("car.traction_force", R, "output", "Real", "N"),
    ("car.brake_force", R, "output", "Real", "N"),
    ("car.grade", R, "output", "Real", "‰"),
    ("car.mode", R, "output", "Integer", None),
    ("sensor.speed", R, "output", "Real", "m/s"),
    ("sensor.position", R, "output", "Real", "m"),
    ("sensor.speed_std", BOTH, "parameter", "Real", "m/s"),
    ("sensor.position_std", BOTH, "parameter", "Real", "m"),
    ("seed", R, "parameter", "Integer", None),
    # RailCarEstimator
    ("traction_force", E, "input", "Real", "N"),
    ("brake_force", E, "input", "Real", "N"),
    ("sensor.speed", E, "input", "Real", "m/s"),
    ("sensor.position", E, "input", "Real", "m"),
    # estimator outputs (both)
    ("est.mass", BOTH, "output", "Real", "t"),
    ("est.mass_std", BOTH, "output", "Real", "t"),
    ("est.A0", BOTH, "output", "Real", "N/kN"),
    ("est.A1", BOTH, "output", "Real", "N/kN/(m/s)"),
    ("est.A2", BOTH, "output", "Real", "N/kN/(m/s)²"),
    ("est.sigma2", BOTH, "output", "Real", "(m/s)²"),
    ("filter.speed", BOTH, "output", "Real", "m/s"),
    ("filter.position", BOTH, "output", "Real", "m"),
    ("filter.speed_std", BOTH, "output", "Real", "m/s"),
    ("filter.position_std", BOTH, "output", "Real", "m"),
    # AtoController: the estimator's outputs in, RailCar's demands out, by the same names
    ("filter.speed", A, "input", "Real", "m/s"),
    ("filter.position", A, "input", "Real", "m"),
    ("filter.speed_std", A, "input", "Real", "m/s"),
    ("est.mass", A, "input", "Real", "t"),
    ("est.A0", A, "input", "Real", "N/kN"),
    ("est.status", A, "input", "Integer", None),
    ("span.stop", A, "parameter", "Real", "m"),
    ("span.schedule", A, "parameter", "Real", "s"),
    ("span.grade_profile", A, "parameter", "String", None),
    ("car.mass", A, "parameter", "Real", "t"),
    ("traction_force_demand", A, "output", "Real", "N"),
    ("brake_force_demand", A, "output", "Real", "N"),
    ("ato.planned_speed", A, "output", "Real", "m/s"),
    ("ato.mode", A, "output", "Integer", None),
]

# contract unit -> (name in modelDescription.xml, SI exponents, factor to SI)
CONTRACT_UNITS = {
    "s": ("s", {"s": 1}, 1.0),
    "N": ("N", {"kg": 1, "m": 1, "s": -2}, 1.0),
    "m": ("m", {"m": 1}, 1.0),
    "m/s": ("m/s", {"m": 1, "s": -1}, 1.0),
    "m/s²": ("m/s2", {"m": 1, "s": -2}, 1.0),
    "(m/s)²": ("m2/s2", {"m": 2, "s": -2}, 1.0),
    "t": ("t", {"kg": 1}, 1000.0),
    "‰": ("permille", {}, 1e-3),
    "N/kN": ("N/kN", {}, 1e-3),
    "N/kN/(m/s)": ("N/kN/(m/s)", {"m": -1, "s": 1}, 1e-3),
    "N/kN/(m/s)²": ("N/kN/(m/s)2", {"m": -2, "s": 2}, 1e-3),
}

# physics of every unit the FMUs may declare (not only the contract's)
KNOWN_UNITS = {name: (exps, factor) for name, exps, factor in CONTRACT_UNITS.values()}
KNOWN_UNITS.update({"W": ({"kg": 1, "m": 2, "s": -3}, 1.0), "m2/s3": ({"m": 2, "s": -3}, 1.0),
                    "1/s": ({"s": -1}, 1.0), "1/s2": ({"s": -2}, 1.0), "1": ({}, 1.0),
                    # the A's covariances: (N/kN)^2 = 1e-6, times (m/s)^-k
                    "(N/kN)2/(m/s)": ({"m": -1, "s": 1}, 1e-6), "(N/kN)2/(m/s)2": ({"m": -2, "s": 2}, 1e-6),
                    "(N/kN)2/(m/s)3": ({"m": -3, "s": 3}, 1e-6)})

SI = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


def base_unit_of(md, unit_name: str):
    units = {u.name: u for u in md.unitDefinitions}
    assert unit_name in units, f"unit {unit_name!r} is not declared in UnitDefinitions"
    bu = units[unit_name].baseUnit
    assert bu is not None, f"unit {unit_name!r} has no BaseUnit"
    return {k: getattr(bu, k) for k in SI if getattr(bu, k)}, bu.factor, bu.offset


# ------------------------------------------------------------------------------------ tests

@pytest.mark.parametrize("name", FMU_NAMES)
def test_validate_fmu_reports_no_problem(built_fmus, name):
    problems = list(validate_fmu(str(built_fmus[name])))
    assert problems == [], f"{name}: validate_fmu found problems:\n" + "\n".join(problems)


@pytest.mark.parametrize("name, fmi", [("RailCarNative", "2.0"), ("RailCarEstimatorNative", "2.0"),
                                       ("RailCarNative3", "3.0"), ("RailCarEstimatorNative3", "3.0")])
def test_build_writes_the_native_fmus_beside_and_validates_them(built_fmus, name, fmi):
    """build.py also writes dist/native/ (docs/native_fmus.md): the native FMUs, each validated
    by fmpy, with the same variables as their pythonfmu twin (their own tests compare outputs)."""
    path = built_fmus["RailCar"].parent / "native" / f"{name}.fmu"
    assert path.is_file(), f"build.py did not write {path}"
    assert list(validate_fmu(str(path))) == []
    md = read_model_description(str(path))
    assert md.fmiVersion == fmi
    twin = read_model_description(str(built_fmus[name.replace("Native3", "").replace("Native", "")]))
    names = {v.name: v.valueReference for v in twin.modelVariables}
    native = {v.name: v.valueReference for v in md.modelVariables if v.name != "time"}
    assert native == names


@pytest.mark.parametrize("name", FMU_NAMES)
def test_built_fmu_bundles_the_c_core(built_fmus, name):
    """build.py bundles the models folder as it is, so the C core that pip install -e . built in
    place (models/_railcar*.so) travels in the FMU, with its sources (models/_railcar.c and
    models/core/*.c, *.h): the FMU runs the C chain where it covers the configuration."""
    with zipfile.ZipFile(built_fmus[name]) as z:
        names = set(z.namelist())
    assert any(n.startswith("resources/models/_railcar") and n.endswith(".so") for n in names), \
        f"{name}.fmu lacks the compiled core models/_railcar*.so"
    assert "resources/models/_railcar.c" in names
    core = sorted(p.name for p in (ROOT / "models" / "core").iterdir() if p.suffix in (".c", ".h"))
    missing = [c for c in core if f"resources/models/core/{c}" not in names]
    assert len(core) >= 20 and not missing, f"{name}.fmu lacks models/core/{missing}"


@pytest.mark.parametrize("name", FMU_NAMES)
def test_every_real_has_a_declared_unit_with_a_consistent_base_unit(fmus, name):
    md = fmus[name].md
    declared = {u.name for u in md.unitDefinitions}
    for v in md.modelVariables:
        if v.type == "Real":
            assert v.unit, f"{name}: Real {v.name} has no unit"
            assert v.unit in declared, f"{name}: {v.name} unit {v.unit!r} not in UnitDefinitions"
    for unit in declared:
        assert unit in KNOWN_UNITS, f"{name}: unexpected unit {unit!r}"
        exps, factor, offset = base_unit_of(md, unit)
        assert (exps, offset) == (KNOWN_UNITS[unit][0], 0.0), f"{name}: BaseUnit of {unit!r}"
        assert factor == pytest.approx(KNOWN_UNITS[unit][1], rel=1e-12), f"{name}: factor of {unit!r}"


@pytest.mark.parametrize("name", FMU_NAMES)
def test_contract_variables_exist_with_the_contract_units(fmus, name):
    md = fmus[name].md
    assert md.variableNamingConvention == "structured"
    variables = fmus[name].variables
    expected = [c for c in CONTRACT if name in c[1]]
    assert expected
    errors = []
    for var_name, _, causality, typ, unit in expected:
        v = variables.get(var_name)
        if v is None:
            errors.append(f"{var_name}: missing")
            continue
        if v.causality != causality:
            errors.append(f"{var_name}: causality {v.causality}, contract {causality}")
        if v.type != typ:
            errors.append(f"{var_name}: type {v.type}, contract {typ}")
        if not v.description:
            errors.append(f"{var_name}: no description")
        if var_name.startswith("track."):
            if v.variability != "fixed":
                errors.append(f"{var_name}: variability {v.variability}, contract fixed")
        if unit is None:
            if typ == "Real":
                errors.append(f"{var_name}: Real without contract unit")  # pragma: no cover
            continue
        md_name, exps, factor = CONTRACT_UNITS[unit]
        if v.unit != md_name:
            errors.append(f"{var_name}: unit {v.unit!r}, contract {unit!r} (= {md_name!r})")
            continue
        got_exps, got_factor, _ = base_unit_of(md, v.unit)
        if got_exps != exps or abs(got_factor - factor) > 1e-12 * factor:
            errors.append(f"{var_name}: BaseUnit {got_exps} x{got_factor}, contract {exps} x{factor}")
    assert not errors, f"{name} breaks the contract:\n" + "\n".join(errors)


@pytest.mark.parametrize("name", FMU_NAMES)
def test_default_experiment(fmus, name):
    de = fmus[name].md.defaultExperiment
    assert de is not None, f"{name}: no DefaultExperiment"
    assert float(de.startTime) == 0.0
    assert float(de.stopTime) > float(de.startTime)
    assert float(de.stepSize) > 0.0


def test_guid_is_reproducible_and_follows_the_sources(built_fmus, tmp_path):
    """Same sources => same GUID (two more builds, other folders); changed source => new GUID."""
    first = build_fmus(tmp_path / "a", native=False)
    second = build_fmus(tmp_path / "b", native=False)
    guids = {}
    for name in FMU_NAMES:
        g = {read_model_description(str(paths[name])).guid for paths in (built_fmus, first, second)}
        assert len(g) == 1, f"{name}: GUID differs between builds of the same sources: {g}"
        guids[name] = g.pop()
    assert guids["RailCar"] != guids["RailCarEstimator"]

    # A copy of the project elsewhere with one source file touched gets another GUID
    copy = tmp_path / "project"
    copy.mkdir()
    shutil.copy2(ROOT / "build.py", copy / "build.py")
    for folder in ("fmu_src", "models", "scenarios"):
        shutil.copytree(ROOT / folder, copy / folder, ignore=shutil.ignore_patterns("__pycache__"))
    noise = copy / "models" / "plant" / "noise.py"
    noise.write_text(noise.read_text() + "\n# touched\n")
    proc = subprocess.run([sys.executable, "build.py", "--dest", str(tmp_path / "c"), "--no-native"],
                          cwd=copy,
                          env=dict(os.environ, PYTHONDONTWRITEBYTECODE="1"),
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    for name in FMU_NAMES:
        touched = read_model_description(str(tmp_path / "c" / f"{name}.fmu")).guid
        assert touched != guids[name], f"{name}: GUID did not change with the sources"


# A fresh interpreter (cwd outside the project, no PYTHONPATH) loads the FMU, runs it and reports
# where its Python modules and the C core (models._railcar) came from. In the pytest process
# other test files import the source tree's ``models``/``fmu_src`` at collection, and an FMU
# instance created afterwards silently reuses those cached modules instead of its bundled
# copies; this test checks the bundle itself.
_FRESH_RUN = r"""
import pythonfmu, json, sys, fmpy
unzipdir, start_values, outputs = sys.argv[1], json.loads(sys.argv[2]), json.loads(sys.argv[3])
r = fmpy.simulate_fmu(unzipdir, stop_time=10.0, output_interval=0.1, start_values=start_values,
                      output=outputs)
print(json.dumps({"modules": {m: sys.modules[m].__file__ for m in ("models", "models.chain",
                                                                   "models._railcar", "models.ato.controller",
                                                                   "fmu_src.adapter")
                              if m in sys.modules},
                  "time": r["time"].tolist(), "values": {n: r[n].tolist() for n in outputs}}))
"""

FRESH_CASES = {
    "RailCar": ({"traction_force_demand": 30e3, "car.mass": 36.0, "seed": 5},
                ["car.speed", "sensor.speed", "est.mass", "filter.speed"]),
    "RailCarEstimator": ({"traction_force": 20e3, "sensor.speed": 1.0, "sensor.position": 5.0},
                         ["est.mass", "filter.speed", "filter.position"]),
    # a car at 10 m/s seen by the controller: it brakes or holds towards its plan
    "AtoController": ({"filter.speed": 10.0, "filter.position": 100.0, "span.schedule": 140.0},
                      ["traction_force_demand", "brake_force_demand", "ato.planned_speed"]),
}


@pytest.mark.parametrize("name", FMU_NAMES)
def test_fmu_runs_its_bundled_code_in_a_fresh_process(fmus, name, tmp_path):
    fmu = fmus[name]
    start_values, outputs = FRESH_CASES[name]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run([sys.executable, "-c", _FRESH_RUN, fmu.unzipdir, json.dumps(start_values),
                           json.dumps(outputs)], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    fresh = json.loads(proc.stdout.strip().splitlines()[-1])
    resources = Path(fmu.unzipdir, "resources").resolve()
    assert {"models", "fmu_src.adapter"} <= set(fresh["modules"])
    for module, file in fresh["modules"].items():
        assert Path(file).resolve().is_relative_to(resources), \
            f"{name}: {module} was loaded from {file}, not from the FMU's resources/"
    assert fresh["time"][-1] == pytest.approx(10.0, abs=1e-9)
    # in this process (possibly on the source tree's cached modules): the very same numbers
    here = fmpy.simulate_fmu(fmu.unzipdir, model_description=fmu.md, stop_time=10.0,
                             output_interval=0.1, start_values=start_values, output=outputs)
    for n in outputs:
        assert fresh["values"][n] == here[n].tolist(), f"{name}: {n} differs from the bundle's"


# ------------------------------------------------------- packaging: fmu_src/build, one writer

NATIVE_FMUS = {"RailCarNative": ("RailCar", 2), "RailCarEstimatorNative": ("RailCarEstimator", 2),
               "RailCarNative3": ("RailCar", 3), "RailCarEstimatorNative3": ("RailCarEstimator", 3)}


def _xml(fmu: Path) -> bytes:
    with zipfile.ZipFile(fmu) as z:
        return z.read("modelDescription.xml")


@pytest.mark.parametrize("name", FMU_NAMES)
def test_pythonfmu_fmu_carries_the_writers_description(built_fmus, name):
    """Byte for byte what fmu_src.build.model_description.fmi2 writes from the table, with the
    GUID of today's sources (the time stamp is the build's)."""
    shipped = _xml(built_fmus[name])
    stamp = ET.fromstring(shipped).get("generationDateAndTime")
    expected = model_description.fmi2(name, pythonfmu_fmus.source_guid(name),
                                      pythonfmu_fmus.generation_tool(), generated_at=stamp)
    assert shipped == expected


@pytest.mark.parametrize("native_name", NATIVE_FMUS)
def test_native_fmu_carries_the_writers_description(built_fmus, native_name):
    name, fmi = NATIVE_FMUS[native_name]
    spec = {s.fmu: s for s in native.SPECS}[name]
    shipped = _xml(built_fmus[name].parent / "native" / f"{native_name}.fmu")
    if fmi == 2:
        stamp = ET.fromstring(shipped).get("generationDateAndTime")
        guid = native.native_guid(_xml(built_fmus[name]), spec)
        expected = model_description.fmi2(
            name, guid, native.GENERATION_TOOL, needs_execution_tool=False,
            source_files=tuple(p.name for p in native.c_sources(spec)), generated_at=stamp)
    else:
        expected = model_description.fmi3(name, native_fmi3.instantiation_token(spec),
                                          native_fmi3.GENERATION_TOOL)
    assert shipped == expected


@pytest.mark.parametrize("name", ("RailCar", "RailCarEstimator"))
def test_native_fmi2_description_is_the_pythonfmu_one_but_for_what_says_native(built_fmus, name):
    """A host swaps the file and nothing else: canonically the same XML once the GUID, time
    stamp, generationTool, needsExecutionTool and SourceFiles are set aside."""
    native_name = {"RailCar": "RailCarNative", "RailCarEstimator": "RailCarEstimatorNative"}[name]

    def canonical(xml: bytes) -> tuple[str, dict]:
        root = ET.fromstring(xml)
        own = {k: root.attrib.pop(k) for k in ("guid", "generationDateAndTime", "generationTool")}
        cosim = root.find("CoSimulation")
        own["needsExecutionTool"] = cosim.attrib.pop("needsExecutionTool")
        own["FMUstate"] = (cosim.attrib.pop("canGetAndSetFMUstate"),
                           cosim.attrib.pop("canSerializeFMUstate"))
        own["SourceFiles"] = [f.get("name") for f in cosim.iter("File")]
        for files in cosim.findall("SourceFiles"):
            cosim.remove(files)
        cosim.text = None
        return ET.canonicalize(ET.tostring(root, encoding="unicode"), strip_text=True), own

    python_xml, python_own = canonical(_xml(built_fmus[name]))
    native_xml, native_own = canonical(_xml(built_fmus[name].parent / "native" / f"{native_name}.fmu"))
    assert native_xml == python_xml
    assert (python_own["needsExecutionTool"], native_own["needsExecutionTool"]) == ("true", "false")
    assert (python_own["FMUstate"], native_own["FMUstate"]) == (("false", "false"), ("true", "true"))
    assert python_own["SourceFiles"] == [] and "native_common.c" in native_own["SourceFiles"]
    assert native_own["guid"] != python_own["guid"]


@pytest.mark.parametrize("fmu", FMU_NAMES)
def test_the_fmi2_writer_follows_the_variable_table(fmu):
    """Every row of fmu_src/variables.py at its value reference: causality, variability,
    initial, type, exact start (repr round-trips the double), unit and bounds; calculated
    outputs are initial unknowns; AtoController's outputs have no direct feedthrough."""
    table = variables_for(fmu)
    root = ET.fromstring(model_description.fmi2(fmu, "{guid}", "test", generated_at="2000-01-01T00:00:00+00:00"))
    assert (root.get("guid"), root.get("generationDateAndTime")) == ("{guid}", "2000-01-01T00:00:00+00:00")
    svs = list(root.find("ModelVariables"))
    assert [sv.get("name") for sv in svs] == [v.name for v in table]
    for vr, (sv, v) in enumerate(zip(svs, table)):
        assert sv.get("valueReference") == str(vr)
        assert (sv.get("causality"), sv.get("variability")) == (v.causality, v.variability), v.name
        assert sv.get("initial") == (v.initial if v.causality == "output" else None), v.name
        (typed,) = list(sv)
        assert typed.tag == v.type, v.name
        if v.causality == "output" and v.initial == "calculated":
            assert typed.get("start") is None, v.name
        elif v.type == "Real":
            assert float(typed.get("start")) == v.start, v.name
        elif v.type == "Boolean":
            assert typed.get("start") == ("true" if v.start else "false"), v.name
        else:
            assert typed.get("start") == str(v.start), v.name
        if v.type == "Real":
            assert typed.get("unit") == v.unit, v.name
            for bound in ("min", "max"):
                want = getattr(v, bound)
                assert (None if typed.get(bound) is None else float(typed.get(bound))) == want, v.name
    units = {u.get("name"): u.find("BaseUnit").attrib for u in root.find("UnitDefinitions")}
    assert set(units) == {v.unit for v in table if v.type == "Real" and v.unit}
    for unit, base in units.items():
        exponents, factor = UNITS[unit]
        assert {k: int(e) for k, e in base.items() if k != "factor"} == exponents, unit
        assert float(base.get("factor", "1.0")) == factor, unit
    structure = root.find("ModelStructure")
    outputs = [vr + 1 for vr, v in enumerate(table) if v.causality == "output"]
    unknowns = list(structure.find("Outputs"))
    assert [int(u.get("index")) for u in unknowns] == outputs
    assert all((u.get("dependencies") == "") == (fmu == "AtoController") for u in unknowns)
    calculated = [vr + 1 for vr, v in enumerate(table) if v.causality == "output" and v.initial == "calculated"]
    initial = structure.find("InitialUnknowns")
    assert [int(u.get("index")) for u in ([] if initial is None else initial)] == calculated


@pytest.mark.parametrize("fmu", ("RailCar", "RailCarEstimator"))
def test_the_fmi3_writer_follows_the_variable_table(fmu):
    """The FMI 2 value references, FMI 3 types, start values on parameters and inputs only,
    "time" after the table, every output an Output and an InitialUnknown."""
    table = variables_for(fmu)
    root = ET.fromstring(model_description.fmi3(fmu, "{token}", "test"))
    assert root.get("instantiationToken") == "{token}"
    variables = list(root.find("ModelVariables"))
    assert [v.get("name") for v in variables] == [v.name for v in table] + ["time"]
    assert [int(v.get("valueReference")) for v in variables] == list(range(len(table) + 1))
    assert variables[-1].get("causality") == "independent"
    fmi3_type = {"Real": "Float64", "Integer": "Int32", "String": "String"}
    for el, v in zip(variables, table):
        assert el.tag == fmi3_type[v.type], v.name
        if v.causality == "output":
            assert (el.get("initial"), el.get("start")) == ("calculated", None), v.name
        elif v.type == "String":
            assert el.find("Start").get("value") == v.start, v.name
        else:
            assert float(el.get("start")) == v.start, v.name
    outputs = [str(vr) for vr, v in enumerate(table) if v.causality == "output"]
    structure = root.find("ModelStructure")
    assert [o.get("valueReference") for o in structure.findall("Output")] == outputs
    assert [o.get("valueReference") for o in structure.findall("InitialUnknown")] == outputs


def test_a_slave_that_registers_other_variables_than_the_table_is_refused():
    """The binary runs what the slave registered, the description says what the table says:
    check_pythonfmu_description names the first difference."""
    good = model_description.fmi2("RailCar", "{g}", "test")
    model_description.check_pythonfmu_description(good, "RailCar", "RailCar.fmu")   # no error
    root = ET.fromstring(good)
    mv = root.find("ModelVariables")
    mv[3].set("name", "car.renamed")
    with pytest.raises(RuntimeError, match=r"RailCar.fmu: the slave registers \('car.renamed'.* at value "
                                           r"reference 3, fmu_src/variables.py has \('car.payload'"):
        model_description.check_pythonfmu_description(ET.tostring(root), "RailCar", "RailCar.fmu")
    mv[3].set("name", "car.payload")
    last = len(mv) - 1
    mv.remove(mv[last])                                    # one variable fewer than the table
    with pytest.raises(RuntimeError, match=f"registers nothing at value reference {last}, "
                                           rf"fmu_src/variables.py has \('{variables_for('RailCar')[-1].name}'"):
        model_description.check_pythonfmu_description(ET.tostring(root), "RailCar", "RailCar.fmu")
    with pytest.raises(RuntimeError, match="modelIdentifier is not RailCarEstimator"):
        model_description.check_pythonfmu_description(good, "RailCarEstimator", "RailCar.fmu")


def test_a_native_build_alone_builds_its_pythonfmu_twin_only_when_stale(built_fmus, tmp_path, monkeypatch):
    """``python -m fmu_src.build.native --build D`` takes dist/'s pythonfmu FMU: current (the
    session build) it is used as it is; missing, build.py builds the pythonfmu FMUs alone."""
    runs = []
    monkeypatch.setattr(dist, "run_build", lambda folder, native=True: runs.append((folder, native)))
    current = built_fmus["RailCar"].parent
    assert dist.current_pythonfmu("RailCar", current) == current / "RailCar.fmu" and runs == []
    assert dist.current_pythonfmu("RailCar", tmp_path) == tmp_path / "RailCar.fmu"
    assert runs == [(tmp_path, False)]


PACKAGING_MODULES = ("fmu_src.build.cli", "fmu_src.build.dist", "fmu_src.build.model_description",
                     "fmu_src.build.native", "fmu_src.build.native_fmi3",
                     "fmu_src.build.pythonfmu_fmus", "fmu_src.build.toolchain")


def test_packaging_imports_no_harness():
    """Layers: models <- fmu_src <- harness. A fresh interpreter imports every packaging module
    (and runs native's header generation, which reaches models.compiled) without the harness."""
    code = ("import importlib, sys\n"
            f"for m in {PACKAGING_MODULES!r}: importlib.import_module(m)\n"
            "from fmu_src.build import native\n"
            "native.generate_header(native.RAILCAR_SPEC)\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'harness'))\n")
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "[]"


def test_build_py_is_imported_by_no_one():
    """build.py is a command line; code reaches packaging as the module fmu_src.build, never by
    loading build.py from its path (two module names for one file) or importing it."""
    by_path = re.compile(r'spec_from_file_location\([^\n]*"build\.py"')
    by_name = re.compile(r"^\s*(import build|from build import)\b", re.M)
    offenders = [str(path.relative_to(ROOT))
                 for folder in ("fmu_src", "harness", "tests", "benchmarks", "studies")
                 for path in (ROOT / folder).rglob("*.py")
                 if by_path.search(text := path.read_text(encoding="utf-8")) or by_name.search(text)]
    assert offenders == []
    assert not (ROOT / "fmu_src" / "native.py").exists() and not (ROOT / "fmu_src" / "native_fmi3.py").exists()


def test_gitignore_ignores_only_the_top_level_build_folder():
    """An unanchored "build/" would ignore fmu_src/build/, the packaging package itself."""
    lines = [line.strip() for line in (ROOT / ".gitignore").read_text().splitlines()]
    assert "/build/" in lines and "build/" not in lines and "build" not in lines
