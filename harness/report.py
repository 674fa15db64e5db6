"""Writing a run's results: CSV with units in the header, a markdown summary, PNG plots."""
from __future__ import annotations

import csv
from dataclasses import asdict
from pathlib import Path

import numpy as np

from .metrics import RunSummary, format_summary


def write_result_csv(result, path: Path) -> Path:
    """All signals over time; header cells are 'name [unit]' (time first)."""
    names = list(result.signals)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time [s]"] + [f"{n} [{result.units.get(n) or '-'}]" for n in names])
        cols = np.column_stack([result.time] + [result.signals[n] for n in names])
        for row in cols:
            w.writerow([repr(float(x)) for x in row])
    return path


def write_summary_md(summary: RunSummary, scenario, path: Path, figures: list[Path], fmu: str = "") -> Path:
    """``fmu``: which FMU ran and why (harness.fmus.FmuChoice.line), a line of its own."""
    lines = [f"# Run report: {summary.scenario}", "", scenario.purpose or "", ""]
    if fmu:
        lines += [f"FMU: {fmu}", ""]
    lines += ["```", format_summary(summary), "```", ""]
    for fig in figures:
        lines += [f"![{fig.stem}]({fig.name})", ""]
    lines += ["Raw values:", "", "| metric | value |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in asdict(summary).items()]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def _save(fig, title: str, path: Path) -> Path:
    import matplotlib.pyplot as plt
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def plot_run(result, out_dir: Path) -> list[Path]:
    """Speed and distance (true, measured, filtered) vs distance; estimates vs time with 2-sigma bands."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result.time
    x = result["car.position"]
    figs = []

    fig, ax = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
    ax[0].plot(x, result["sensor.speed"], ".", ms=1.5, color="0.6", label="measured")
    ax[0].plot(x, result["car.speed"], color="k", lw=1.2, label="true")
    ax[0].plot(x, result["filter.speed"], color="tab:red", lw=1.0, label="filtered")
    ax[0].set_ylabel("speed [m/s]")
    ax[0].legend(loc="best")
    ax[1].plot(x, result["sensor.speed"] - result["car.speed"], ".", ms=1.5, color="0.6", label="measured - true")
    ax[1].plot(x, result["filter.speed"] - result["car.speed"], color="tab:red", lw=1.0, label="filtered - true")
    ax[1].fill_between(x, -2 * result["filter.speed_std"], 2 * result["filter.speed_std"],
                       color="tab:red", alpha=0.15, label="filter +-2 sigma")
    ax[1].set_ylabel("speed error [m/s]")
    ax[1].set_xlabel("distance from the previous station [m]")
    ax[1].legend(loc="best")
    figs.append(_save(fig, f"{result.scenario.name}: speed vs distance", out_dir / "speed.png"))

    fig, ax = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    m, s = result["est.mass"], result["est.mass_std"]
    ax[0].plot(t, result["car.total_mass"], color="k", label="true")
    ax[0].plot(t, m, color="tab:blue", label="identified")
    ax[0].fill_between(t, m - 2 * s, m + 2 * s, color="tab:blue", alpha=0.15, label="+-2 sigma")
    mt = result["car.total_mass"]
    ax[0].set_ylim(0.8 * mt.min(), 1.2 * mt.max())
    ax[0].set_ylabel("mass [t]")
    ax[0].legend(loc="best")
    ax[1].plot(t, result["filter.position"] - x, color="tab:red", label="filtered - true")
    ax[1].plot(t, result["sensor.position"] - x, ".", ms=1, color="0.6", label="measured - true")
    ax[1].fill_between(t, -2 * result["filter.position_std"], 2 * result["filter.position_std"],
                       color="tab:red", alpha=0.15)
    ax[1].set_ylabel("distance error [m]")
    ax[1].legend(loc="best")
    ax[2].plot(t, result["car.speed"], color="k", label="true speed [m/s]")
    ax[2].set_ylabel("speed [m/s]")
    ax[2].set_xlabel("time [s]")
    figs.append(_save(fig, f"{result.scenario.name}: identification and filter vs time",
                      out_dir / "estimates.png"))
    return figs


def plot_resistance(result, true_A: tuple, out_dir: Path) -> Path:
    """w0(V) identified (end of run) vs true over the travelled speed range."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from .metrics import w0

    v_run = result["car.speed"]
    v = np.linspace(0.0, max(float(v_run.max()), 1.0), 100)
    est = (result["est.A0"][-1], result["est.A1"][-1], result["est.A2"][-1])
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(v, w0(v, *true_A), color="k", label="true")
    ax.plot(v, w0(v, *est), color="tab:blue", label="identified")
    ax.set_xlabel("speed [m/s]")
    ax.set_ylabel("w0 [N/kN]")
    ax.legend()
    return _save(fig, f"{result.scenario.name}: main resistance eq. (1)", out_dir / "resistance.png")


def plot_resistance_vs_time(result, true_A: tuple, out_dir: Path) -> Path:
    """A0, A1, A2 identified vs time with +-2 sigma bands, and the truth."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = result.time
    fig, ax = plt.subplots(3, 1, figsize=(10, 8), sharex=True)
    for j, (name, unit) in enumerate((("A0", "N/kN"), ("A1", "N/kN/(m/s)"), ("A2", "N/kN/(m/s)2"))):
        est, sd = result[f"est.{name}"], result[f"est.{name}_std"]
        ax[j].plot(t, est, color="tab:blue", label="identified")
        ax[j].fill_between(t, est - 2 * sd, est + 2 * sd, color="tab:blue", alpha=0.15, label="+-2 sigma")
        ax[j].axhline(true_A[j], color="k", lw=1, label="true (at the end)")
        span = 6 * max(abs(true_A[j]), float(np.median(sd)), 1e-6)
        ax[j].set_ylim(true_A[j] - span, true_A[j] + span)
        ax[j].set_ylabel(f"{name} [{unit}]")
    ax[0].legend(loc="best")
    ax[2].set_xlabel("time [s]")
    return _save(fig, f"{result.scenario.name}: resistance coefficients vs time", out_dir / "resistance_vs_time.png")


def write_report(result, summary: RunSummary, true_A: tuple, out_dir: Path, fmu: str = "") -> list[Path]:
    """Everything for one run into ``out_dir``; returns the files written. ``fmu``: which FMU ran
    (a line of summary.md; default: the kind the result records)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = write_result_csv(result, out_dir / f"{result.scenario.name}_result.csv")
    figs = plot_run(result, out_dir) + [plot_resistance(result, true_A, out_dir),
                                        plot_resistance_vs_time(result, true_A, out_dir)]
    md = write_summary_md(summary, result.scenario, out_dir / "summary.md", figs,
                          fmu or getattr(result, "fmu", ""))
    return [csv_path, md, *figs]
