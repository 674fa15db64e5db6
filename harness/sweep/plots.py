"""A sweep's plots (PNG, through harness.reports.plotting): the metrics that vary over the ok runs,
a few per figure, grouped by what they say about the run (``PLOT_GROUPS``: the mass estimate, the
running resistance, the filter's accuracy, the filter's calibration, the ATO (a span scenario's
sweep); any other varying metric in
``other`` figures, so that none is dropped silently):

- ``GROUP_vs_NAME.png``: each metric of the group against a swept value (one dot per run; for a
  grid or zip axis a line through the median of each value);
- ``GROUP_histograms.png`` (a sweep over seeds): each metric's distribution, runs per bin;
- ``GROUP_heatmap_A__B.png`` (a two-axis grid): each metric's mean over the other axes (seeds).

A sweep of more than PLOT_SAMPLE_ROWS runs is plotted from a sample of that many (``PlotSample``:
the same rows whatever the order they finished in; the titles say so), so that its plots cost
the same memory and time at 100,000 runs as at 5,000.

At most ``PANELS_PER_FIGURE`` panels a figure, every axis labelled with its unit, text large
enough to read at the PNG's size. ``sweep_figures`` makes the figures (tests read them),
``plot_sweep`` writes them.
"""
from __future__ import annotations

import heapq
import math
import re
import textwrap
from pathlib import Path

import numpy as np

from harness.reports.plotting import display_unit, pyplot, save_figure
from harness.sweep.spec import Sweep
from harness.sweep.table import ATO_SWEEP_COLUMNS, CALIBRATION_COLUMNS, Column, Table, finite_values, metric_columns

PANELS_PER_FIGURE = 6
TITLE_PT, LABEL_PT, TICK_PT, SUPTITLE_PT = 11, 10, 9, 13      # [pt]; at DPI the PNG is ~1300 px wide
PANEL_INCHES = (4.4, 3.5)                                       # [in] width, height of one panel
MIN_FIGURE_WIDTH_IN = 7.0                                       # [in] room for the title of a 1-panel figure
DPI = 100

# (file prefix, figure title, metric keys in panel order)
PLOT_GROUPS = (
    ("mass", "mass estimate",
     ("mass_error_pct", "mass_errors_at_stops_pct.max_abs", "mass_std_t", "mass_z_at_stops.max_abs",
      "mass_time_within_1pct_s.max_abs", "mass_est_t")),
    ("resistance", "running resistance",
     ("A0_est", "A1_est", "A2_est", "w0_rel_rms_error", "coast_time_errors_s.max_abs")),
    ("filter_accuracy", "filter accuracy",
     ("speed_rmse_sensor", "speed_rmse_filter", "speed_rmse_oracle",
      "position_rmse_sensor", "position_rmse_filter", "position_rmse_oracle")),
    ("filter_calibration", "filter calibration",
     ("speed_nees", "position_nees", "speed_within_2sigma_pct", "position_within_2sigma_pct")),
    ("ato", "the ATO over the run's spans",
     ("ato_arrival_error_s.max_abs", "ato_stop_error_m.max_abs", "ato_energy_kwh", "ato_margin_mps",
      "ato_interventions", "ato_on_target")),
)
# Not plotted: counts (their percentages are), the truth (set by the sweep, not estimated)
NOT_PLOTTED = {"moving_samples", "speed_within_2sigma", "position_within_2sigma", "mass_stops_covered",
               "duration_s", "stops", "mass_true_t", "A0_true", "A1_true", "A2_true", "ato_spans", "ato_arrived"}
