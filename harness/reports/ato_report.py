"""The report of a span scenario: planned vs actual V(s) with the mode bar, and the ATO table.

``ato_figure`` returns the matplotlib figure (tests read its artists); ``write_ato_report``
saves it as ato.png and gives the table summary.md takes, from the metrics computed once
(harness.metrics.ato, via harness.metrics.run) and the ATO's calls the run recorded
(RunResult.driver_steps). Per span, two axes over the true
distance from the previous station [m]: the speeds (true car.speed, filter.speed the ATO reads,
the planned speed of its commands, V_lim(s)) and a bar of the ATO's mode (AtoMode) along s.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from models.ato.interface import AtoMode

from harness.reports.plotting import pyplot
from harness.metrics.ato import markdown_ato

MODE_COLOURS = {
    AtoMode.TG: "tab:green", AtoMode.C: "yellowgreen", AtoMode.VB: "lightgrey",
    AtoMode.SR: "tab:cyan", AtoMode.RK: "tab:blue", AtoMode.ST: "tab:purple",
    AtoMode.TM: "tab:orange", AtoMode.EP: "tab:brown", AtoMode.HOLD: "black",
    AtoMode.SAFE: "red", AtoMode.OVERSPEED: "magenta", AtoMode.CREEP: "gold",
}
"""The mode bar's colour of each AtoMode."""
# a mode the controller gains later (SETTLE, ...) gets a colour of its own, not a blank bar
_SPARE = ("tab:olive", "tab:pink", "tab:gray", "navy", "teal", "salmon")
for _m in AtoMode:
    if _m not in MODE_COLOURS:
        MODE_COLOURS[_m] = _SPARE[sum(1 for k in MODE_COLOURS if k > 11) % len(_SPARE)]

NO_PLAN = (int(AtoMode.HOLD), int(AtoMode.SAFE))   # commands whose planned speed means nothing


def mode_runs(modes) -> list[tuple[int, int, int]]:
    """(mode, first index, last index + 1) of each run of equal modes."""
    out = []
    start = 0
    for j in range(1, len(modes) + 1):
        if j == len(modes) or modes[j] != modes[start]:
            out.append((int(modes[start]), start, j))
            start = j
    return out


def span_rows(steps, k: int, n: int) -> list[int]:
    """The result rows (< n) where span k's controller drove (not a dwell)."""
    return [j for j in range(min(n, len(steps))) if steps[j].span == k and not steps[j].dwell]


def ato_figure(result, steps):
    """Planned vs actual V(s) and the mode bar of every span of a span scenario's run
    (``steps``: the ATO's calls, row by row)."""
    plt = pyplot()
    spans = result.scenario.ato_setup().spans
    n = len(spans)
    fig = plt.figure(figsize=(11, 4.6 * n))
    outer = fig.add_gridspec(n, 1, hspace=0.3)
    x_all, v_all, f_all = result["car.position"], result["car.speed"], result["filter.speed"]
    for k, ls in enumerate(spans):
        inner = outer[k].subgridspec(2, 1, height_ratios=[5, 1], hspace=0.08)
        ax = fig.add_subplot(inner[0])
        bar = fig.add_subplot(inner[1], sharex=ax)
        ax.tick_params(labelbottom=False)
        rows = span_rows(steps, k, len(result.time))
        if not rows:
            ax.set_title(f"span {k + 1}: not reached")
            continue
        rows = rows[1:] if k > 0 else rows   # the departure row still stands at the last mark
        x, v, vf = x_all[rows], v_all[rows], f_all[rows]
        modes = [steps[j].command.mode for j in rows]
        planned = np.array([np.nan if steps[j].command.mode in NO_PLAN
                            else steps[j].command.planned_speed for j in rows])
        span = ls.span
        lim_x = list(span.limit_distances) + [span.stop]
        lim_v = list(span.limit_speeds) + [span.limit_speeds[-1]]
        ax.step(lim_x, lim_v, where="post", color="tab:red", lw=1.5, label="speed limit V_lim")
        ax.plot(x, v, color="k", lw=1.2, label="true car.speed")
        ax.plot(x, vf, color="tab:orange", lw=0.9, label="filter.speed (what the ATO reads)")
        ax.plot(x, planned, color="tab:green", lw=1.6, ls="--", label="planned (ATO commands)")
        ax.axvline(span.stop, color="0.4", ls=":", lw=1, label=f"stop mark {span.stop:g} m")
        ax.set_ylabel("speed [m/s]")
        ax.set_title(f"span {k + 1}: schedule {span.schedule:g} s, stop {span.stop:g} m")
        ax.legend(loc="lower center", fontsize="small", ncol=3)
        ax.set_xlim(0.0, span.length)
        seen = {}
        for mode, a, b in mode_runs(modes):
            x0 = float(x[a])
            x1 = float(x[b]) if b < len(x) else float(x[-1])
            colour = MODE_COLOURS[AtoMode(mode)]
            seen[mode] = colour
            bar.broken_barh([(x0, max(x1 - x0, 0.0))], (0.0, 1.0), facecolors=colour,
                            label=AtoMode(mode).name)
        bar.set_yticks([])
        bar.set_xlabel("distance from the previous station (true) [m]")
        bar.set_ylabel("mode")
        from matplotlib.patches import Patch
        bar.legend(handles=[Patch(color=c, label=AtoMode(m).name) for m, c in sorted(seen.items())],
                   loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize="small", title="ATO mode")
    return fig


def write_ato_report(result, metrics, out_dir: Path, steps=None) -> tuple[Path, list[str]]:
    """ato.png into ``out_dir`` for a run (``steps``: the ATO's calls, default the run's own,
    ``result.driver_steps``) and its span metrics ``metrics`` (harness.metrics.ato.SpanMetrics);
    returns (its path, the ATO table in markdown)."""
    from harness.reports.plotting import pyplot
    plt = pyplot()
    fig = ato_figure(result, result.driver_steps if steps is None else steps)
    fig.suptitle(f"{result.scenario.name}: planned vs actual V(s), ATO mode")
    # nested grids (a bar under each speed plot) are not tight_layout's: fixed margins, and
    # the legends right of the bars kept by bbox_inches
    fig.subplots_adjust(left=0.07, right=0.86, top=1.0 - 0.85 / fig.get_figheight(),
                        bottom=0.45 / fig.get_figheight())
    path = out_dir / "ato.png"
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path, markdown_ato(metrics)
