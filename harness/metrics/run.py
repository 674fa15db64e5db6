"""Every metric of one run, computed once: the estimation summary, the resistance covariance,
a span scenario's ATO table, and the driver's log lines. The reports (harness.reports) and the
library table only draw and print a RunMetrics; nothing here runs the model again except the
oracle filter (harness.metrics.estimation.oracle_filter), once, and the re-runs of the coasts
(coast_time_errors): both in C when the C core runs (models/core/run_metrics.c, ~1.5 ms for all
of a station_day run's metrics instead of ~140 ms in Python; the same numbers bit for bit).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from harness.metrics.estimation import RunSummary, resistance_covariance, summarise


@dataclass
class RunMetrics:
    """What the reports of one RailCar run show (units as in the fields' classes)."""
    summary: RunSummary
    true_A: tuple                          # (A0, A1, A2) at the end, the wind then blowing
    A_std: tuple                           # est.A0_std, est.A1_std, est.A2_std at the end
    A_covariance: np.ndarray               # 3x3 covariance of (A0, A1, A2) at the end
    A_covariance_full: bool                # True: from est.cov_* (correlations); False: stds alone
    ato: list | None = None                # harness.metrics.ato.SpanMetrics per span, or None
    driver_log: list[str] = field(default_factory=list)   # each line names the scenario


def run_metrics(result) -> RunMetrics:
    """The metrics of a RailCar RunResult, each computed once. A span scenario's ATO table
    comes from the calls the run recorded (``result.driver_steps``), or, for a result without
    them, from the recorded outputs fed to a fresh ATO (harness.run.span_scenario.replay_steps:
    the controllers only, no model)."""
    summary = summarise(result)
    cov, full = resistance_covariance(result)
    ato = None
    if result.scenario.ato is not None:
        from harness.metrics.ato import ato_metrics
        steps = result.driver_steps
        if steps is None:
            from harness.run.span_scenario import replay_steps
            steps = replay_steps(result.scenario, result).steps
        ato = ato_metrics(result.scenario, result, steps)
    A_std = tuple(float(result[f"est.{a}_std"][-1]) for a in ("A0", "A1", "A2"))
    return RunMetrics(summary, tuple(summary.A_true), A_std, cov, full, ato, list(result.driver_log))
