"""Writing a run's results: CSV with units in the header, a markdown summary, PNG plots.

The figures are built by ``*_figure`` functions that return the matplotlib figure (the tests
read its artists); ``plot_*`` save them. Uncertainty bands are +-2 sigma of the estimator's own
standard deviations; the band of the identified resistance curve w0(V) comes from the covariance
of (A0, A1, A2) the run recorded (harness.metrics.estimation.resistance_covariance). Everything
shown is computed once, before (harness.metrics.run.RunMetrics): the report only draws and
writes; nothing here runs a model.
"""
from __future__ import annotations

import csv
from dataclasses import asdict
from pathlib import Path

import numpy as np

from harness.reports.plotting import pyplot, save_figure
from harness.metrics.estimation import RunSummary, format_summary, resistance_covariance

A_NAMES = (("A0", "N/kN"), ("A1", "N/kN/(m/s)"), ("A2", "N/kN/(m/s)²"))
"""The main resistance coefficients of eq. (1) and their units."""

ROOT = Path(__file__).resolve().parents[2]


ATO_COLUMNS = (("ato.span", "-"), ("ato.dwell", "-"), ("ato.mode", "-"), ("ato.planned_speed", "m/s"),
               ("ato.ep_stage", "-"))
"""A span scenario's ATO call at each row (harness.run.span_scenario.AtoStep): the span (1, 2, ..),
1 while standing at a station between spans, the mode (models.ato.interface.AtoMode), the planned
speed and the EP brake stages; nan on a row without a call (the last). The demands it gave are
the loop's (traction_force_demand, brake_force_demand): not repeated."""


def ato_columns(steps, rows: int) -> dict[str, np.ndarray]:
    """The ATO_COLUMNS over ``rows`` result rows from the ATO's calls ``steps`` (call j at row j)."""
    out = {n: np.full(rows, np.nan) for n, _ in ATO_COLUMNS}
    for j, st in enumerate(steps[:rows]):
        c = st.command
        for (n, _), x in zip(ATO_COLUMNS, (st.span + 1, float(st.dwell), c.mode, c.planned_speed, c.ep_stage)):
            out[n][j] = x
    return out


def result_columns(result) -> list[tuple[str, str, np.ndarray]]:
    """(name, unit, values over result.time) of every column of the result CSV after the time: the
    recorded outputs, the loop's inputs as applied over each step (harness.run.result.INPUT_UNITS:
    the demands, the wind, the payload; held over [t_k, t_k+1], the last repeated) and for a span
    scenario the ATO's calls (ATO_COLUMNS)."""
    from harness.run.result import INPUT_UNITS
    cols = [(n, result.units.get(n) or "-", result.signals[n]) for n in result.signals]
    cols += [(n, INPUT_UNITS.get(n, "-"), u) for n, u in result.inputs.items()
             if n not in result.signals and len(u) == len(result.time)]
    if result.driver_steps is not None:
        ato = ato_columns(result.driver_steps, len(result.time))
        cols += [(n, unit, ato[n]) for n, unit in ATO_COLUMNS]
    return cols


def write_result_csv(result, path: Path) -> Path:
    """Every column of ``result_columns`` over time; header cells are 'name [unit]' (time first),
    values by repr (they read back bit for bit)."""
    cols = result_columns(result)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time [s]"] + [f"{n} [{unit}]" for n, unit, _ in cols])
        table = np.column_stack([result.time] + [c for _, _, c in cols])
        for row in table:
            w.writerow([repr(float(x)) for x in row])
    return path


def format_run_summary(summary: RunSummary, result) -> str:
    """``metrics.format_summary`` with each A's standard deviation at the end of the run
    (est.A0_std, ... from ``result``), as the mass has it: 'A0 true / est  0.89 / 0.4688 +- 2.001
    N/kN'."""
    lines = format_summary(summary).split("\n")
    for name, unit in A_NAMES:
        sd = float(result[f"est.{name}_std"][-1])
        for i, line in enumerate(lines):
            if line.lstrip().startswith(f"{name} true / est") and "+-" not in line and line.endswith(unit):
                lines[i] = f"{line[:-len(unit)].rstrip()} +- {sd:.4g} {unit}"
    return "\n".join(lines)


