"""The scenario library against its stored cross-check references, and issue 3's targets.

All library scenarios run once per session on the freshly built RailCar (fixture), then:
each matches its reference (explicit tolerances + fmpy's band test), the stored inputs are
those the driver applied, and every target of the library table is met. The span scenarios
(scenarios/library/ato_*.toml: the ATO in closed loop on the FMU) are among them: their
inputs are the ATO's demands, and the ATO's targets are checked on every span.
The references hold every output of the RailCar FMU (harness.run.regress.reference_outputs, from
the model description's table); a reference lacking one fails, naming the columns and the command.
The tests below also pin the tooling: tolerances for every output, exact integers, and --update
writing a file only when its content changes and saying what changed.

pytest only checks. To regenerate after a deliberate change (e.g. to models/ato/: 'ato_*'):
    python -m harness regress --update [NAME ...]
"""
from dataclasses import replace

import numpy as np
import pytest

from harness.reports.library_report import library_rows
from fmpy import read_model_description

from harness.run import regress
from harness.run.regress import (EXACT, FLOAT_TOLERANCES, check_or_update, compare, describe_csv_change,
                                 library_scenarios, read_inputs, reference_outputs, tolerance,
                                 write_reference)
from harness.run.runner import INPUTS, FmuRunner
from harness.run.scenario import load_scenario

NAMES = [p.stem for p in library_scenarios()]
LIBRARY_PATHS = {p.stem: p for p in library_scenarios()}


@pytest.fixture(scope="module")
def library_results(built_fmus):
    with FmuRunner(built_fmus["RailCar"]) as runner:
        return {p.stem: runner.run(load_scenario(p)) for p in library_scenarios()}


def test_library_has_at_least_eight_scenarios_each_with_a_purpose():
    assert len(NAMES) >= 8
    for p in library_scenarios():
        assert load_scenario(p).purpose.strip(), p


@pytest.mark.parametrize("name", NAMES)
def test_scenario_matches_its_reference(library_results, name):
    c = compare(library_results[name])
    assert c.ok, "\n".join(c.problems)


@pytest.mark.parametrize("name", NAMES)
def test_stored_inputs_are_what_the_driver_applied(library_results, name):
    """_in.csv holds the zero-order-hold inputs: at each row time, the last value written."""
    result = library_results[name]
    stored = read_inputs(name)
    t = stored["time"]
    for n in INPUTS:
        # value in force on [t_k, t_k+1): the last stored row with time <= t_k
        idx = np.searchsorted(t, result.time, side="right") - 1
        # closed-loop demands follow the truth, so they share the outputs' tolerance (1e-6 rel.)
        np.testing.assert_allclose(stored[n][idx], result.inputs[n], rtol=1e-6, atol=1e-6,
                                   err_msg=f"{name}: {n}")


def test_a_deliberate_model_change_fails_naming_scenario_and_signal(built_fmus):
    """A 10 % change of car.A0 in level_run is caught, and the message says where."""
    s = load_scenario(next(p for p in library_scenarios() if p.stem == "level_run"))
    changed = replace(s, parameters={**s.parameters, "car.A0": 1.1 * s.parameter("car.A0")})
    with FmuRunner(built_fmus["RailCar"]) as runner:
        c = compare(runner.run(changed))
    assert not c.ok
    assert any(p.startswith("level_run: car.speed:") for p in c.problems), c.problems


# The library targets the default estimator (est.method 2) does not meet, each with the bound it
# is held to instead (measured, docs/estimation.md): a 12 m/s headwind rising mid-run moves A1 to
# 2.5 sigma of its prior, est.forgetting forgets the data but not the prior, and the mass takes up
# the difference: 1.44 % at the stop of seed 13. Over seeds 1-30 the default misses 1 % in 11, the
# former default in 12 (0.06 % on seed 13 was its luck): test_headwind_change_gap_is_no_worse_...
KNOWN_GAPS = {"headwind_change": ("mass", 1.5)}
"""scenario -> (its missed target, the largest mass error at a stop [%] allowed meanwhile)."""


HEADWIND_SEEDS = range(1, 31)


def _headwind_stop_errors(overrides: dict) -> np.ndarray:
    """headwind_change on the models chain (the C core where built) for seeds 1..30: the mass
    error at the stop [%] and |error| / est.mass_std there [-], per seed."""
    from harness.run.driver import drive_chain
    scenario = load_scenario(LIBRARY_PATHS["headwind_change"])
    rows = []
    for seed in HEADWIND_SEEDS:
        out = drive_chain(scenario.chain_setup({**overrides, "seed": seed}).open(), scenario)
        k = max(i for i in range(1, len(out)) if out[i]["car.speed"] <= 0.0 < out[i - 1]["car.speed"])
        err = out[k]["est.mass"] - out[k]["car.total_mass"]
        rows.append((100.0 * err / out[k]["car.total_mass"], abs(err) / out[k]["est.mass_std"]))
    return np.array(rows)


