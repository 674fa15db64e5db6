"""What a run report's plots and summary show, read from matplotlib's objects (never pixels):
the band of the identified resistance curve is the A's covariance the run recorded (est.cov_*
off the diagonal) propagated, or without those outputs the stds alone, labelled so, and no
model runs for it; the bands of the time plots stay inside their axes, which are scaled to the
estimate and the truth, not to the prior's band; every band has a legend entry; the summary
gives each A's standard deviation with its unit, floats in few digits. And the command line:
every option has a help text.

The runs are made here on the models' Python chain (no FMU, well under a second each), with the
est.cov_* columns taken from the chain's estimator as the FMUs output them; one test runs the
native FMU from the session build."""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest
from matplotlib.collections import PolyCollection

from harness.metrics.estimation import resistance_covariance
from harness.reports import run_report as report
from harness.run.runner import INPUTS, RunResult
from harness.run.scenario import load_scenario
from models.chain import RailCarChain

ROOT = Path(__file__).resolve().parents[3]
DEFAULT = ROOT / "scenarios" / "default.toml"
UNITS = {"A0": "N/kN", "A1": "N/kN/(m/s)", "A2": "N/kN/(m/s)²"}
COV = {(0, 1): "est.cov_A0_A1", (0, 2): "est.cov_A0_A2", (1, 2): "est.cov_A1_A2"}


def a_covariance(chain) -> np.ndarray:
    """The chain's estimator's covariance of (A0, A1, A2) now (what est.A*_std are the square
    roots of the diagonal of, and est.cov_* the rest)."""
    e = chain.estimator
    return np.array(e.method.with_resistance_covariance(e.ident.covariance())[1:, 1:], dtype=float)


def open_loop_run(scenario, seconds: float = 100.0):
    """``scenario``'s car (its parameters and seed) driven open loop: 40 kN of traction for 25 s,
    coast to 60 s, 20 kN to 70 s, then 30 kN of brake; a RunResult as the FMU runner makes one
    (with the est.cov_* outputs), and the chain at the end (its estimator holds the covariance)."""
    s = scenario.chain_setup()
    chain = RailCarChain(s.config, s.grade, s.speed)
    h = scenario.step_s

    def outputs():
        out, c = chain.outputs(), a_covariance(chain)
        out.update({name: float(c[i, j]) for (i, j), name in COV.items()})
        return out

    rows, inputs = [outputs()], []
    for k in range(int(round(seconds / h))):
        t = k * h
        u = (40e3 if t < 25 else 0.0 if t < 60 else 20e3 if t < 70 else 0.0,
             30e3 if t >= 70 else 0.0, 0.0, 0.0)
        chain.do_step(t, h, *u)
        rows.append(outputs())
        inputs.append(u)
    inputs.append(inputs[-1])
    u_arr = np.array(inputs)
    result = RunResult(scenario, np.arange(len(rows)) * h, {n: np.array([r[n] for r in rows]) for n in rows[0]},
                       {}, inputs={n: u_arr[:, j] for j, n in enumerate(INPUTS)})
    return result, chain


@pytest.fixture(scope="module")
def run():
    return open_loop_run(load_scenario(DEFAULT))


def true_A(result) -> tuple:
    return tuple(result.scenario.parameter(f"car.{a}") for a in UNITS)


def bands(ax) -> list:
    """The filled areas (fill_between) of an axes."""
    return [c for c in ax.collections if isinstance(c, PolyCollection)]


