"""Sweep throughput on 1 and 2 dask worker processes, and the per-run instance overhead.

    python benchmarks/sweep_benchmark.py [--runs 40] [--dist DIR]

Prints (does not assert) against the targets:
- runs per second of a seed sweep of level_run cut to 1500 steps (150 s at 0.1 s), on a
  LocalCluster of 1 and of 2 single-threaded worker processes, each warmed up first (FMU
  extracted, one run done), so that cluster start-up is not counted; target: 2 workers >= 1.8x 1;
- the instance life-cycle cost per run as a share of the run's time, for the sweep's reuse path
  (fmi2Reset + setupExperiment + initialisation + terminate) and for a fresh instance per run
  (instantiate + ... + freeInstance); target <= 10 %.
Not run by the test suite.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (before any FMU is loaded in this process)

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from harness.fmus import DIST, ensure_built, fmu_guid  # noqa: E402
from harness.metrics import summarise  # noqa: E402
from harness.runner import FmuRunner  # noqa: E402
from harness.sweep import ReusableRunner, execute_run, load_sweep, run_sweep  # noqa: E402

STEPS = 1500


def sweep_file(folder: Path, runs: int, first_seed: int = 1) -> Path:
    p = folder / f"bench_{first_seed}.toml"
    seeds = list(range(first_seed, first_seed + runs))
    p.write_text(f'name = "bench"\nscenario = "{(ROOT / "scenarios/library/level_run.toml").as_posix()}"\n'
                 f'seeds = {seeds}\n[fixed]\nduration_s = {STEPS * 0.1}\nstop_after_last_phase = false\n',
                 encoding="utf-8")
    return p


class ForeignLoad:
    """CPU time used by processes outside this benchmark's tree while a measurement runs.

    Another job on the same machine (a test suite, a build) slows the 2-worker case most; the
    benchmark prints this share so that a low speed-up can be read for what it is.
    """

    def __enter__(self):
        import psutil
        self.psutil = psutil
        self.t0, self.busy0, self.own0 = time.monotonic(), self._busy(), self._own()
        return self

    def _busy(self) -> float:
        t = self.psutil.cpu_times()
        return sum(t) - t.idle - getattr(t, "iowait", 0.0)

    def _own(self) -> float:
        me = self.psutil.Process()
        total = sum(me.cpu_times()[:4])                       # incl. children that have ended
        for c in me.children(recursive=True):
            try:
                total += sum(c.cpu_times()[:2])
            except self.psutil.Error:
                pass
        return total

    def stop(self) -> None:                                    # call while the workers still live
        self.share = max(0.0, (self._busy() - self.busy0) - (self._own() - self.own0)) / (
            (time.monotonic() - self.t0) * (self.psutil.cpu_count() or 1))

    def __exit__(self, *exc):
        return False


def throughput(n_workers: int, fmu: Path, runs: int, folder: Path) -> tuple[float, float, float]:
    """(runs per second, mean worker-side seconds per run, CPU share taken by other processes)
    on a warmed-up LocalCluster."""
    import logging
    from distributed import Client, LocalCluster
    warm = load_sweep(sweep_file(folder, n_workers, first_seed=10_000))
    sweep = load_sweep(sweep_file(folder, runs))
    with LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True, dashboard_address=None,
                      host="127.0.0.1", silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.wait_for_workers(n_workers)
        guid = fmu_guid(fmu)
        futures = [client.submit(execute_run, str(fmu), guid, spec, workers=[w], pure=False)
                   for spec, w in zip(warm.runs, client.scheduler_info()["workers"])]
        client.gather(futures)                                    # every worker: FMU loaded, one run done
        with ForeignLoad() as load:
            o = run_sweep(sweep, folder / f"out_{n_workers}_{time.monotonic_ns()}", fmu, client=client,
                          plots=False, progress=False)
            load.stop()
    assert all(r["status"] == "ok" for r in o.table.rows), [r["error"] for r in o.table.rows if r["error"]]
    return runs / o.wall_s, statistics.mean(r["wall_time"] for r in o.table.rows), load.share


def overhead(fmu: Path, repeats: int) -> dict:
    """Seconds per run: the 1500-step run, its metrics, and the instance life-cycle calls."""
    sweep = load_sweep(sweep_file(Path(tempfile.mkdtemp()), 1))
    sc = sweep.runs[0].scenario
    reuse, fresh = ReusableRunner(fmu), FmuRunner(fmu)
    t = {"run": [], "metrics": [], "reuse": [], "fresh": []}
    try:
        reuse.run(sc)                                               # warm-up (imports, profiles)
        for _ in range(repeats):
            t0 = time.perf_counter()
            res = reuse.run(sc)
            t1 = time.perf_counter()
            summarise(res)
            t2 = time.perf_counter()
            assert len(res.time) == STEPS + 1
            t["run"].append(t1 - t0)
            t["metrics"].append(t2 - t1)
            t0 = time.perf_counter()                               # reset + setup + init + terminate
            lease = reuse.start(sc.parameters, sc.duration_s, [], "bench")
            lease.terminate()
            t1 = time.perf_counter()
            lease.freeInstance()                                   # (hands the instance back: no call)
            t["reuse"].append(t1 - t0)
            t0 = time.perf_counter()                               # instantiate + ... + freeInstance
            inst = fresh.start(sc.parameters, sc.duration_s, [], "bench")
            inst.terminate()
            inst.freeInstance()
            t["fresh"].append(time.perf_counter() - t0)
    finally:
        reuse.close()
        fresh.close()
    return {k: statistics.median(v) for k, v in t.items()}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=40, help="runs per throughput measurement (default 40)")
    ap.add_argument("--repeats", type=int, default=10, help="repeats of the overhead measurement (default 10)")
    ap.add_argument("--trials", type=int, default=2, help="throughput trials per worker count; the best counts")
    ap.add_argument("--dist", help="folder of the FMUs (default: dist/, built if stale)")
    args = ap.parse_args(argv)
    fmu = ensure_built(Path(args.dist) if args.dist else DIST)["RailCar"]
    trials = {1: [], 2: []}
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.trials):
            for n in (1, 2):
                trials[n].append(throughput(n, fmu, args.runs, Path(tmp)))
    o = overhead(fmu, args.repeats)
    print(f"sweep throughput, {args.runs} runs of {STEPS} steps (level_run, run + metrics per task), "
          f"best of {args.trials} trials:")
    for n in (1, 2):
        for r, w, load in trials[n]:
            print(f"  {n} worker{'s' if n > 1 else ' '}: {r:6.2f} runs/s  (worker time per run {w:.3f} s; "
                  f"other processes took {100 * load:4.1f} % of the CPUs meanwhile)")
    (r1, w1, _), (r2, w2, _) = (max(trials[n]) for n in (1, 2))
    print(f"  speed-up 2 vs 1 worker: {r2 / r1:.2f}x   (target >= 1.8x)")
    print(f"  dask + result writing per run on 1 worker: {1 / r1 - w1:+.4f} s "
          f"({100 * (1 / r1 - w1) * r1:.1f} % of the wall time per run)")
    run = o["run"]
    print(f"per-run overhead ({STEPS}-step run: {run:.3f} s, its metrics {o['metrics']:.3f} s; medians of {args.repeats}):")
    print(f"  reuse (reset + setup + init + terminate): {1000 * o['reuse']:7.2f} ms = "
          f"{100 * o['reuse'] / run:5.2f} % of the run   (target <= 10 %)")
    print(f"  fresh (instantiate + setup + init + terminate + free): {1000 * o['fresh']:7.2f} ms = "
          f"{100 * o['fresh'] / run:5.2f} % of the run")
    print(f"  reuse vs fresh instance per run: {o['fresh'] / o['reuse']:.1f}x cheaper")
    return 0


if __name__ == "__main__":
    sys.exit(main())
