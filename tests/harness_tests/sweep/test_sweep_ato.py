"""A sweep of a span scenario (the ATO drives every run): each row carries the ATO's metrics over
the run's spans (harness.sweep.table.ATO_SWEEP_COLUMNS), and the summary aggregates them (the
share of spans within +-2.5 s and +-0.3 m, the worst errors and their runs):

- ``ato_row`` and ``ato_outcome`` on hand-made span metrics, exactly;
- a three-seed Monte Carlo of ato_nominal through the CLI (one worker process): the rows' ATO
  cells are harness.metrics.ato's for the same run on the same FMU, bit for bit; the summary
  and the plots hold the ATO; a sweep of a scenario without spans has no ATO column.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (before any FMU is loaded in this process)

import math
import os
import subprocess
import sys
from pathlib import Path


from harness.metrics.ato import SpanMetrics, ato_metrics
from harness.sweep.results import read_results
from harness.sweep.spec import load_sweep
from harness.sweep.table import (ATO_SWEEP_COLUMNS, Table, ato_outcome, ato_row, format_ato_outcome,
                                 sweep_columns)

ROOT = Path(__file__).resolve().parents[3]
NOMINAL = ROOT / "scenarios" / "library" / "ato_nominal.toml"
LEVEL = ROOT / "scenarios" / "library" / "level_run.toml"
ENV = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT)] + ([os.environ["PYTHONPATH"]]
                                                                  if os.environ.get("PYTHONPATH") else [])),
           PYTHONDONTWRITEBYTECODE="1")


def span(k: int, arrival: float, stop: float, arrived: bool = True, energy: float = 2.0, margin: float = 0.4,
         interventions: int = 0) -> SpanMetrics:
    return SpanMetrics(span=k, schedule_s=135.0, departure_s=0.0, arrival_s=135.0 + arrival,
                       arrival_error_s=arrival, stop_m=2150.0, stop_error_m=stop, energy_kwh=energy,
                       margin_mps=margin, interventions=interventions, arrived=arrived)


def test_a_rows_ato_cells_count_sum_and_keep_each_span():
    row = ato_row([span(0, 1.0, -0.1), span(1, -3.0, 0.05, energy=1.5, margin=0.2, interventions=2),
                   span(2, 0.5, 0.4, arrived=False)])
    assert set(row) == {c.key for c in ATO_SWEEP_COLUMNS}
    assert (row["ato_spans"], row["ato_arrived"], row["ato_on_target"]) == (3, 2, 1)
    assert row["ato_arrival_error_s.max_abs"] == 3.0 and row["ato_stop_error_m.max_abs"] == 0.4
    assert row["ato_arrival_error_s.list"] == "1.0;-3.0;0.5"
    assert (row["ato_energy_kwh"], row["ato_margin_mps"], row["ato_interventions"]) == (5.5, 0.2, 2)


def test_the_summary_shares_and_worst_over_every_span_of_the_ok_runs():
    rows = [dict(run_id=0, status="ok", **ato_row([span(0, 1.0, -0.1), span(1, 2.6, 0.0)])),
            dict(run_id=1, status="ok", **ato_row([span(0, -0.2, 0.31), span(1, 0.0, 0.0)])),
            dict(run_id=2, status="failed")]
    a = ato_outcome(Table(list(ATO_SWEEP_COLUMNS), rows))
    assert (a["runs"], a["spans"], a["arrival_within"], a["stop_within"], a["on_target"]) == (2, 4, 3, 3, 2)
    assert a["worst_arrival"] == (2.6, 0) and a["worst_stop"] == (0.31, 1)
    text = "\n".join(format_ato_outcome(a))
    assert "arrival within +-2.5 s     3 of 4 spans (75.0 %)" in text
    assert "arrived, both within       2 of 4 spans (50.0 %)" in text
    assert "worst |stop error|         0.31 m (run 1)" in text
    never = [dict(run_id=5, status="ok", **ato_row([span(0, math.nan, 3.0, arrived=False)]))]
    assert "never came to rest (run 5)" in "\n".join(format_ato_outcome(ato_outcome(Table([], never))))
    assert ato_outcome(Table([], [dict(run_id=0, status="ok")])) is None     # no span scenario


def sweep_file(tmp_path: Path, scenario: Path, body: str = "seeds = 3\n") -> Path:
    p = tmp_path / "mc_ato.toml"
    p.write_text(f'name = "mc_ato"\nscenario = "{scenario.as_posix()}"\n{body}', encoding="utf-8")
    return p


def test_only_a_span_scenarios_sweep_has_ato_columns(tmp_path):
    keys = [c.key for c in sweep_columns(load_sweep(sweep_file(tmp_path, NOMINAL)))]
    assert keys[-len(ATO_SWEEP_COLUMNS) - 2:-2] == [c.key for c in ATO_SWEEP_COLUMNS]
    assert keys[-2:] == ["engine", "fmu"]
    assert not {c.key for c in ATO_SWEEP_COLUMNS} & {c.key for c in
                                                     sweep_columns(load_sweep(sweep_file(tmp_path, LEVEL)))}


def test_a_monte_carlo_of_a_span_reports_the_atos_metrics(built_fmus, tmp_path):
    from harness.run.runner import FmuRunner
    dist = Path(built_fmus["RailCar"]).parent
    sweep = sweep_file(tmp_path, NOMINAL)
    out = tmp_path / "out"
    p = subprocess.run([sys.executable, "-m", "harness", "sweep", str(sweep), "--out", str(out), "--dist",
                        str(dist), "--workers", "1", "--fmu", "native"], cwd=ROOT, env=ENV, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr
    table = read_results(out)
    assert [r["status"] for r in table.rows] == ["ok"] * 3 and [r["seed"] for r in table.rows] == [1, 2, 3]
    header = (out / "results.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    assert {"ato_arrival_error_s.max_abs [s]", "ato_stop_error_m.max_abs [m]", "ato_energy_kwh [kWh]",
            "ato_margin_mps [m/s]", "ato_interventions [-]", "ato_on_target [-]"} <= set(header)
    # the cells are harness.metrics.ato's for the same run, bit for bit
    spec = load_sweep(sweep).runs[1]
    with FmuRunner(dist / "native" / "RailCarNative.fmu") as runner:
        result = runner.run(spec.scenario)
    (m,) = ato_metrics(spec.scenario, result, result.driver_steps)
    row = table.rows[1]
    assert row["ato_arrival_error_s.list"] == repr(m.arrival_error_s)
    assert row["ato_stop_error_m.list"] == repr(m.stop_error_m)
    assert (row["ato_energy_kwh"], row["ato_margin_mps"], row["ato_interventions"]) == \
        (m.energy_kwh, m.margin_mps, m.interventions)
    assert all(r["ato_spans"] == 1 and r["ato_arrived"] == 1 for r in table.rows)
    summary = (out / "summary.md").read_text(encoding="utf-8")
    assert "ATO over the spans of the 3 ok runs" in summary and "arrival within +-2.5 s" in summary
    assert "ATO over the spans" in p.stdout
    assert (out / "plots" / "ato_histograms.png").is_file()
