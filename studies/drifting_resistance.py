"""Run-to-run forgetting of the A's (est.run_forgetting) when the resistance changes between runs
(a study, not a test).

    python studies/drifting_resistance.py [--days N]

Issue 5 asks that the A's carry over from run to run "with slow forgetting" while the mass
restarts at each stop. This drives studies/estimation_quality.py's ten-run day (station_day's
car and line, ten inter-station runs, passengers at every stop) twice per seed:

  steady   the same resistance all day (the ten-run target's case: forgetting only costs)
  drift    a 10 m/s headwind from the 6th run on: eq. (2)'s coefficients move to
           A0 + A2 Vw^2, A1 + 2 A2 Vw (docs/model.md, Forces on the car), which the estimator must follow

with est.method 2 (LS on Sidorenko's (1997) slopes) and each est.run_forgetting f, and prints the mean
w0 relative RMS error after the 10th run against the coefficients then in force (harness.metrics.estimation
.w0_relative_rms_error over the travelled speed range), with the share of days within 2 %.
Seeded (days 1..N, the seeds of estimation_quality's ten-run Monte Carlo); ~1 min on 2 cores
with 20 days.
"""
from __future__ import annotations

import argparse
import sys
from multiprocessing import Pool
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for p in (ROOT, ROOT / "studies"):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import numpy as np  # noqa: E402

import estimation_quality as eq  # noqa: E402
from harness.metrics.estimation import true_theta, w0_relative_rms_error  # noqa: E402
from harness.run.scenario import WindStep  # noqa: E402

FORGETTING = (0.0, 0.1, 0.3, 0.5)
HEADWIND = 10.0          # [m/s] from the 6th run on
FIRST_WINDY_RUN = 6


def _wind_from(day, seed: int) -> float:
    """Time [s] the car leaves for run FIRST_WINDY_RUN (from a run of the steady day)."""
    run = eq.run_scenario(day, seed)
    segs = eq.moving_segments(run.sig["sensor.speed"], 6.0 * day.parameter("sensor.speed_std"), 100)
    return float(run.time[segs[FIRST_WINDY_RUN - 1][0]] - 5.0)


def run_day(job) -> tuple[str, float, float]:
    """(case, f, w0 error after the 10th run [-]) for one seeded day."""
    case, f, seed, wind_time = job
    from dataclasses import replace
    day = eq.with_parameters(eq.ten_run_day(), {**eq.SLOPES, "est.run_forgetting": f})
    if case == "drift":
        day = replace(day, wind=(WindStep(wind_time, HEADWIND),))
    run = eq.run_scenario(day, seed)
    A = tuple(float(x) for x in eq.est_A(run, -1))
    wind = HEADWIND if case == "drift" else 0.0
    A_now = tuple(float(x) for x in true_theta(1.0, tuple(run.A_true), wind)[1:])
    return case, f, w0_relative_rms_error(run.sig["car.speed"], A, A_now)


def compute(days: int, processes: int = 2) -> dict:
    """{(case, f): array of w0 errors [-] over the days}."""
    seeds = [2000 + s for s in range(1, days + 1)]
    wind_time = _wind_from(eq.ten_run_day(), seeds[0])
    jobs = [(c, f, s, wind_time) for c in ("steady", "drift") for f in FORGETTING for s in seeds]
    with Pool(processes) as pool:
        out = pool.map(run_day, jobs)
    table: dict = {}
    for case, f, err in out:
        table.setdefault((case, f), []).append(err)
    return {k: np.array(v) for k, v in table.items()}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--days", type=int, default=20)
    args = ap.parse_args(argv)
    table = compute(args.days)
    print(f"w0 relative RMS error after ten runs, est.method 2, {args.days} days "
          f"(mean %, share <= 2 %); drift = {HEADWIND:g} m/s headwind from run {FIRST_WINDY_RUN}\n")
    print(f"{'est.run_forgetting':>20s} {'steady':>16s} {'drift':>16s}")
    for f in FORGETTING:
        cells = [f"{100 * table[(c, f)].mean():7.2f} ({np.mean(table[(c, f)] <= 0.02):4.0%})"
                 for c in ("steady", "drift")]
        print(f"{f:20g} {cells[0]:>16s} {cells[1]:>16s}")


if __name__ == "__main__":
    main()