def test_headwind_change_gap_is_no_worse_than_the_former_default_over_seeds():
    """KNOWN_GAPS' headwind_change is one draw: over seeds 1..30 the default misses 1 % at the
    stop in no more seeds than the former default (the paper's scheme, 0.06 % on seed 13 by
    luck), its median error is within 1 %, and its stated sigma covers every error within 3."""
    from fmu_src.variables import FORMER_DEFAULTS
    today, former = _headwind_stop_errors({}), _headwind_stop_errors(FORMER_DEFAULTS)
    misses_today = int(np.sum(np.abs(today[:, 0]) > 1.0))
    misses_former = int(np.sum(np.abs(former[:, 0]) > 1.0))
    assert misses_today <= misses_former, (misses_today, misses_former)
    assert np.median(np.abs(today[:, 0])) <= 1.0, today[:, 0]
    assert today[:, 1].max() <= 3.0, today[:, 1]
    print(f"headwind_change seeds 1-30: > 1 % in {misses_today} (former {misses_former}); "
          f"median {np.median(np.abs(today[:, 0])):.2f} %; worst |err|/sigma {today[:, 1].max():.2f}")


def test_library_targets_met(library_results):
    """Speed noise <= 0.05 m/s: mass within 1 % at every stop; filter RMSE <= 0.6x sensor's.
    A known gap (KNOWN_GAPS) misses only its own target, by no more than its bound, and the
    test says when it closes (so that it leaves the list)."""
    from harness.run.scenario import load_scenario as load
    rows = library_rows([(load(p), library_results[p.stem]) for p in library_scenarios()])
    checked = [r for r in rows if r.targets_apply]
    assert len(checked) >= 8
    failures = {r.name: r.checks for r in checked if not all(r.checks.values())}
    for name, (target, bound) in KNOWN_GAPS.items():
        row = next(r for r in checked if r.name == name)
        missed = {k for k, ok in row.checks.items() if not ok}
        assert missed == {target}, f"{name}: missed {missed}, KNOWN_GAPS says {target}: update it"
        failures.pop(name)
        worst = max(abs(e) for e in row.summary.mass_errors_at_stops_pct)
        assert worst <= bound, (name, worst)
    assert not failures, failures
    outputs = {o.name for o in reference_outputs()}
    assert all(outputs <= set(library_results[r.name].signals) for r in rows)


ATO_NAMES = [n for n in NAMES if n.startswith("ato_")]


def test_the_library_has_the_ato_scenarios():
    assert {"ato_nominal", "ato_mass_plus20", "ato_A0_plus50", "ato_headwind", "ato_wet_rail",
            "ato_speed_noise", "ato_line"} <= set(ATO_NAMES)


@pytest.mark.parametrize("name", ATO_NAMES)
def test_the_ato_scenario_meets_the_atos_targets(library_results, name):
    """Every span, on the FMU: arrived, |arrival error| <= 2.5 s, |stop error| <= 0.3 m, never
    over V_lim, no safety intervention (library_report's bounds, Meleshin 2011 and Sidorenko
    1997). The message gives the measured figures."""
    from harness.metrics.ato import format_ato
    (row,) = library_rows([(load_scenario(LIBRARY_PATHS[name]), library_results[name])])
    assert row.ato, name
    assert all(row.ato_checks.values()), (row.ato_checks, "\n" + format_ato(row.ato))


# ------------------------------------------------------------------------------ the tooling

def test_the_references_hold_every_output_of_the_model_description(built_fmus):
    """reference_outputs is the built FMU's list of outputs (all 29 today), integers marked."""
    md = read_model_description(str(built_fmus["RailCar"]))
    declared = {v.name: v.type for v in md.modelVariables if v.causality == "output"}
    outputs = reference_outputs()
    assert [o.name for o in outputs] == list(declared)
    assert len(outputs) >= 29
    assert {o.name for o in outputs if o.integer} == {n for n, t in declared.items() if t != "Real"}
    assert {"car.mode", "est.samples", "est.status", "filter.rejected"} <= {o.name for o in outputs if o.integer}


def test_every_output_has_a_tolerance_and_integers_are_exact():
    for o in reference_outputs():
        atol, rtol = tolerance(o)
        if o.integer:
            assert (atol, rtol) == EXACT == (0.0, 0.0), o
        else:
            assert 0 < atol <= 1e-2 and 0 < rtol <= 1e-5, o
    assert set(FLOAT_TOLERANCES) == {o.name for o in reference_outputs() if not o.integer}


def test_a_real_output_without_a_tolerance_says_where_to_add_one():
    with pytest.raises(KeyError, match="est.new_thing: .*FLOAT_TOLERANCES in harness/run/regress.py"):
        tolerance(regress.Output("est.new_thing", integer=False))


