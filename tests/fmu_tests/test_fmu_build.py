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
import zipfile
from pathlib import Path

import fmpy
import pytest
from fmpy import read_model_description
from fmpy.validation import validate_fmu

from conftest import FMU_NAMES, ROOT, build_fmus

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
