"""The filters side by side on the scenario library: speed and distance RMSE and NEES.

Every scenario runs once per ``filter.kind`` (1 linearised, 2 EKF, 3 the paper's (13)-(19)
verbatim, 4 Singer). The linearised kinds need V_zad(X): a scenario without
``track.speed_profile`` gets its nominal plan (harness.run.plan) for these runs.
"""
from __future__ import annotations

import dataclasses
import tempfile
from pathlib import Path

from harness.metrics.estimation import normalised_error_squared, rmse
from harness.run.plan import plan_speed_profile, profile_csv_text

KINDS = {1: "linearised", 2: "EKF", 3: "paper (13)-(19)", 4: "Singer"}


def with_parameters(scenario, **params):
    """A copy of a scenario with FMU parameters overridden."""
    return dataclasses.replace(scenario, parameters={**scenario.parameters, **params})


def compare_filters(scenarios, runner, progress=None) -> list[dict]:
    """One row per (scenario, kind): RMSE [m/s], [m] of sensor and filter, NEES [-]."""
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for s in scenarios:
            base = s
            if not s.parameter("track.speed_profile") and s.parameter("car.initial_speed") == 0.0:
                xs, vs = plan_speed_profile(s)
                path = Path(tmp) / f"{s.name}_vzad.csv"
                path.write_text(profile_csv_text(xs, vs), encoding="utf-8")
                base = with_parameters(s, **{"track.speed_profile": str(path)})
            for kind, label in KINDS.items():
                if kind in (1, 3) and not base.parameter("track.speed_profile"):
                    rows.append({"scenario": s.name, "filter": label, "error": "needs V_zad"})
                    continue
                r = runner.run(with_parameters(base, **{"filter.kind": kind}))
                v, x = r["car.speed"], r["car.position"]
                moving = v > 0.0
                rows.append({
                    "scenario": s.name, "filter": label,
                    "speed_rmse_sensor": rmse(r["sensor.speed"], v),
                    "speed_rmse": rmse(r["filter.speed"], v),
                    "distance_rmse_sensor": rmse(r["sensor.position"], x),
                    "distance_rmse": rmse(r["filter.position"], x),
                    "speed_nees": normalised_error_squared(r["filter.speed"], v, r["filter.speed_std"], moving),
                    "distance_nees": normalised_error_squared(r["filter.position"], x,
                                                              r["filter.position_std"], moving),
                })
                if progress:
                    progress.advance(f"{s.name} {label}")
    return rows


def format_rows(rows: list[dict]) -> str:
    head = ("scenario", "filter", "speed RMSE sensor / filter [m/s]", "dist. RMSE sensor / filter [m]",
            "NEES v / x")
    body = []
    for r in rows:
        if "error" in r:
            body.append((r["scenario"], r["filter"], r["error"], "", ""))
            continue
        body.append((r["scenario"], r["filter"],
                     f"{r['speed_rmse_sensor']:.4f} / {r['speed_rmse']:.4f} ({r['speed_rmse'] / r['speed_rmse_sensor']:.2f})",
                     f"{r['distance_rmse_sensor']:.2f} / {r['distance_rmse']:.3f} ({r['distance_rmse'] / r['distance_rmse_sensor']:.2f})",
                     f"{r['speed_nees']:.2f} / {r['distance_nees']:.2f}"))
    w = [max(len(h), *(len(b[j]) for b in body)) for j, h in enumerate(head)]
    lines = ["  ".join(h.ljust(n) for h, n in zip(head, w)), "  ".join("-" * n for n in w)]
    lines += ["  ".join(c.ljust(n) for c, n in zip(b, w)) for b in body]
    return "\n".join(lines)