PANEL_TITLES = {
    "mass_error_pct": "mass error at the end",
    "mass_errors_at_stops_pct.max_abs": "largest |mass error| at a stop",
    "mass_std_t": "mass std at the end",
    "mass_z_at_stops.max_abs": "largest |mass error| / std at a stop",
    "mass_time_within_1pct_s.max_abs": "longest time to 1 % after a departure",
    "mass_est_t": "mass estimate at the end",
    "A0_est": "A0 identified", "A1_est": "A1 identified", "A2_est": "A2 identified",
    "w0_rel_rms_error": "w0(V) relative RMS error",
    "coast_time_errors_s.max_abs": "largest coast time error",
    "speed_rmse_sensor": "speed RMSE, sensor", "speed_rmse_filter": "speed RMSE, filter",
    "speed_rmse_oracle": "speed RMSE, filter knowing the truth",
    "position_rmse_sensor": "distance RMSE, sensor", "position_rmse_filter": "distance RMSE, filter",
    "position_rmse_oracle": "distance RMSE, filter knowing the truth",
    "speed_nees": "speed NEES (dashed: 1, honest)", "position_nees": "distance NEES (dashed: 1, honest)",
    "speed_within_2sigma_pct": "speed truth within 2 sigma (dashed: 95.4)",
    "position_within_2sigma_pct": "distance truth within 2 sigma (dashed: 95.4)",
    "ato_arrival_error_s.max_abs": "worst |arrival error| of a span",
    "ato_stop_error_m.max_abs": "worst |stop error| of a span",
    "ato_energy_kwh": "energy from the network", "ato_margin_mps": "least margin to the speed limit",
    "ato_interventions": "safety interventions", "ato_on_target": "spans within +-2.5 s and +-0.3 m",
}
# What an honest estimator gives (a dashed line in the panel): NEES 1, 95.4 % of Gaussian errors within 2 sigma
HONEST_VALUES = {"speed_nees": 1.0, "position_nees": 1.0, "speed_within_2sigma_pct": 95.4,
                 "position_within_2sigma_pct": 95.4}
MEDIAN_LINE_MAX_VALUES = 30        # a swept name with more distinct values gets no median line
PLOT_SAMPLE_ROWS = 5_000
"""Rows plotted at most: a larger sweep is plotted from a sample of this many (PlotSample)."""


class PlotSample:
    """At most ``size`` rows out of those offered one at a time: the ``size`` whose run ids hash
    smallest, so the sample is the same whatever order the rows come in (completion order) and
    spread over the whole sweep (the ids of a grid or hypercube walk its axes in order)."""

    def __init__(self, size: int):
        self.size = size
        self._heap: list = []            # (-hash, run id, row): the largest hash on top, dropped first

    @staticmethod
    def _hash(run_id: int) -> int:
        return (run_id * 0x9E3779B97F4A7C15 + 0x632BE59BD9B4E019) % 2**64     # Fibonacci hashing

    def offer(self, row: dict) -> None:
        item = (-self._hash(row["run_id"]), row["run_id"], row)
        if len(self._heap) < self.size:
            heapq.heappush(self._heap, item)
        elif item[0] > self._heap[0][0]:
            heapq.heapreplace(self._heap, item)

    def rows(self) -> list[dict]:
        """The sample, sorted by run id."""
        return [row for _, _, row in sorted(self._heap, key=lambda item: item[1])]


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def _label(column: Column) -> str:
    """Axis label of a column: its key and unit ('-' for a dimensionless number)."""
    return f"{column.key} [{display_unit(column.unit) if column.unit else '-'}]"


def _varying_metrics(table: Table) -> list[Column]:
    """Numeric metric columns, other than NOT_PLOTTED, that vary over the ok runs."""
    ok = table.ok_rows()
    keys = {c.key for c in metric_columns()} | {c.key for c in CALIBRATION_COLUMNS} | {c.key for c in ATO_SWEEP_COLUMNS}
    out = []
    for c in table.columns:
        if c.kind == "str" or c.key not in keys or c.key in NOT_PLOTTED:
            continue
        xs = finite_values(r.get(c.key) for r in ok)
        if xs and max(xs) > min(xs):
            out.append(c)
    return out


