"""Value references are a contract with our users' models (fmu_src/variables.py: "they never
change"): every FMU the build makes keeps each variable's value reference, causality,
variability, type and unit as frozen in value_references.json.

The FMU test reads the session build (conftest's ``built_fmus``: the pythonfmu FMUs and, beside
them in native/, the native FMI 2 and FMI 3 ones); the unit test checks the variable table
itself against the same file, so that the fast layer notices a reordered table too. The frozen
file changes only through fmu_src/build/value_references.py (see its docstring for the policy).
"""
from __future__ import annotations

import copy

import pytest

from fmu_src.build.value_references import COMMAND, FMU_FILES, INDEPENDENT, compare, load_frozen, read_build
from fmu_src.variables import ATO, ESTIMATOR, RAILCAR, variables_for

POLICY = (f"Value references are a contract with users' models: a change is only allowed as a "
          f"documented, appended addition (a new variable after the existing ones, with a "
          f"CHANGELOG.md entry), then frozen with: {COMMAND}")

TABLE_OF = {"RailCar": RAILCAR, "RailCarNative": RAILCAR, "RailCarNative3": RAILCAR,
            "RailCarEstimator": ESTIMATOR, "RailCarEstimatorNative": ESTIMATOR,
            "RailCarEstimatorNative3": ESTIMATOR, "AtoController": ATO, "AtoControllerNative": ATO,
            "AtoControllerNative3": ATO}
"""Which FMU of fmu_src/variables.py each built FMU describes."""


def _failure(breaking: list[str], added: list[str]) -> str:
    parts = []
    if breaking:
        parts.append(f"{len(breaking)} frozen variable(s) changed or removed:\n  " + "\n  ".join(breaking))
    if added:
        parts.append(f"{len(added)} variable(s) not frozen yet:\n  " + "\n  ".join(added))
    return "\n".join(parts) + "\n" + POLICY


def test_the_frozen_file_covers_every_fmu_the_build_makes():
    assert set(load_frozen()) == set(FMU_FILES) == set(TABLE_OF)


def test_built_fmus_keep_their_frozen_value_references(built_fmus):
    dist = built_fmus["RailCar"].parent     # build.py writes the native FMUs into dist/native/
    breaking, added, _time_moved = compare(load_frozen(), read_build(dist))
    assert not breaking and not added, _failure(breaking, added)


def test_the_variable_table_keeps_the_frozen_value_references():
    """The builds number each FMU's variables in the table's order (fmu_src.variables.variables_for):
    the table alone must give the frozen name -> value reference and causality."""
    breaking, added = [], []
    for fmu, frozen in load_frozen().items():
        table = {v.name: {"vr": vr, "causality": v.causality} for vr, v in enumerate(variables_for(TABLE_OF[fmu]))}
        kept = {name: {"vr": e["vr"], "causality": e["causality"]}
                for name, e in frozen.items() if e["causality"] != INDEPENDENT}
        for name in kept.keys() - table.keys():
            breaking.append(f"{fmu}: {name} is no longer in fmu_src/variables.py")
        for name in kept.keys() & table.keys():
            if kept[name] != table[name]:
                breaking.append(f"{fmu}: {name} frozen as {kept[name]}, the table now gives {table[name]}")
        added += [f"{fmu}: {name} ({table[name]})" for name in table.keys() - kept.keys()]
    assert not breaking and not added, _failure(sorted(breaking), sorted(added))


# ------------------------------------------------------------------ the comparison itself

def _entry(vr: int, causality: str = "output", type_name: str = "Float64", unit: str | None = "m") -> dict:
    return {"vr": vr, "causality": causality, "variability": "continuous", "type": type_name, "unit": unit}


FROZEN_FMI3 = {"F": {"a": _entry(0), "b": _entry(1), "time": _entry(2, INDEPENDENT, unit="s")}}


def test_an_appended_variable_is_an_addition_and_moves_time_as_expected():
    built = copy.deepcopy(FROZEN_FMI3)
    built["F"]["c"] = _entry(2)
    built["F"]["time"]["vr"] = 3
    breaking, added, moved = compare(FROZEN_FMI3, built)
    assert breaking == []
    assert added == ["F: c added (vr 2, causality output, variability continuous, type Float64, unit m)"]
    assert moved == ["F: time value reference 2 -> 3 (expected: it sits after the table)"]


def test_swapped_variables_are_named_with_their_old_and_new_value_references():
    built = copy.deepcopy(FROZEN_FMI3)
    built["F"]["a"]["vr"], built["F"]["b"]["vr"] = 1, 0
    breaking, added, moved = compare(FROZEN_FMI3, built)
    assert breaking == ["F: a vr 0 -> 1", "F: b vr 1 -> 0"]
    assert added == moved == []


@pytest.mark.parametrize("change, expected", [
    (lambda f: f.pop("b"), "F: b removed (was vr 1, causality output, variability continuous, type Float64, unit m)"),
    (lambda f: f["b"].update(unit="km"), "F: b unit 'm' -> 'km'"),
    (lambda f: f["b"].update(causality="input"), "F: b causality 'output' -> 'input'"),
    (lambda f: f["time"].update(vr=0), "F: time vr 2 -> 0"),     # time must stay after the table
    (lambda f: f.update(n=_entry(1)), "F: n added at value reference 1, inside the frozen range (up to 1): "
                                      "a new variable must be appended"),
])
def test_a_removed_changed_or_inserted_variable_is_breaking(change, expected):
    built = copy.deepcopy(FROZEN_FMI3)
    change(built["F"])
    breaking, _added, _moved = compare(FROZEN_FMI3, built)
    assert expected in breaking
