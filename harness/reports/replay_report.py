"""The replay's report: RailCarEstimator's estimates on a log written to CSV (units in the header) and
a short text (the run's errors where the log carries the truth, the comparison with the run's own
est.* where it carries them: harness/run/replay.py says when they agree bit for bit)."""
from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from harness.metrics.estimation import rmse
from harness.run.replay import Log, compare_with_run


def replay_report(log: Log, signals: dict[str, np.ndarray], out: Path, fmu: str = "", forces: str = "") -> str:
    """Write the estimates (CSV, units in the header) and return a short summary text.

    RailCarEstimator's outputs at row k are its estimates for row k's instant (the one-step
    prediction made at row k-1), so they compare directly with truth columns on the same row.
    ``fmu``: which FMU ran (harness.run.fmus.FmuChoice.describe), a line of the text. ``forces``:
    what the log's forces are (``read_log_parameters``), for the comparison with the run's own
    est.* where the log carries them.
    """
    out.mkdir(parents=True, exist_ok=True)
    names = [n for n in signals if n.startswith(("est.", "filter."))]
    units = {"est.mass": "t", "est.mass_std": "t", "est.A0": "N/kN", "est.A1": "N/kN/(m/s)",
             "est.A2": "N/kN/(m/s)2", "est.sigma2": "m2/s2", "filter.speed": "m/s", "filter.position": "m",
             "filter.speed_std": "m/s", "filter.position_std": "m"}
    path = out / "estimates.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time [s]"] + [f"{n} [{units.get(n, '-')}]" for n in names])
        for k in range(len(log.time)):
            w.writerow([repr(float(log.time[k]))] + [repr(float(signals[n][k])) for n in names])
    lines = [f"replayed {log.path}: {len(log.time)} rows, {log.time[-1] - log.time[0]:.1f} s",
             f"  est.mass at the end      {signals['est.mass'][-1]:.3f} +- {signals['est.mass_std'][-1]:.3f} t",
             f"  est.A0, A1, A2           {signals['est.A0'][-1]:.4g}, {signals['est.A1'][-1]:.4g}, "
             f"{signals['est.A2'][-1]:.4g}"]
    c = log.columns
    if "car.speed" in c:
        lines.append(f"  speed RMSE sensor/filter {rmse(c['sensor.speed'], c['car.speed']):.4f} / "
                     f"{rmse(signals['filter.speed'][1:], c['car.speed'][1:]):.4f} m/s (the filter's one-step "
                     f"predictions)")
    if "car.position" in c:
        lines.append(f"  distance RMSE s./filter  {rmse(c['sensor.position'], c['car.position']):.3f} / "
                     f"{rmse(signals['filter.position'][1:], c['car.position'][1:]):.3f} m")
    if "car.total_mass" in c:
        err = 100 * (signals["est.mass"][-1] - c["car.total_mass"][-1]) / c["car.total_mass"][-1]
        lines.append(f"  mass error at the end    {err:+.3f} %")
    lines += compare_with_run(log, signals, forces)
    if fmu:
        lines.append(f"  ran on the FMU {fmu}")
    lines.append(f"  estimates: {path}")
    return "\n".join(lines)