def metric_groups(table: Table) -> list[tuple[str, str, list[Column]]]:
    """(file prefix, title, columns) of each figure's worth of varying metrics: PLOT_GROUPS' metrics
    that vary (groups with none left out), then the other varying metrics in ``other`` groups of at
    most PANELS_PER_FIGURE."""
    varying = {c.key: c for c in _varying_metrics(table)}
    groups, grouped = [], set()
    for prefix, title, keys in PLOT_GROUPS:
        cols = [varying[k] for k in keys if k in varying]
        grouped.update(keys)
        for i in range(0, len(cols), PANELS_PER_FIGURE):
            part = "" if i == 0 else f"_{i // PANELS_PER_FIGURE + 1}"
            groups.append((prefix + part, title, cols[i:i + PANELS_PER_FIGURE]))
    rest = [c for k, c in varying.items() if k not in grouped]
    for i in range(0, len(rest), PANELS_PER_FIGURE):
        part = "" if i == 0 else f"_{i // PANELS_PER_FIGURE + 1}"
        groups.append(("other" + part, "other metrics", rest[i:i + PANELS_PER_FIGURE]))
    return groups


def _panels(plt, n: int):
    """A figure with ``n`` panels (up to 3 a row) and its axes, in reading order."""
    ncol = n if n <= 3 else 2 if n == 4 else 3
    nrow = math.ceil(n / ncol)
    width = max(PANEL_INCHES[0] * ncol, MIN_FIGURE_WIDTH_IN)
    fig, axs = plt.subplots(nrow, ncol, figsize=(width, PANEL_INCHES[1] * nrow + 0.9), squeeze=False)
    for ax in axs.flat[n:]:
        ax.set_visible(False)
    return fig, list(axs.flat[:n])


def _suptitle(fig, text: str) -> None:
    """The figure's title, wrapped to the figure's width (a long title would be cut at the edges)."""
    chars = int(fig.get_figwidth() * 72 / (SUPTITLE_PT * 0.62))      # a character ~0.6 em wide
    fig.suptitle(textwrap.fill(text, chars), fontsize=SUPTITLE_PT)


def _style(ax, title: str, xlabel: str, ylabel: str) -> None:
    ax.set_title(title, fontsize=TITLE_PT)
    ax.set_xlabel(xlabel, fontsize=LABEL_PT)
    ax.set_ylabel(ylabel, fontsize=LABEL_PT)
    ax.tick_params(labelsize=TICK_PT)
    ax.grid(True, alpha=0.3)


def _finite_pairs(rows, x: str, y: str) -> list[tuple[float, float]]:
    return [(float(r[x]), float(r[y])) for r in rows
            if r.get(y) is not None and math.isfinite(r[y]) and r.get(x) is not None and math.isfinite(r[x])]


def _runs_text(ok: list[dict], ok_runs: int | None) -> str:
    """'N ok runs', or for a sample 'a sample of N of the M ok runs'."""
    if ok_runs is not None and ok_runs > len(ok):
        return f"a sample of {len(ok)} of the {ok_runs} ok runs"
    return f"{len(ok)} ok runs"


def _vs_figure(plt, sweep: Sweep, ok: list[dict], x: Column, title: str, cols: list[Column], median_line: bool,
               ok_runs: int | None = None):
    fig, axs = _panels(plt, len(cols))
    for ax, m in zip(axs, cols):
        pts = _finite_pairs(ok, x.key, m.key)
        if pts:
            ax.plot(*zip(*pts), ".", ms=5, alpha=0.6, color="C0")
        if median_line and pts:
            xs = sorted({p[0] for p in pts})
            ax.plot(xs, [float(np.median([p[1] for p in pts if p[0] == v])) for v in xs], "-", color="C1", lw=1.8)
        if m.key in HONEST_VALUES:
            ax.axhline(HONEST_VALUES[m.key], ls="--", color="0.4", lw=1.2)
        _style(ax, PANEL_TITLES.get(m.key, m.key), _label(x), _label(m))
    how = "dots: runs; line: median of each value" if median_line else "dots: runs"
    _suptitle(fig, f"{sweep.name}: {title} vs {x.key} ({_runs_text(ok, ok_runs)}; {how})")
    return fig