def format_value(x) -> str:
    """A metric's value for summary.md: floats to 6 significant digits (140.7, not
    140.70000000000002), lists and tuples element by element."""
    if isinstance(x, float):
        return f"{x:.6g}"
    if isinstance(x, (list, tuple)):
        inner = ", ".join(format_value(v) for v in x)
        return f"({inner})" if isinstance(x, tuple) else f"[{inner}]"
    return str(x)


def short_path(path) -> str:
    """``path`` relative to the repository when it lies inside it, else its file name: a report
    names no machine's folders."""
    p = Path(path)
    try:
        return p.resolve().relative_to(ROOT).as_posix()
    except ValueError:
        return p.name


def write_summary_md(summary: RunSummary, scenario, path: Path, figures: list[Path], fmu: str = "",
                     result=None, ato: list[str] | None = None, driver_log: list[str] | None = None) -> Path:
    """``fmu``: which FMU ran and why (a line of its own; paths as ``short_path`` gives them).
    ``result``: the run, for the A's standard deviations (``format_run_summary``). ``ato``: a
    span scenario's ATO table in markdown (harness.reports.ato_report), first; ``driver_log``:
    the ATO's log lines (RunResult.driver_log), after it."""
    lines = [f"# Run report: {summary.scenario}", "", scenario.purpose or "", ""]
    if fmu:
        lines += [f"FMU: {fmu}", ""]
    if ato:
        lines += ["ATO, per span (docs/ato.md):", "", *ato, ""]
        if driver_log:
            lines += ["ATO log:", "", *(f"- {x}" for x in driver_log), ""]
        lines += ["Estimation:", ""]
    text = format_summary(summary) if result is None else format_run_summary(summary, result)
    lines += ["```", text, "```", ""]
    for fig in figures:
        lines += [f"![{fig.stem}]({fig.name})", ""]
    lines += ["Raw values:", "", "| metric | value |", "|---|---|"]
    lines += [f"| {k} | {format_value(v)} |" for k, v in asdict(summary).items()]
    if result is not None:
        lines.append(f"| A_std | {format_value(tuple(float(result[f'est.{n}_std'][-1]) for n, _ in A_NAMES))} |")
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


def clipped_band(ax, t, centre, sd, lo: float, hi: float, colour: str, label: str) -> str:
    """Fill centre +- 2 sd over ``t`` inside the axis range [lo, hi] only: where the band is
    wider than the range (the prior, a coefficient the run hardly excites) it is not drawn, so
    that it never paints the whole panel; elsewhere its edges are clipped to the range. Returns
    the label given, with what was left out said."""
    wide = 4.0 * np.asarray(sd) > (hi - lo)
    if wide.all():
        note = "\nwider than the axes all along: not drawn"
    elif wide[0] and not wide[np.argmax(~wide):].any():
        note = f"\nwider than the axes until t = {float(t[np.argmax(~wide)]):.0f} s: not drawn there"
    elif wide.any():
        note = "\nwider than the axes at times: not drawn there"
    else:
        note = ""
    ax.fill_between(t, np.clip(centre - 2 * sd, lo, hi), np.clip(centre + 2 * sd, lo, hi), where=~wide,
                    color=colour, alpha=0.15, label=label + note)
    return label + note