def band_edges(poly, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper edge of a fill_between area at the abscissae ``x`` (its vertices' x are
    the plotted x, copied exactly)."""
    verts = poly.get_paths()[0].vertices
    lo = np.array([verts[verts[:, 0] == xi, 1].min() for xi in x])
    hi = np.array([verts[verts[:, 0] == xi, 1].max() for xi in x])
    return lo, hi


def legend_texts(ax) -> list[str]:
    leg = ax.get_legend()
    return [t.get_text() for t in leg.get_texts()] if leg else []


def close(fig):
    import matplotlib.pyplot as plt
    plt.close(fig)


def without_covariances(result) -> RunResult:
    """The run as an FMU built before the est.cov_* outputs records it."""
    return RunResult(result.scenario, result.time, {n: v for n, v in result.signals.items() if n not in COV.values()},
                     {}, inputs=result.inputs)


# ------------------------------------------------------------------------------ resistance.png

def test_the_covariance_of_the_As_is_the_runs_own_outputs(run):
    """The stds on the diagonal (squared), est.cov_* off it, bit for bit: the estimator's own
    covariance at the end (the diagonal within an ulp or two: sqrt then square)."""
    result, chain = run
    cov, full = resistance_covariance(result)
    assert full and cov.shape == (3, 3)
    own = a_covariance(chain)
    for (i, j), name in COV.items():
        assert cov[i, j] == cov[j, i] == result[name][-1] == own[i, j]
    std = np.array([result[f"est.{a}_std"][-1] for a in UNITS])
    assert np.diag(cov).tobytes() == (std * std).tobytes()
    np.testing.assert_allclose(np.diag(cov), np.diag(own), rtol=1e-15, atol=0)
    corr = cov[0, 2] / np.sqrt(cov[0, 0] * cov[2, 2])
    assert abs(corr) > 0.5        # A0 and A2 correlate: why the stds alone would mislead


def test_resistance_band_is_the_covariance_propagated_to_w0(run):
    """Half-width of the band at every plotted speed = 2 sqrt(phi^T C phi), phi = (1, V, V^2).
    Tolerance 1e-12 relative: the figure computes the same sum in another order (einsum), a few
    ulps apart. Control: the stds alone give a band that differs by far more (the A's correlate)."""
    result, chain = run
    cov, _ = resistance_covariance(result)
    fig = report.resistance_figure(result, true_A(result))
    ax = fig.axes[0]
    [poly] = bands(ax)
    v = ax.lines[1].get_xdata()                                       # the identified curve's speeds
    lo, hi = band_edges(poly, v)
    phi = np.stack([np.ones_like(v), v, v * v], axis=1)
    sd = np.sqrt(np.array([p @ cov @ p for p in phi]))
    np.testing.assert_allclose((hi - lo) / 4, sd, rtol=1e-12, atol=0)
    np.testing.assert_allclose((hi + lo) / 2, ax.lines[1].get_ydata(), rtol=1e-12, atol=1e-15)
    sd_diag = np.sqrt(np.array([p @ np.diag(np.diag(cov)) @ p for p in phi]))
    assert np.max(np.abs(sd_diag / sd - 1)) > 0.1                    # correlations matter here
    label = poly.get_label()
    assert "covariance" in label and "ignored" not in label and label in legend_texts(ax)
    close(fig)


def test_resistance_band_falls_back_to_the_stds_and_says_so(run):
    """A run without the est.cov_* outputs gets the band of the stds alone, labelled as ignoring
    the correlations."""
    result, _ = run
    bare = without_covariances(result)
    cov, full = resistance_covariance(bare)
    assert not full and np.count_nonzero(cov - np.diag(np.diag(cov))) == 0
    fig = report.resistance_figure(bare, true_A(result))
    ax = fig.axes[0]
    [poly] = bands(ax)
    v = ax.lines[1].get_xdata()
    lo, hi = band_edges(poly, v)
    s = [bare.signals[f"est.{a}_std"][-1] for a in UNITS]
    sd = np.sqrt(s[0] ** 2 + v ** 2 * s[1] ** 2 + v ** 4 * s[2] ** 2)
    np.testing.assert_allclose((hi - lo) / 4, sd, rtol=1e-12, atol=0)   # as above
    assert "correlations ignored" in poly.get_label() and poly.get_label() in legend_texts(ax)
    close(fig)


def test_no_model_runs_for_a_plot(run, monkeypatch, tmp_path):
    """Drawing the whole report builds no chain and no estimator (the metrics' oracle filter is
    the only model run after the FMU's, and it is not the report's)."""
    import models.chain
    import models.estimation.online
    from harness.metrics.run import RunMetrics
    from harness.metrics.estimation import summarise
    result, _ = run
    metrics = RunMetrics(summarise(result), true_A(result), (1.0, 1.0, 1.0), *resistance_covariance(result))

    def refuse(*args, **kwargs):
        raise AssertionError("a model was built for a plot")

    monkeypatch.setattr(models.chain.RailCarChain, "__init__", refuse)
    monkeypatch.setattr(models.estimation.online.OnlineEstimator, "__init__", refuse)
    files = report.write_report(result, metrics, tmp_path)
    assert [f.name for f in files[2:]] == ["speed.png", "estimates.png", "resistance.png", "resistance_vs_time.png"]


# ----------------------------------------------------------------------- resistance_vs_time.png

def test_resistance_vs_time_is_scaled_to_the_estimate_and_the_truth(run):
    """Each axis holds the whole estimate and the truth, with a 10 % margin, however wide the
    band; the band stays inside the axis: where it is wider (the prior's, A0 +-4 N/kN) it is not
    drawn, and the legend says so and gives its width at the end."""
    result, _ = run
    A = true_A(result)
    fig = report.resistance_vs_time_figure(result, A)
    for j, (name, unit) in enumerate(UNITS.items()):
        ax = fig.axes[j]
        est, sd = result[f"est.{name}"], result[f"est.{name}_std"]
        y0, y1 = ax.get_ylim()
        lo, hi = min(est.min(), A[j]), max(est.max(), A[j])
        assert y0 < lo and hi < y1, name
        assert (y1 - y0) == pytest.approx(1.2 * (hi - lo), rel=1e-12), name   # margin 10 % each side
        [poly] = bands(ax)
        ys = np.concatenate([p.vertices[:, 1] for p in poly.get_paths()]) if poly.get_paths() else np.array([])
        assert np.all((ys >= y0) & (ys <= y1)), name                  # never beyond the axis
        xs = np.concatenate([p.vertices[:, 0] for p in poly.get_paths()]) if poly.get_paths() else np.array([])
        assert result.time[0] not in xs, name                         # the prior's band: left out ...
        label = poly.get_label()
        assert "wider than the axes" in label and f"+-{2 * sd[-1]:.3g} {unit}" in label, label   # ... and said
        assert label in legend_texts(ax)
    # control: scaled to the band (as before), A0's axis would be > 5x the estimate's range
    est0 = result["est.A0"]
    assert 4 * result["est.A0_std"][0] > 5 * (max(est0.max(), A[0]) - min(est0.min(), A[0]))
    close(fig)


def test_a_band_narrower_than_its_axis_is_drawn_where_it_fits(run):
    """Where 4 sigma fits the axis the band is drawn, clipped to it: A1's band at the end."""
    result, _ = run
    fig = report.resistance_vs_time_figure(result, true_A(result))
    drawn = [bool(bands(ax)[0].get_paths()) for ax in fig.axes[:3]]
    sd = [result[f"est.{a}_std"][-1] for a in UNITS]
    spans = [ax.get_ylim()[1] - ax.get_ylim()[0] for ax in fig.axes[:3]]
    assert drawn == [4 * s <= w or bool(np.any(4 * result[f"est.{a}_std"] <= w))
                     for s, w, a in zip(sd, spans, UNITS)]
    close(fig)


# ------------------------------------------------------------------------- speed / estimates.png

def test_every_band_has_a_legend_entry(run):
    result, _ = run
    figs = report.run_figures(result)
    found = []
    for fig in figs:
        for ax in fig.axes:
            for poly in bands(ax):
                assert not poly.get_label().startswith("_"), (fig.axes.index(ax), poly.get_label())
                assert poly.get_label() in legend_texts(ax)
                found.append(poly.get_label())
        close(fig)
    assert found.count("filter +-2 sigma") == 2                                 # speed, distance
    [mass] = [x for x in found if not x.startswith("filter")]
    # the mass's prior band (est.mass_std_initial) is wider than the axis: left out, and said
    assert mass.startswith("+-2 sigma") and "wider than the axes until t =" in mass, mass


def test_the_mass_band_stays_inside_its_axis(run):
    result, _ = run
    fig = report.run_figures(result)[1]
    ax = fig.axes[0]
    y0, y1 = ax.get_ylim()
    [poly] = bands(ax)
    ys = np.concatenate([p.vertices[:, 1] for p in poly.get_paths()])
    assert ys.size and np.all((ys >= y0) & (ys <= y1))
    assert 4 * result["est.mass_std"][0] > y1 - y0          # control: the prior's band would not fit
    close(fig)


# ---------------------------------------------------------------------------------- the summary

def test_summary_gives_each_A_its_std_and_unit(run):
    from harness.metrics.estimation import summarise
    result, _ = run
    text = report.format_run_summary(summarise(result), result)
    for name, unit in UNITS.items():
        [line] = [x for x in text.splitlines() if x.strip().startswith(f"{name} true / est")]
        sd = result[f"est.{name}_std"][-1]
        assert line.endswith(f" +- {sd:.4g} {unit}"), line
    [mass] = [x for x in text.splitlines() if "mass: true / estimated" in x]
    assert mass.count("+-") == 1


def test_summary_md_holds_the_As_stds(run, tmp_path):
    from harness.metrics.estimation import summarise
    result, _ = run
    page = report.write_summary_md(summarise(result), result.scenario, tmp_path / "summary.md", [],
                                   result=result).read_text(encoding="utf-8")
    assert f"+- {result['est.A2_std'][-1]:.4g} N/kN/(m/s)²" in page and "| A_std |" in page
    # floats in 6 significant digits: 100.0 s of 0.1 s steps, not 100.00000000000001
    duration = [x for x in page.splitlines() if x.startswith("| duration_s |")]
    assert duration == [f"| duration_s | {result.time[-1]:.6g} |"] and repr(result.time[-1]) not in page


# ------------------------------------------------------------------------------ the native FMU

def test_a_native_fmu_runs_covariance_comes_from_its_outputs(built_fmus):
    """The diagonal is the FMU's stds squared, bit for bit; the off-diagonal its est.cov_*
    outputs where it has them (``full``), zeros where it does not (an FMU built before them)."""
    from harness.run.runner import FmuRunner
    native = built_fmus["RailCar"].parent / "native" / "RailCarNative.fmu"
    assert native.is_file()
    scenario = load_scenario(DEFAULT)
    with FmuRunner(native) as runner:
        result = runner.run(scenario)
    cov, full = resistance_covariance(result)
    assert np.sqrt(np.diag(cov)).tobytes() == np.array([result[f"est.{a}_std"][-1] for a in UNITS]).tobytes()
    assert full == all(name in result.signals for name in COV.values())
    for (i, j), name in COV.items():
        assert cov[i, j] == (result[name][-1] if full else 0.0)


# ---------------------------------------------------------------------------------------- CLI

def test_every_command_line_option_has_a_help_text(monkeypatch):
    """Every subcommand, positional and option of ``python -m harness`` explains itself in --help."""
    from harness import __main__ as cli

    class Parsed(Exception):
        pass

    def capture(self, args=None, namespace=None):
        raise Parsed(self)

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", capture)
    with pytest.raises(Parsed) as caught:
        cli.main(["list"])
    parser = caught.value.args[0]
    [sub] = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    commands = {c.dest: c.help for c in sub._choices_actions}
    assert set(commands) == set(sub.choices) and all(commands.values()), commands
    assert {"run", "list", "sweep", "plan"} <= set(commands)
    missing = [f"{name} {a.option_strings or a.dest}" for name, p in sub.choices.items()
               for a in p._actions if not isinstance(a, argparse._HelpAction) and not a.help]
    assert missing == []
