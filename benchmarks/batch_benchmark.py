"""Where a station_day run's time goes, and what the C batch engine gains (issue 31's benchmark).

    python benchmarks/batch_benchmark.py [--scenario scenarios/library/station_day.toml]
                                         [--runs 50] [--repeat 5] [--part scripted|spans|all]

Measures in one process, on one core, the least CPU time of --repeat, per run of the scenario (its own seed;
station_day ends at its last phase after 5,192 of its 9,000 steps):
  (a) the C chain alone (models.compiled.CompiledChain.run_steps) stepping the run's recorded
      inputs: the model's floor;
  (b) harness.run.driver.run_on_chain: the Python driver per step around the C chain (before);
  (c) the metrics of the RunResult (harness.metrics.run.run_metrics), and of them the oracle
      filter alone (harness.metrics.estimation.oracle_filter) and the coast-time errors
      (coast_time_errors): in Python (RAILCAR_PURE_PYTHON set: before) and with the oracle and
      the coasts in C (models/core/run_metrics.c through models.batch: after);
  (d) the C batch engine (harness.run.batch.run_batch, models/core/scenario_driver.c): one run,
      and --runs runs (seeds 0..runs-1) in one call, per run; (d raw) the C runs alone
      (harness.run.batch.run_chains: models.batch.run_scripts, no RunResults).
Prints the table, the engine's time per step over the chain's (issue 31's target <= 3x), and the
projection for 1,000 runs on 2 workers (issue 31's target <= 5 s, metrics included) from (c)
and (d) (CPU time per run x runs / workers: 2 free cores assumed), with the metrics in Python and
in C.

``--part spans`` (``all``: both parts) measures the span scenarios ato_nominal and ato_line (the
ATO drives) the same way: (b) run_on_chain with the Python AtoDriver (before), (d) the C batch
engine (models/core/span_driver.c: after), one run a call and --runs a call, and the run's
metrics: the ATO's (harness.metrics.ato.ato_metrics: Python) and all of them
(harness.metrics.run.run_metrics); then the share the metrics take of an engine run + metrics.
Not run by the test suite; the figures are this machine's, noisy when others share it.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.metrics.ato import ato_metrics  # noqa: E402
from harness.metrics.estimation import c_metrics, coast_time_errors, oracle_filter  # noqa: E402
from harness.metrics.run import run_metrics  # noqa: E402
from harness.run.batch import run_batch, run_chains, script_of  # noqa: E402
from harness.run.driver import run_on_chain  # noqa: E402
from harness.run.phases import INPUTS  # noqa: E402
from harness.run.scenario import load_scenario  # noqa: E402
from models import batch  # noqa: E402

TARGET_RUNS, TARGET_WALL_S, TARGET_STEP_RATIO, WORKERS = 1000, 5.0, 3.0, 2


def best(fn, repeat: int) -> float:
    """The least of ``repeat`` CPU times of fn() [s]: this process's CPU time, not the wall's, so
    that other processes on a shared machine count less (a short call's best wall time would
    catch a quiet moment more often than a long one's)."""
    times = []
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        times.append(time.process_time() - t0)
    return min(times)


@contextmanager
def python_metrics():
    """The metrics' Python reference inside (RAILCAR_PURE_PYTHON set), the environment back after."""
    before = os.environ.get("RAILCAR_PURE_PYTHON")
    os.environ["RAILCAR_PURE_PYTHON"] = "1"
    try:
        yield
    finally:
        if before is None:
            del os.environ["RAILCAR_PURE_PYTHON"]
        else:
            os.environ["RAILCAR_PURE_PYTHON"] = before


def recorded_steps(scenario, result) -> np.ndarray:
    """The run's inputs as CompiledChain.run_steps takes them: time, step, then INPUTS."""
    n = len(result.time) - 1
    h = scenario.step_s
    return np.column_stack([np.arange(n) * h, np.full(n, h)] + [result.inputs[k][:n] for k in INPUTS])


SPAN_SCENARIOS = ("ato_nominal", "ato_line")


def spans_part(args) -> None:
    """The span scenarios' table (module docstring, --part spans)."""
    print(f"span scenarios: least CPU time of {args.repeat}, one core, per run\n")
    print(f"{'':12} {'b before':>10} {'d 1 run':>10} {'d many':>10} {'ratio':>7} {'ato_metrics':>12} "
          f"{'run_metrics':>12} {'metrics share':>14}")
    for name in SPAN_SCENARIOS:
        sc = load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml")
        result = run_on_chain(sc)
        [same] = run_batch([sc])
        assert same.driver_steps == result.driver_steps and all(
            same[n].tobytes() == result[n].tobytes() for n in result.signals), f"{name}: batch != run_on_chain"
        seeds = [{"seed": k} for k in range(args.runs)]
        t = {"b": best(lambda: run_on_chain(sc), args.repeat),
             "d": best(lambda: run_batch([sc]), args.repeat),
             "d many": best(lambda: run_batch([sc] * args.runs, seeds), max(1, args.repeat // 2)) / args.runs,
             "ato": best(lambda: ato_metrics(sc, result, result.driver_steps), args.repeat),
             "run": best(lambda: run_metrics(result), args.repeat)}
        share = t["run"] / (t["d many"] + t["run"])
        print(f"{name:12} {1e3 * t['b']:7.2f} ms {1e3 * t['d']:7.2f} ms {1e3 * t['d many']:7.2f} ms "
              f"{t['b'] / t['d many']:6.1f}x {1e3 * t['ato']:9.2f} ms {1e3 * t['run']:9.2f} ms "
              f"{100 * share:12.0f} %   ({len(result.time) - 1} steps)")
    print("\nratio: before / the engine (d many); metrics share: run_metrics / (d many + run_metrics)")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default=str(ROOT / "scenarios" / "library" / "station_day.toml"))
    ap.add_argument("--runs", type=int, default=50, help="runs per batch call in (d) [default 50]")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--part", choices=("scripted", "spans", "all"), default="scripted",
                    help="the scripted scenario (--scenario), the span scenarios, or both")
    args = ap.parse_args(argv)
    if not batch.available():
        print("models._batch is not compiled: python setup.py build_ext --inplace")
        return 2
    if args.part in ("spans", "all"):
        spans_part(args)
        if args.part == "spans":
            return 0
        print()
    sc = load_scenario(args.scenario)
    setup = sc.chain_setup()
    result = run_on_chain(sc)
    steps = len(result.time) - 1
    inputs = recorded_steps(sc, result)
    seeds = [{"seed": k} for k in range(args.runs)]
    many = [sc] * args.runs
    raw_runs = [(setup.config, setup.grade, setup.speed, script_of(sc))] * args.runs

    [same] = run_batch([sc])
    assert all(same[n].tobytes() == result[n].tobytes() for n in result.signals), "batch != run_on_chain"

    if c_metrics() is None:
        print("the C run metrics do not run here (models._batch or models._railcar not compiled, "
              "or RAILCAR_PURE_PYTHON set)")
        return 2

    def identified(last):
        return tuple(float(result[f"est.A{j}"][last]) for j in range(3))

    def metric_times(suffix: str) -> dict:
        return {"c" + suffix: best(lambda: run_metrics(result), args.repeat),
                "c oracle" + suffix: best(lambda: oracle_filter(result, setup), args.repeat),
                "c coasts" + suffix: best(lambda: coast_time_errors(result, identified, setup=setup),
                                          args.repeat)}

    with python_metrics():
        reference = run_metrics(result)
        t = metric_times(" py")
    assert repr(run_metrics(result).summary) == repr(reference.summary), "C metrics != Python metrics"
    t.update(metric_times(""))
    t.update({
        "a": best(lambda: setup.open().run_steps(inputs), args.repeat),
        "b": best(lambda: run_on_chain(sc), args.repeat),
        "d": best(lambda: run_batch([sc]), args.repeat),
        "d many": best(lambda: run_batch(many, seeds), max(1, args.repeat // 2)) / args.runs,
        "d raw": best(lambda: run_chains(raw_runs), max(1, args.repeat // 2)) / args.runs,
    })
    us = 1e6 / steps
    print(f"{sc.name}: {steps} steps a run (step {sc.step_s} s), least CPU time of {args.repeat}, one core\n")
    print(f"{'':12} {'per run':>10} {'per step':>10}  what")
    rows = [("a", "C chain alone, recorded inputs (CompiledChain.run_steps)"),
            ("b", "run_on_chain: Python driver + C chain (before)"),
            ("c py", "metrics of the result (run_metrics) in Python (before)"),
            ("c oracle py", "  of which the oracle filter"),
            ("c coasts py", "  of which the coast-time errors"),
            ("c", "metrics of the result, the oracle and the coasts in C (after)"),
            ("c oracle", "  of which the oracle filter"),
            ("c coasts", "  of which the coast-time errors"),
            ("d", "C batch engine, 1 run a call, RunResult built (after)"),
            ("d many", f"C batch engine, {args.runs} runs a call, per run"),
            ("d raw", f"  the C runs alone ({args.runs} a call, no RunResults), per run")]
    for key, what in rows:
        print(f"{key:12} {1e3 * t[key]:7.2f} ms {us * t[key]:7.3f} us  {what}")
    print(f"\ndriver loop: run_on_chain / C engine (1 run) = {t['b'] / t['d']:.1f}x")
    print(f"engine per step / chain per step = {t['d raw'] / t['a']:.2f}x (issue 31 target <= {TARGET_STEP_RATIO:g}x)")
    print(f"metrics in C / in Python = {t['c'] / t['c py']:.3f} "
          f"(oracle {t['c oracle'] / t['c oracle py']:.4f}, coasts {t['c coasts'] / t['c coasts py']:.3f})")
    for label, run_s in (("before: run_on_chain + metrics in Python", t["b"] + t["c py"]),
                         ("C engine + metrics in Python", t["d many"] + t["c py"]),
                         ("after: C engine + metrics in C", t["d many"] + t["c"]),
                         ("after, runs alone", t["d many"])):
        wall = TARGET_RUNS * run_s / WORKERS
        print(f"{TARGET_RUNS} runs on {WORKERS} workers, {label}: {wall:6.1f} s "
              f"(target <= {TARGET_WALL_S:g} s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
