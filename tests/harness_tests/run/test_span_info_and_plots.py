"""``harness span-info`` (the ATO's planner per span, before a run), ``harness run --plots none``
and the result CSV's columns (the ATO's calls, the demands applied, the wind):

- span-info's fastest run is the controller's own minimum time (the planner made as the
  controller makes it), the margin is schedule / fastest - 1, the min-time run is no cheaper
  than the schedule's plan; a schedule the ATO refuses is shown with the reason (exit 1);
  a scenario without spans is invalid input (exit 2);
- a report with plots "none" writes the CSV and summary.md (the ATO table in it) and no PNG;
- the CSV's header has a unit in every cell; its ato.* columns are the run's ATO calls, its
  demand and wind columns the loop's inputs, bit for bit.
"""
from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np
import pytest

from harness.__main__ import main
from harness.metrics.ato import span_info
from harness.metrics.run import run_metrics
from harness.reports.run_report import ATO_COLUMNS, write_report
from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = ROOT / "scenarios" / "library"
GRADE = (ROOT / "scenarios" / "profiles" / "ato_span_grade.csv").as_posix()


def test_span_info_is_the_controllers_minimum_time_and_its_energy():
    s = load_scenario(LIBRARY / "ato_line.toml")
    infos = span_info(s.ato_setup())
    assert [i.span for i in infos] == [0, 1, 2]
    for info, ctrl, ls in zip(infos, s.ato_setup().controllers(), s.ato.spans):
        assert info.fastest_s == ctrl.planner.min_time(ctrl.configured)        # the same planner
        assert info.schedule_s == ls.span.schedule and info.stop_m == ls.span.stop
        assert info.margin_pct == pytest.approx(100.0 * (ls.span.schedule / info.fastest_s - 1.0), abs=1e-12)
        assert info.schedule_energy_kwh == ctrl.initial_plan.energy_kwh
        # running flat out costs more than running to the schedule; the traction alone more still
        assert info.min_time_traction_kwh > info.min_time_energy_kwh > info.schedule_energy_kwh > 0.0
        assert info.problem == ""
    assert infos[1].margin_pct == pytest.approx(10.4, abs=0.1)   # the scenario's comment: 90.6 s, 10 % above


def write_span(tmp_path: Path, schedule_s: float) -> Path:
    p = tmp_path / "short.toml"
    p.write_text(f'name = "short"\n[parameters]\n"track.grade_profile" = "{GRADE}"\n[span]\n'
                 f'stop_m = 2150.0\nlength_m = 2200.0\nschedule_s = {schedule_s}\n'
                 f'limit_kmh = [[0, 80], [900, 60], [1300, 80]]\n', encoding="utf-8")
    return p


def test_span_info_command_shows_the_fastest_run_of_a_refused_schedule(tmp_path, capsys):
    p = write_span(tmp_path, 120.0)           # the fastest run is 127.0 s: `run` refuses this
    assert main(["run", str(p), "--out", str(tmp_path / "o")]) == 2
    capsys.readouterr()
    assert main(["span-info", str(p)]) == 1
    out = capsys.readouterr().out.splitlines()
    assert "fastest [s]" in out[1] and "margin [%]" in out[1] and "min-time energy [kWh]" in out[1]
    cells = out[2].split()
    assert cells[:4] == ["1", "2150.0", "120.0", "127.01"] and cells[4] == "-5.5"
    assert cells[-1] == "n/a"                 # no plan for the schedule
    assert "the ATO refuses it: span.schedule = 120.00 s is infeasible" in out[3]
    assert main(["span-info", str(write_span(tmp_path, 135.0))]) == 0
    assert "+6.3" in capsys.readouterr().out.splitlines()[2].split()


def test_span_info_of_a_scenario_without_spans_is_invalid_input(capsys):
    assert main(["span-info", str(LIBRARY / "level_run.toml")]) == 2
    assert "level_run.toml: not a span scenario" in capsys.readouterr().err


@pytest.fixture(scope="module")
def nominal_run():
    s = load_scenario(LIBRARY / "ato_nominal.toml")
    r = run_on_chain(s)
    return r, run_metrics(r)


