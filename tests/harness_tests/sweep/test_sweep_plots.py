"""What a sweep's plots show, read from matplotlib's objects (never pixels): a few panels per
figure, grouped by what they say; every axis labelled with its unit (histograms count "runs"),
text large enough to read; the dots, median lines, bars and heat-map cells are the table's values
(failed runs left out); every varying metric is plotted once, constant ones not at all.

The table is made up here (seeded random metrics on a 3 x 2 grid x 4 seeds of level_run, one
run failed): no FMU runs, the module takes a few seconds."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from matplotlib.image import AxesImage

from harness.sweep.plots import NOT_PLOTTED, PANELS_PER_FIGURE, PLOT_GROUPS, metric_groups, plot_sweep, sweep_figures
from harness.sweep.spec import load_sweep
from harness.sweep.table import CALIBRATION_COLUMNS, TEXT_STATUS_FAILED, TEXT_STATUS_OK, Table, metric_columns, \
    sweep_columns

ROOT = Path(__file__).resolve().parents[3]
LEVEL = ROOT / "scenarios" / "library" / "level_run.toml"
SWEEP = f"""
name = "t_plots_of_a_sweep_with_a_long_name"       # a long title to wrap
scenario = "{LEVEL.as_posix()}"
seeds = 4
[grid]
"car.mass" = [30.0, 34.0, 38.0]
"sensor.speed_std" = [0.02, 0.08]
"""
CONSTANT = "position_rmse_sensor"        # the same in every run: not plotted
FAILED_RUN = 5
SMALLEST_PT = 9.0                        # [pt] no text on the plots smaller
NUMERIC = [c for c in metric_columns() + list(CALIBRATION_COLUMNS) if c.kind != "str"]


def made_up_table(sweep) -> Table:
    """A row per run: the swept values, seeded random metrics (CONSTANT the same in every row), and
    run FAILED_RUN failed with nan metrics (a failed row's metrics are empty)."""
    rng = np.random.default_rng(26)
    cols = sweep_columns(sweep)
    rows = []
    for run in sweep.runs:
        row = {"run_id": run.run_id, "status": TEXT_STATUS_OK, "error": "", "wall_time": 0.1, "fmu": "native",
               **dict(run.values)}
        for c in NUMERIC:
            row[c.key] = int(rng.integers(1, 100)) if c.kind == "int" else float(rng.normal(1.0, 0.3))
        row[CONSTANT] = 1.0
        if run.run_id == FAILED_RUN:
            row.update(status=TEXT_STATUS_FAILED, error="made up", **{c.key: None for c in NUMERIC})
        rows.append(row)
    return Table(cols, rows)


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    path = tmp_path_factory.mktemp("plots") / "t_plots.toml"
    path.write_text(SWEEP, encoding="utf-8")
    return load_sweep(path)


@pytest.fixture(scope="module")
def table(sweep):
    return made_up_table(sweep)


@pytest.fixture(scope="module")
def figures(sweep, table):
    import matplotlib.pyplot as plt
    figs = dict(sweep_figures(sweep, table))
    yield figs
    for fig in figs.values():
        plt.close(fig)


def panels(fig) -> list:
    """The visible axes of a figure that are panels (not colour bars)."""
    return [ax for ax in fig.axes if ax.get_visible() and ax.get_label() != "<colorbar>"]


def metric_of(label: str) -> str:
    """'mass_std_t [t]' -> 'mass_std_t'."""
    return label.rsplit(" [", 1)[0]


def ok_rows(table) -> list[dict]:
    return [r for r in table.rows if r["status"] == TEXT_STATUS_OK]


GROUPS = [g[0] for g in PLOT_GROUPS if g[0] != "ato"]     # the ATO's: a span scenario's sweep (test_sweep_ato.py)


def test_each_group_has_a_figure_per_swept_value_histograms_and_heat_maps(figures):
    want = {f"{g}_{kind}.png" for g in GROUPS
            for kind in ("vs_car.mass", "vs_sensor.speed_std", "histograms", "heatmap_car.mass__sensor.speed_std")}
    assert set(figures) == want


def test_every_varying_metric_is_plotted_once_and_no_constant_one(table):
    plotted = [c.key for _, _, cols in metric_groups(table) for c in cols]
    numeric = {c.key for c in NUMERIC}
    assert sorted(plotted) == sorted(numeric - NOT_PLOTTED - {CONSTANT})
    assert CONSTANT in numeric                                     # the control: it would have been plotted


def test_few_panels_readable_text_and_every_axis_labelled_with_a_unit(figures):
    for name, fig in figures.items():
        axs = panels(fig)
        assert 1 <= len(axs) <= PANELS_PER_FIGURE, name
        assert fig._suptitle is not None and fig._suptitle.get_fontsize() > SMALLEST_PT
        fig.tight_layout()                                    # as saved (harness.reports.plotting)
        title = fig._suptitle.get_window_extent(fig.canvas.get_renderer())
        assert 0 <= title.x0 and title.x1 <= fig.bbox.width, (name, fig._suptitle.get_text())   # not cut off
        for ax in axs:
            texts = [ax.title, ax.xaxis.label, ax.yaxis.label] + ax.get_xticklabels() + ax.get_yticklabels()
            assert min(t.get_fontsize() for t in texts) >= SMALLEST_PT, (name, ax.get_title())
            assert ax.get_title(), name
            x, y = ax.get_xlabel(), ax.get_ylabel()
            if "histograms" in name:
                assert y == "runs" and x.endswith("]") and " [" in x, (name, x, y)
            else:
                assert x.endswith("]") and " [" in x and y.endswith("]") and " [" in y, (name, x, y)


def test_dots_are_the_ok_runs_and_the_line_their_median_per_value(figures, table):
    ok = ok_rows(table)
    fig = figures["mass_vs_car.mass.png"]
    for ax in panels(fig):
        m = metric_of(ax.get_ylabel())
        dots, median = ax.lines[0], ax.lines[1]
        got = sorted(zip(dots.get_xdata(), dots.get_ydata()))
        assert got == sorted((r["car.mass"], r[m]) for r in ok)            # exact: the values themselves
        assert len(got) == len(table.rows) - 1                             # the failed run left out
        xs = [30.0, 34.0, 38.0]
        assert list(median.get_xdata()) == xs
        want = [np.median([r[m] for r in ok if r["car.mass"] == x]) for x in xs]
        np.testing.assert_allclose(median.get_ydata(), want, rtol=0, atol=0)


def test_histogram_bars_count_the_ok_runs(figures, table):
    ok = ok_rows(table)
    for g in GROUPS:
        for ax in panels(figures[f"{g}_histograms.png"]):
            m = metric_of(ax.get_xlabel())
            heights = [p.get_height() for p in ax.patches]
            assert sum(heights) == len(ok) and all(float(h).is_integer() for h in heights), m
            lo = min(p.get_x() for p in ax.patches)
            assert lo == pytest.approx(min(r[m] for r in ok), rel=1e-12, abs=0)


def test_heat_map_cells_are_the_mean_over_seeds(figures, table, sweep):
    ok = ok_rows(table)
    fig = figures["filter_accuracy_heatmap_car.mass__sensor.speed_std.png"]
    colorbars = [ax for ax in fig.axes if ax.get_label() == "<colorbar>"]
    assert len(colorbars) == len(panels(fig))
    assert all(cb.get_ylabel().endswith("]") for cb in colorbars)              # the metric and its unit
    for ax, cb in zip(panels(fig), colorbars):
        [image] = [a for a in ax.get_children() if isinstance(a, AxesImage)]
        z = np.asarray(image.get_array())
        m = metric_of(cb.get_ylabel())
        for i, s in enumerate([0.02, 0.08]):                # rows: sensor.speed_std (the y axis)
            for j, mass in enumerate([30.0, 34.0, 38.0]):
                vals = [r[m] for r in ok if r["car.mass"] == mass and r["sensor.speed_std"] == s]
                assert len(vals) == (3 if (mass, s) == (30.0, 0.08) else 4)   # run 5: the failed one
                assert z[i, j] == pytest.approx(float(np.mean(vals)), rel=1e-12, abs=0)
        assert ax.get_xlabel() == "car.mass [t]" and ax.get_ylabel() == "sensor.speed_std [m/s]"


def test_plot_sweep_writes_one_png_per_figure_and_closes_it(sweep, table, tmp_path):
    """With one varying metric (few panels: saving is the slow part), one PNG per figure."""
    import matplotlib.pyplot as plt
    one = Table(table.columns, [{**r, **{c.key: 1.0 for c in NUMERIC if c.kind == "float"
                                         and c.key != "speed_nees" and r["status"] == TEXT_STATUS_OK}}
                                for r in table.rows])
    open_before = plt.get_fignums()
    files = plot_sweep(sweep, one, tmp_path / "plots")
    assert sorted(p.name for p in files) == sorted(p.name for p in (tmp_path / "plots").glob("*.png"))
    assert sorted(p.name for p in files) == ["filter_calibration_heatmap_car.mass__sensor.speed_std.png",
                                             "filter_calibration_histograms.png",
                                             "filter_calibration_vs_car.mass.png",
                                             "filter_calibration_vs_sensor.speed_std.png"]
    assert all(p.stat().st_size > 1000 for p in files)
    assert plt.get_fignums() == open_before                    # a long sweep holds no figures


def test_no_ok_run_no_plot(sweep, table, tmp_path):
    failed = Table(table.columns, [{**r, "status": TEXT_STATUS_FAILED} for r in table.rows])
    assert list(sweep_figures(sweep, failed)) == []
    assert plot_sweep(sweep, failed, tmp_path / "none") == []