def _histogram_figure(plt, sweep: Sweep, ok: list[dict], title: str, cols: list[Column], ok_runs: int | None = None):
    from matplotlib.ticker import MaxNLocator
    fig, axs = _panels(plt, len(cols))
    bins = min(30, max(5, len(ok) // 5))
    for ax, m in zip(axs, cols):
        ax.hist(finite_values(r.get(m.key) for r in ok), bins=bins, color="C0", edgecolor="white")
        if m.key in HONEST_VALUES:
            ax.axvline(HONEST_VALUES[m.key], ls="--", color="0.4", lw=1.2)
        _style(ax, PANEL_TITLES.get(m.key, m.key), _label(m), "runs")
        ax.yaxis.set_major_locator(MaxNLocator(integer=True))      # counts of runs
    _suptitle(fig, f"{sweep.name}: {title}, distribution over {_runs_text(ok, ok_runs)}")
    return fig


def _heatmap_figure(plt, sweep: Sweep, table: Table, a: Column, b: Column, title: str, cols: list[Column]):
    ok = table.ok_rows()
    av = sorted({r[a.key] for r in table.rows})
    bv = sorted({r[b.key] for r in table.rows})
    fig, axs = _panels(plt, len(cols))
    for ax, m in zip(axs, cols):
        z = np.full((len(bv), len(av)), np.nan)
        for i, y in enumerate(bv):
            for j, x in enumerate(av):
                vals = finite_values(r.get(m.key) for r in ok if r[a.key] == x and r[b.key] == y)
                if vals:
                    z[i, j] = float(np.mean(vals))   # the mean over the other axes (seeds)
        im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis")
        ax.set_xticks(range(len(av)), [f"{x:.4g}" for x in av], rotation=45 if len(av) > 6 else 0)
        ax.set_yticks(range(len(bv)), [f"{y:.4g}" for y in bv])
        _style(ax, PANEL_TITLES.get(m.key, m.key), _label(a), _label(b))
        ax.grid(False)
        cb = fig.colorbar(im, ax=ax)
        cb.set_label(_label(m), fontsize=LABEL_PT)
        cb.ax.tick_params(labelsize=TICK_PT)
    _suptitle(fig, f"{sweep.name}: {title}, mean over the other axes (blank: every run failed)")
    return fig


def sweep_figures(sweep: Sweep, table: Table, ok_runs: int | None = None):
    """Yields (file name, matplotlib Figure) for each plot of the sweep (see the module docstring),
    one at a time: the caller saves and closes each (plot_sweep) before the next is made. None when
    no run is ok or no metric varies. ``ok_runs``: the sweep's ok runs when ``table`` is a sample
    of its rows (the titles say so)."""
    plt = pyplot()
    ok = table.ok_rows()
    groups = metric_groups(table)
    if not ok or not groups:
        return
    by_key = {c.key: c for c in table.columns}
    swept = [by_key[n] for n in sweep.axes if n != "seed" and by_key[n].kind != "str"
             and len({r.get(n) for r in ok}) > 1]
    discrete = set(sweep.blocks.get("grid", ())) | set(sweep.blocks.get("zip", ()))
    for x in swept:
        median_line = x.key in discrete and len({r.get(x.key) for r in ok}) <= MEDIAN_LINE_MAX_VALUES
        for prefix, title, cols in groups:
            yield f"{prefix}_vs_{_safe(x.key)}.png", _vs_figure(plt, sweep, ok, x, title, cols, median_line, ok_runs)
    if "seed" in sweep.axes and len(ok) > 1:
        for prefix, title, cols in groups:
            yield f"{prefix}_histograms.png", _histogram_figure(plt, sweep, ok, title, cols, ok_runs)
    grid = [by_key[n] for n in sweep.grid_axes if by_key[n].kind != "str"]
    if len(sweep.grid_axes) == 2 and len(grid) == 2:
        a, b = grid
        for prefix, title, cols in groups:
            yield (f"{prefix}_heatmap_{_safe(a.key)}__{_safe(b.key)}.png",
                   _heatmap_figure(plt, sweep, table, a, b, title, cols))


def plot_sweep(sweep: Sweep, table: Table, plot_dir: Path, ok_runs: int | None = None) -> list[Path]:
    """Write sweep_figures' figures as PNGs into ``plot_dir``; their paths. ``ok_runs``: see
    sweep_figures."""
    plot_dir.mkdir(parents=True, exist_ok=True)
    return [save_figure(fig, None, plot_dir / name, dpi=DPI) for name, fig in sweep_figures(sweep, table, ok_runs)]