def run_figures(result) -> tuple:
    """(speed figure, estimates figure): speed and its error vs distance (true, measured,
    filtered, the filter's +-2 sigma); mass identified vs true with +-2 sigma, the distance error
    with the filter's +-2 sigma, and the true speed, vs time."""
    plt = pyplot()
    t = result.time
    x = result["car.position"]

    fig1, ax = plt.subplots(2, 1, figsize=(10, 7), sharex=True)
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

    fig2, ax = plt.subplots(3, 1, figsize=(10, 9), sharex=True)
    m, s = result["est.mass"], result["est.mass_std"]
    ax[0].plot(t, result["car.total_mass"], color="k", label="true")
    ax[0].plot(t, m, color="tab:blue", label="identified")
    mt = result["car.total_mass"]
    lo, hi = 0.8 * mt.min(), 1.2 * mt.max()
    clipped_band(ax[0], t, m, s, lo, hi, "tab:blue", "+-2 sigma")     # the prior's: est.mass_std_initial
    ax[0].set_ylim(lo, hi)
    ax[0].set_ylabel("mass [t]")
    ax[0].legend(loc="best")
    ax[1].plot(t, result["filter.position"] - x, color="tab:red", label="filtered - true")
    ax[1].plot(t, result["sensor.position"] - x, ".", ms=1, color="0.6", label="measured - true")
    ax[1].fill_between(t, -2 * result["filter.position_std"], 2 * result["filter.position_std"],
                       color="tab:red", alpha=0.15, label="filter +-2 sigma")
    ax[1].set_ylabel("distance error [m]")
    ax[1].legend(loc="best")
    ax[2].plot(t, result["car.speed"], color="k", label="true speed [m/s]")
    ax[2].set_ylabel("speed [m/s]")
    ax[2].set_xlabel("time [s]")
    return fig1, fig2


def plot_run(result, out_dir: Path) -> list[Path]:
    """speed.png and estimates.png (``run_figures``)."""
    fig1, fig2 = run_figures(result)
    name = result.scenario.name
    return [save_figure(fig1, f"{name}: speed vs distance", out_dir / "speed.png"),
            save_figure(fig2, f"{name}: identification and filter vs time", out_dir / "estimates.png")]