def _with_signal(result, name, values):
    return replace(result, signals={**result.signals, name: values})


def test_a_reference_lacking_columns_names_them_and_the_command(library_results, tmp_path):
    """An old reference (13 columns) fails on the missing outputs, saying how to regenerate."""
    result = library_results["level_run"]
    write_reference(result, tmp_path)
    path = tmp_path / "level_run_ref.csv"
    lines = path.read_text().splitlines()
    header = [n.strip('"') for n in lines[0].split(",")]
    drop = [header.index("est.samples"), header.index("car.acceleration")]
    path.write_text("\n".join(",".join(x for j, x in enumerate(line.split(",")) if j not in drop)
                              for line in lines) + "\n")
    c = compare(result, tmp_path)
    assert not c.ok
    assert ("level_run: reference lacks columns car.acceleration, est.samples; "
            "regenerate with python -m harness regress --update level_run") in c.problems, c.problems


def test_an_integer_output_off_by_one_fails_compared_exactly(library_results, tmp_path):
    result = library_results["level_run"]
    write_reference(result, tmp_path)
    assert compare(result, tmp_path).ok
    samples = result["est.samples"].copy()
    rows = regress.reference_rows(result)
    samples[rows[len(rows) // 2]] += 1                # in a stored row
    c = compare(_with_signal(result, "est.samples", samples), tmp_path)
    assert [p for p in c.problems if p.startswith("level_run: est.samples: 1 of ") and p.endswith("(exact)")], \
        c.problems


def test_update_writes_only_changed_files_and_says_what_changed(library_results, tmp_path):
    """A second write is "unchanged" and leaves the files alone; a last-bit change of one float is
    written and reported: file, column, rows, largest change, within tolerance."""
    result = library_results["level_run"]
    first = write_reference(result, tmp_path)
    assert [u.status for u in first] == ["new"] * 3
    stamps = {u.path: u.path.stat().st_mtime_ns for u in first}
    again = write_reference(result, tmp_path)
    assert [u.status for u in again] == ["unchanged"] * 3
    assert {u.path: u.path.stat().st_mtime_ns for u in again} == stamps

    speed = result["filter.speed"].copy()
    rows = regress.reference_rows(result)
    k = rows[len(rows) // 2]
    speed[k] = np.nextafter(speed[k], np.inf)         # one last-bit change in a stored row
    changed = write_reference(_with_signal(result, "filter.speed", speed), tmp_path)
    by_name = {u.path.name: u for u in changed}
    assert by_name["level_run_in.csv"].status == by_name["level_run_ref.opt"].status == "unchanged"
    ref = by_name["level_run_ref.csv"]
    assert ref.status == "changed"
    t = result.time[k]
    assert ref.changes[0] == (f"1 of {len(rows)} rows changed in 1 columns; largest change "
                              f"{abs(speed[k] - result['filter.speed'][k]):.3g} in filter.speed at t = {t:g} s, "
                              f"within its tolerance"), ref.changes
    assert ref.changes[1].startswith("changed: filter.speed (1 rows, max ")


def test_update_reports_beyond_tolerance_and_added_columns():
    old = '"time","car.speed","est.samples"\n0.0,1.0,0\n0.5,2.0,1\n'
    new = '"time","car.speed","est.samples","est.status"\n0.0,1.0,0,0\n0.5,2.5,2,1\n'
    assert describe_csv_change(old, new) == [
        "added 1 columns: est.status",
        "1 of 2 rows changed in 2 columns; largest change 1 in est.samples at t = 0.5 s, BEYOND its tolerance in 1 rows",
        "changed: est.samples (1 rows, max 1, 1 beyond tolerance), car.speed (1 rows, max 0.5, 1 beyond tolerance)"]
    assert describe_csv_change('"time","a"\n0.0,1.0\n', '"time","a"\n0.0,1.0\n0.5,1.0\n') == [
        "time grid changed: 1 rows -> 2 rows (last time 0.0 -> 0.5 s); values not compared row by row"]
    assert describe_csv_change('"time","a"\n0.0,1.0\n', '"time","a"\n0.0,1\n') == [
        "same values, different text (number formatting)"]


def test_check_or_update_prints_unchanged_only_for_byte_identical_files(library_results, tmp_path):
    result = library_results["level_run"]
    printed = []
    assert check_or_update([("level_run", result)], update=True, folder=tmp_path, out=printed.append)
    assert printed[0] == "new level_run"
    printed.clear()
    assert check_or_update([("level_run", result)], update=True, folder=tmp_path, out=printed.append)
    assert printed == ["unchanged level_run (3 files byte-identical)"]
    printed.clear()
    assert check_or_update([("level_run", result)], update=False, folder=tmp_path, out=printed.append)
    assert printed == ["ok   level_run"]
