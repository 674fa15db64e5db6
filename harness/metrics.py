"""Metrics of a run, as functions of result arrays. Units in each docstring.

Input arrays come from ``RunResult`` (one value per communication step). Nothing here reads
or writes files.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def rmse(estimate: np.ndarray, truth: np.ndarray, mask: np.ndarray | None = None) -> float:
    """Root-mean-square error, in the unit of the arrays."""
    e = np.asarray(estimate) - np.asarray(truth)
    if mask is not None:
        e = e[mask]
    return float(np.sqrt(np.mean(e * e))) if e.size else float("nan")


def stop_indices(speed: np.ndarray) -> list[int]:
    """Index of the last sample of each standstill that follows motion (speed [m/s])."""
    still = np.asarray(speed) <= 0.0
    out = []
    moved = False
    for k in range(len(still)):
        if not still[k]:
            moved = True
        elif moved and (k + 1 == len(still) or not still[k + 1]):
            out.append(k)
            moved = False
    return out


def relative_error(estimate: float, truth: float) -> float:
    """(estimate - truth) / truth [-]."""
    return (estimate - truth) / truth


def time_to_stay_within(time: np.ndarray, rel_err: np.ndarray, bound: float,
                        start: int = 0, end: int | None = None) -> float:
    """First time [s] from which |rel_err| <= bound until ``end``; nan if never."""
    seg = np.abs(rel_err[start:end]) > bound
    if not seg.any():
        return float(time[start])
    last_bad = start + int(np.nonzero(seg)[0][-1])
    stop = len(time) if end is None else end
    return float(time[last_bad + 1]) if last_bad + 1 < stop else float("nan")


def w0(v: np.ndarray, a0: float, a1: float, a2: float) -> np.ndarray:
    """Specific main resistance eq. (1) [N/kN] at speeds v [m/s] (still air)."""
    return a0 + a1 * v + a2 * v * v


def w0_relative_rms_error(speeds: np.ndarray, est: tuple, true: tuple) -> float:
    """RMS of w0_est - w0_true over the travelled speed range, relative to RMS of w0_true [-].

    The range is [min, max] of the speeds [m/s] while moving, sampled at 100 points.
    """
    moving = speeds[speeds > 0.0]
    if moving.size == 0:
        return float("nan")
    v = np.linspace(moving.min(), moving.max(), 100)
    wt = w0(v, *true)
    return float(np.sqrt(np.mean((w0(v, *est) - wt) ** 2)) / np.sqrt(np.mean(wt ** 2)))


def normalised_error_squared(estimate: np.ndarray, truth: np.ndarray, std: np.ndarray,
                             mask: np.ndarray | None = None) -> float:
    """Mean of ((estimate - truth) / std)^2 over samples with std > 0 [-]; ~1 for an honest filter."""
    std = np.asarray(std)
    ok = std > 0
    if mask is not None:
        ok &= mask
    e = (np.asarray(estimate)[ok] - np.asarray(truth)[ok]) / std[ok]
    return float(np.mean(e * e)) if e.size else float("nan")


@dataclass
class RunSummary:
    """Truth vs estimates for one RailCar run (units in the field comments)."""
    scenario: str
    duration_s: float
    stops: int
    mass_true_t: float                 # [t] at the end
    mass_est_t: float                  # [t] at the end
    mass_std_t: float                  # [t]
    mass_error_pct: float              # [%] at the end
    mass_errors_at_stops_pct: list     # [%] at each stop
    mass_time_within_1pct_s: float     # [s] from which |error| <= 1 % to the end of the first run
    A_true: tuple                      # (A0, A1, A2)
    A_est: tuple
    w0_rel_rms_error: float            # [-] over the travelled speed range
    speed_rmse_sensor: float           # [m/s]
    speed_rmse_filter: float           # [m/s]
    position_rmse_sensor: float        # [m]
    position_rmse_filter: float        # [m]
    speed_nees: float                  # [-]
    position_nees: float               # [-]


def summarise(result, true_A: tuple) -> RunSummary:
    """Compute the summary of a ``RunResult`` of RailCar; ``true_A`` = (A0, A1, A2) of the car."""
    t = result.time
    v = result["car.speed"]
    mass = result["car.total_mass"]
    est_mass = result["est.mass"]
    rel = (est_mass - mass) / mass
    stops = stop_indices(v)
    first_end = stops[0] + 1 if stops else None
    moving = v > 0.0
    est_A = (float(result["est.A0"][-1]), float(result["est.A1"][-1]), float(result["est.A2"][-1]))
    return RunSummary(
        scenario=result.scenario.name, duration_s=float(t[-1]), stops=len(stops),
        mass_true_t=float(mass[-1]), mass_est_t=float(est_mass[-1]),
        mass_std_t=float(result["est.mass_std"][-1]), mass_error_pct=100.0 * float(rel[-1]),
        mass_errors_at_stops_pct=[100.0 * float(rel[k]) for k in stops],
        mass_time_within_1pct_s=time_to_stay_within(t, rel, 0.01, 0, first_end),
        A_true=tuple(true_A), A_est=est_A,
        w0_rel_rms_error=w0_relative_rms_error(v, est_A, true_A),
        speed_rmse_sensor=rmse(result["sensor.speed"], v),
        speed_rmse_filter=rmse(result["filter.speed"], v),
        position_rmse_sensor=rmse(result["sensor.position"], result["car.position"]),
        position_rmse_filter=rmse(result["filter.position"], result["car.position"]),
        speed_nees=normalised_error_squared(result["filter.speed"], v, result["filter.speed_std"], moving),
        position_nees=normalised_error_squared(result["filter.position"], result["car.position"],
                                               result["filter.position_std"], moving),
    )


def format_summary(s: RunSummary) -> str:
    """A plain-text table of a summary, for the terminal."""
    def f(x, fmt="{:.4g}"):
        return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else fmt.format(x)

    rows = [
        ("scenario", s.scenario, ""),
        ("duration", f(s.duration_s, "{:.1f}"), "s"),
        ("station stops", str(s.stops), ""),
        ("mass: true / estimated", f"{s.mass_true_t:.3f} / {s.mass_est_t:.3f} +- {s.mass_std_t:.3f}", "t"),
        ("mass error at the end", f(s.mass_error_pct, "{:+.3f}"), "%"),
        ("mass error at each stop", ", ".join(f"{e:+.3f}" for e in s.mass_errors_at_stops_pct) or "n/a", "%"),
        ("mass within 1 % from", f(s.mass_time_within_1pct_s, "{:.1f}"), "s"),
        ("A0 true / est", f"{s.A_true[0]:.4g} / {s.A_est[0]:.4g}", "N/kN"),
        ("A1 true / est", f"{s.A_true[1]:.4g} / {s.A_est[1]:.4g}", "N/kN/(m/s)"),
        ("A2 true / est", f"{s.A_true[2]:.4g} / {s.A_est[2]:.4g}", "N/kN/(m/s)2"),
        ("w0(V) relative RMS error", f(100 * s.w0_rel_rms_error, "{:.1f}"), "%"),
        ("speed RMSE sensor / filter", f"{s.speed_rmse_sensor:.4f} / {s.speed_rmse_filter:.4f} "
         f"(ratio {s.speed_rmse_filter / s.speed_rmse_sensor:.2f})", "m/s"),
        ("distance RMSE sensor / filter", f"{s.position_rmse_sensor:.3f} / {s.position_rmse_filter:.3f} "
         f"(ratio {s.position_rmse_filter / s.position_rmse_sensor:.2f})", "m"),
        ("filter NEES speed / distance", f"{s.speed_nees:.2f} / {s.position_nees:.2f}", "-"),
    ]
    w = max(len(r[0]) for r in rows)
    return "\n".join(f"  {name:<{w}}  {val} {unit}".rstrip() for name, val, unit in rows)