def resistance_band(v: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """Standard deviation of w0(V) = A0 + A1 V + A2 V^2 at speeds ``v`` [m/s] for a covariance
    ``cov`` of (A0, A1, A2): sqrt(phi^T cov phi), phi = (1, V, V^2) (w0 is linear in the A's, so
    this is exact, not a linearisation) [N/kN]."""
    phi = np.stack([np.ones_like(v), v, v * v])
    return np.sqrt(np.maximum(np.einsum("in,ij,jn->n", phi, cov, phi), 0.0))


def resistance_figure(result, true_A: tuple, cov: np.ndarray | None = None, full: bool | None = None):
    """w0(V) identified (end of run) with +-2 sigma vs true, over 0 .. the run's top speed.

    ``cov``: covariance of (A0, A1, A2) and ``full`` whether it holds the correlations; by
    default the run's own (harness.metrics.estimation.resistance_covariance: est.cov_* off the
    diagonal, or the stds alone, and then the legend says the correlations are ignored)."""
    from harness.metrics.estimation import w0
    plt = pyplot()
    v = np.linspace(0.0, max(float(result["car.speed"].max()), 1.0), 100)
    est = tuple(float(result[f"est.{a}"][-1]) for a, _ in A_NAMES)
    if cov is None:
        cov, full = resistance_covariance(result)
    how = "covariance of A0, A1, A2" if full or full is None else "stds of A0, A1, A2 alone: correlations ignored"
    w_est, sd = w0(v, *est), resistance_band(v, cov)
    fig, ax = plt.subplots(figsize=(7, 4.5))
    ax.plot(v, w0(v, *true_A), color="k", label="true")
    ax.plot(v, w_est, color="tab:blue", label="identified")
    ax.fill_between(v, w_est - 2 * sd, w_est + 2 * sd, color="tab:blue", alpha=0.15,
                    label=f"identified +-2 sigma ({how})")
    ax.set_xlabel("speed [m/s]")
    ax.set_ylabel("w0 [N/kN]")
    ax.legend(loc="best")
    return fig


def plot_resistance(result, true_A: tuple, out_dir: Path, cov: np.ndarray | None = None,
                    full: bool | None = None) -> Path:
    """resistance.png (``resistance_figure``)."""
    return save_figure(resistance_figure(result, true_A, cov, full),
                       f"{result.scenario.name}: main resistance eq. (1)", out_dir / "resistance.png")


def resistance_vs_time_figure(result, true_A: tuple):
    """A0, A1, A2 identified vs time with +-2 sigma bands, and the truth. Each axis is scaled to
    the estimate and the truth (10 % margin), not to the band: the prior's band (A0 +-10 N/kN
    against A0 ~ 1) would hide the estimate's error. The band is drawn only where it fits the
    axis (``clipped_band``); the legend (right of each axis) gives its half-width at the end
    and says where it was left out."""
    plt = pyplot()
    t = result.time
    fig, ax = plt.subplots(3, 1, figsize=(12, 8), sharex=True)
    for j, (name, unit) in enumerate(A_NAMES):
        est, sd = result[f"est.{name}"], result[f"est.{name}_std"]
        lo, hi = min(float(est.min()), true_A[j]), max(float(est.max()), true_A[j])
        pad = 0.1 * (hi - lo) if hi > lo else 0.1 * max(abs(hi), 1e-6)
        lo, hi = lo - pad, hi + pad
        ax[j].plot(t, est, color="tab:blue", label="identified")
        clipped_band(ax[j], t, est, sd, lo, hi, "tab:blue",
                     f"+-2 sigma (+-{2 * float(sd[-1]):.3g} {unit} at the end)")
        ax[j].axhline(true_A[j], color="k", lw=1, label="true (at the end)")
        ax[j].set_ylim(lo, hi)
        ax[j].set_ylabel(f"{name} [{unit}]")
        ax[j].legend(loc="upper left", bbox_to_anchor=(1.01, 1.0), fontsize="small")
    ax[2].set_xlabel("time [s]")
    return fig


def plot_resistance_vs_time(result, true_A: tuple, out_dir: Path) -> Path:
    """resistance_vs_time.png (``resistance_vs_time_figure``)."""
    return save_figure(resistance_vs_time_figure(result, true_A),
                 f"{result.scenario.name}: resistance coefficients vs time", out_dir / "resistance_vs_time.png")


PLOTS = ("all", "none")
"""``harness run --plots``: every figure (default), or none (the CSV and summary.md alone: the
figures take most of a span run's time)."""


def write_report(result, metrics, out_dir: Path, fmu: str = "", plots: str = "all") -> list[Path]:
    """Everything for one run into ``out_dir``, drawn from ``metrics`` (harness.metrics.run.
    RunMetrics, computed once); returns the files written: the result CSV, summary.md, then the
    figures. ``fmu``: which FMU ran (a line of summary.md; default: the kind the result
    records). A span scenario's ato.png and ATO table come first. ``plots`` (PLOTS): "none"
    draws nothing; summary.md then holds the tables alone."""
    if plots not in PLOTS:
        raise ValueError(f"plots: expected one of {', '.join(PLOTS)}, got {plots!r}")
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path = write_result_csv(result, out_dir / f"{result.scenario.name}_result.csv")
    figs, ato_md = [], None
    if metrics.ato is not None:
        from harness.metrics.ato import markdown_ato
        if plots == "all":
            from harness.reports.ato_report import write_ato_report
            png, ato_md = write_ato_report(result, metrics.ato, out_dir)
            figs.append(png)
        else:
            ato_md = markdown_ato(metrics.ato)
    if plots == "all":
        figs += plot_run(result, out_dir) + [
            plot_resistance(result, metrics.true_A, out_dir, metrics.A_covariance, metrics.A_covariance_full),
            plot_resistance_vs_time(result, metrics.true_A, out_dir)]
    md = write_summary_md(metrics.summary, result.scenario, out_dir / "summary.md", figs,
                          fmu or getattr(result, "fmu", ""), result, ato_md, metrics.driver_log)
    return [csv_path, md, *figs]
