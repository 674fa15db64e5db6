"""A sweep's plots (PNG, matplotlib's Agg backend): every varying metric against each swept value
(``vs_NAME.png``), their distribution over seeds (``histograms.png``) and, for a two-axis grid,
heat maps (``heatmap_A__B.png``).
"""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from harness.reports.plotting import pyplot, save_figure
from harness.sweep.spec import Sweep
from harness.sweep.table import CALIBRATION_COLUMNS, Column, Table, finite_values, metric_columns


def _safe(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name)


def _plot_metrics(table: Table) -> list[Column]:
    """Numeric metric columns that vary over the ok runs."""
    ok = table.ok_rows()
    keys = {c.key for c in metric_columns()} | {c.key for c in CALIBRATION_COLUMNS}
    skip = {"moving_samples", "speed_within_2sigma", "position_within_2sigma", "duration_s"}
    out = []
    for c in table.columns:
        if c.kind == "str" or c.key not in keys or c.key in skip:
            continue
        xs = finite_values(r.get(c.key) for r in ok)
        if xs and max(xs) > min(xs):
            out.append(c)
    return out


def plot_sweep(sweep: Sweep, table: Table, plot_dir: Path) -> list[Path]:
    """Each metric against each swept value (and heat maps of a two-axis grid) as PNGs."""
    plt = pyplot()
    plot_dir.mkdir(parents=True, exist_ok=True)
    ok = table.ok_rows()
    metrics = _plot_metrics(table)
    if not ok or not metrics:
        return []
    units = {c.key: c.unit for c in table.columns}
    kinds = {c.key: c.kind for c in table.columns}
    files = []
    ncol = min(5, len(metrics))
    nrow = math.ceil(len(metrics) / ncol)

    def grid_fig():
        fig, axs = plt.subplots(nrow, ncol, figsize=(3.4 * ncol, 2.6 * nrow), squeeze=False)
        for ax in axs.flat[len(metrics):]:
            ax.set_visible(False)
        return fig, axs.flat

    def save(fig, name):
        files.append(save_figure(fig, None, plot_dir / name, dpi=90))

    xs_names = [n for n in sweep.axes if n != "seed" and kinds.get(n) != "str"
                and len({r.get(n) for r in ok}) > 1]
    for xn in xs_names:
        fig, axs = grid_fig()
        for ax, m in zip(axs, metrics):
            pts = [(r[xn], r[m.key]) for r in ok if r.get(m.key) is not None and math.isfinite(r[m.key])]
            if pts:
                ax.plot(*zip(*pts), ".", ms=4, alpha=0.7)
            ax.set_xlabel(f"{xn} [{units.get(xn) or '-'}]", fontsize=8)
            ax.set_title(f"{m.key} [{m.unit}]", fontsize=8)
            ax.tick_params(labelsize=7)
        fig.suptitle(f"{sweep.name}: metrics vs {xn} ({len(ok)} ok runs)", fontsize=10)
        save(fig, f"vs_{_safe(xn)}.png")

    if "seed" in sweep.axes and len(ok) > 1:
        fig, axs = grid_fig()
        for ax, m in zip(axs, metrics):
            ax.hist(finite_values(r.get(m.key) for r in ok), bins=min(30, max(5, len(ok) // 5)))
            ax.set_title(f"{m.key} [{m.unit}]", fontsize=8)
            ax.tick_params(labelsize=7)
        fig.suptitle(f"{sweep.name}: distribution over {len(ok)} ok runs", fontsize=10)
        save(fig, "histograms.png")

    grid = [n for n in sweep.grid_axes if kinds.get(n) != "str"]
    if len(sweep.grid_axes) == 2 and len(grid) == 2:
        a, b = grid
        av = sorted({r[a] for r in table.rows})
        bv = sorted({r[b] for r in table.rows})
        fig, axs = grid_fig()
        for ax, m in zip(axs, metrics):
            z = np.full((len(bv), len(av)), np.nan)
            for i, y in enumerate(bv):
                for j, x in enumerate(av):
                    vals = finite_values(r.get(m.key) for r in ok if r[a] == x and r[b] == y)
                    if vals:
                        z[i, j] = float(np.mean(vals))   # the mean over the other axes (seeds)
            im = ax.imshow(z, origin="lower", aspect="auto", cmap="viridis")
            ax.set_xticks(range(len(av)), [f"{x:.4g}" for x in av], fontsize=6, rotation=45)
            ax.set_yticks(range(len(bv)), [f"{y:.4g}" for y in bv], fontsize=6)
            ax.set_xlabel(f"{a} [{units.get(a) or '-'}]", fontsize=7)
            ax.set_ylabel(f"{b} [{units.get(b) or '-'}]", fontsize=7)
            ax.set_title(f"{m.key} [{m.unit}]", fontsize=8)
            cb = fig.colorbar(im, ax=ax)
            cb.ax.tick_params(labelsize=6)
        fig.suptitle(f"{sweep.name}: heat maps over {a} x {b} (mean over other axes; blank: failed)", fontsize=10)
        save(fig, f"heatmap_{_safe(a)}__{_safe(b)}.png")
    return files