def test_a_report_without_plots_writes_the_csv_and_the_summary_only(nominal_run, tmp_path):
    r, m = nominal_run
    files = write_report(r, m, tmp_path, plots="none")
    assert [f.name for f in files] == ["ato_nominal_result.csv", "summary.md"]
    assert not list(tmp_path.glob("*.png"))
    md = (tmp_path / "summary.md").read_text(encoding="utf-8")
    assert "| span | schedule [s] | arrival err [s] |" in md and "![" not in md
    with pytest.raises(ValueError, match="plots: expected one of all, none"):
        write_report(r, m, tmp_path, plots="some")


def test_the_result_csv_holds_the_atos_calls_the_demands_and_the_wind(nominal_run, tmp_path):
    r, m = nominal_run
    path = write_report(r, m, tmp_path, plots="none")[0]
    rows = list(csv.reader(path.open(encoding="utf-8")))
    header = rows[0]
    assert all(h.endswith("]") and " [" in h for h in header)        # a unit in every cell
    col = {h.split(" [")[0]: j for j, h in enumerate(header)}
    units = {h.split(" [")[0]: h.split(" [")[1][:-1] for h in header}
    assert (units["traction_force_demand"], units["brake_force_demand"], units["wind_speed"],
            units["car.payload"]) == ("N", "N", "m/s", "t")
    assert {n: units[n] for n, _ in ATO_COLUMNS} == dict(ATO_COLUMNS)
    data = np.array([[float(x) for x in row] for row in rows[1:]])
    assert len(data) == len(r.time)
    for n in ("traction_force_demand", "brake_force_demand", "wind_speed"):
        assert np.array_equal(data[:, col[n]], r.inputs[n])
    steps = r.driver_steps
    k = len(steps)
    assert np.array_equal(data[:k, col["ato.mode"]], [s.command.mode for s in steps])
    assert np.array_equal(data[:k, col["ato.planned_speed"]], [s.command.planned_speed for s in steps])
    assert set(data[:k, col["ato.span"]]) == {1.0} and set(data[:k, col["ato.dwell"]]) == {0.0}
    # the demands applied are the ATO's own
    assert np.array_equal(data[:k, col["traction_force_demand"]], [s.command.traction for s in steps])
    assert np.array_equal(data[:k, col["brake_force_demand"]], [s.command.brake for s in steps])
    assert all(math.isnan(x) for x in data[k:, col["ato.mode"]])        # rows without a call


def test_the_csv_of_a_headwind_run_carries_the_wind(tmp_path):
    s = load_scenario(LIBRARY / "ato_headwind.toml")
    r = run_on_chain(s)
    path = write_report(r, run_metrics(r), tmp_path, plots="none")[0]
    rows = list(csv.reader(path.open(encoding="utf-8")))
    j = rows[0].index("wind_speed [m/s]")
    assert {float(row[j]) for row in rows[1:]} == {5.0}


def test_harness_run_with_plots_none_writes_no_png(built_fmus, tmp_path, capsys):
    """The command line: ``--plots none`` reaches the report (no PNG, the report and its table
    written, the line says so); the default draws them (test_harness_ato.py)."""
    out = tmp_path / "out"
    dist = Path(built_fmus["RailCar"]).parent
    assert main(["run", str(LIBRARY / "ato_nominal.toml"), "--out", str(out), "--dist", str(dist),
                 "--fmu", "native", "--plots", "none"]) == 0
    text = capsys.readouterr().out
    assert "(no plots: --plots none; data ato_nominal_result.csv)" in text
    assert sorted(p.name for p in out.iterdir()) == ["ato_nominal_result.csv", "summary.md"]
    assert "| span | schedule [s] |" in (out / "summary.md").read_text(encoding="utf-8")
    with pytest.raises(SystemExit) as e:          # argparse refuses another choice itself
        main(["run", str(LIBRARY / "ato_nominal.toml"), "--plots", "some"])
    assert e.value.code == 2
