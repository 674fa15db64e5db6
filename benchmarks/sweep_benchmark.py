"""Sweep throughput on 1 and 2 dask worker processes, per-run overhead, and what the native FMU gains.

    python benchmarks/sweep_benchmark.py [--runs 40] [--mc 1000] [--engines 200] [--dist DIR]
        [--thousand 1000] [--fmu-runs 200] [--hundredk 100000]
        [--part workers|kinds|mc|engines|thousand|ratio|hundredk ...]

Prints (does not assert) against the targets:
- ``workers``: runs per second of a seed sweep of level_run cut to 1500 steps (150 s at 0.1 s),
  with the pythonfmu FMU on a LocalCluster of 1 and of 2 single-threaded worker processes, each
  warmed up first (FMU extracted, one run done), so that cluster start-up is not counted; target:
  2 workers >= 1.8x 1; and the instance life-cycle cost per run as a share of the run's time, for
  the sweep's reuse path (fmi2Reset + setupExperiment + initialisation + terminate) and for a fresh
  instance per run (instantiate + ... + freeInstance); target <= 10 %;
- ``kinds``: the same 1500-step sweep on 2 workers with the pythonfmu RailCar.fmu and the native
  RailCarNative.fmu (``--fmu python`` / ``native``), runs per second of each and the ratio, plus
  where a run's time goes (the FMU run vs the metrics computed on it, which are Python either way);
- ``mc``: a Monte Carlo of the library scenario station_day (900 s, 9000 steps), seeds 0..N-1
  (``--mc``, default 1000), on 2 warmed-up worker processes with each FMU kind: the sweep's wall
  time with each, the ratio, and whether the two tables are the same bit for bit;
- ``engines``: N station_day runs (``--engines``, default 200) on 2 warmed-up worker processes with
  ``--engine fmu`` (the native FMU, a run a task) and ``--engine batch`` (the C batch engine, chunks
  of runs a task): wall times, the ratio, whether the tables are the same bit for bit (but for
  wall_time, engine and fmu), and one run's split between the engine and the metrics, so that the
  gap to the target (1,000 runs in <= 5 s on 2 workers) shows where it is;
- ``thousand`` (the issue's first target): 1,000 station_day runs (``--thousand``) on 2 warmed-up
  local workers with the batch engine, metrics included: wall time (target <= 5 s); the FMU path
  (native FMU) on the first ``--fmu-runs`` of them (default 200), its wall time scaled to the whole
  sweep (said so), and those rows compared bit for bit;
- ``ratio``: the batch engine's time per step (station_day, run_batch of CALL_RUNS runs, no metrics)
  vs the model's time per step in a C host (benchmarks/native_benchmark.py's host and its (a1)
  profile, runs and stops every 180 s; its (a), the car standing after 150 s, printed too); target
  <= 3x;
- ``hundredk``: scenarios/sweeps/mc_short_run.toml (100,000 runs of 300 steps; ``--hundredk`` cuts
  it) on a local cluster of 2 workers: the first 10 % (``--limit``), then the rest (``--resume``),
  the RSS of the main process and of the workers (now and at most, sampled every 0.5 s) printed
  after each, and the run ids of results.csv counted (none lost, none doubled); then the same sweep
  through an external ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1 started
  here, the same counts.
Every measurement also prints the CPU share other processes took meanwhile. Not run by the test
suite.
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
sys.path.insert(0, str(ROOT / "benchmarks"))        # native_benchmark (the ratio part's C host)

from harness.run.fmus import DIST, ensure_built, fmu_guid, native_path  # noqa: E402
from harness.metrics.estimation import summarise  # noqa: E402
from harness.run.runner import FmuRunner  # noqa: E402
from harness.sweep.main import run_sweep  # noqa: E402
from harness.sweep.execute import (CALL_RUNS, CLUSTER_CONFIG, ReusableRunner, execute_chunk,  # noqa: E402
                                   execute_run)
from harness.sweep.spec import load_sweep  # noqa: E402

STEPS = 1500


def sweep_file(folder: Path, runs: int, first_seed: int = 1, scenario: str = "level_run",
               duration_s: float | None = STEPS * 0.1) -> Path:
    """A seed sweep of a library scenario (cut to ``duration_s`` and run to it, unless None)."""
    p = folder / f"bench_{scenario}_{first_seed}_{runs}.toml"
    seeds = list(range(first_seed, first_seed + runs))
    fixed = f"[fixed]\nduration_s = {duration_s}\nstop_after_last_phase = false\n" if duration_s else ""
    p.write_text(f'name = "bench"\nscenario = "{(ROOT / "scenarios/library" / scenario).as_posix()}.toml"\n'
                 f'seeds = {seeds}\n{fixed}', encoding="utf-8")
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
        self.main0 = sum(self.psutil.Process().cpu_times()[:2])
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
        self.own = self._own() - self.own0                     # [s] CPU of this process and its workers
        self.main = sum(self.psutil.Process().cpu_times()[:2]) - self.main0      # [s] of this process
        self.share = max(0.0, (self._busy() - self.busy0) - self.own) / (
            (time.monotonic() - self.t0) * (self.psutil.cpu_count() or 1))

    def __exit__(self, *exc):
        return False


def throughput(n_workers: int, fmu: Path, runs: int, folder: Path, sweep=None) -> tuple[float, float, float]:
    """(runs per second, mean worker-side seconds per run, CPU share taken by other processes)
    on a warmed-up LocalCluster; ``sweep`` (default: ``runs`` seeds of the 1500-step level run)."""
    o, share = timed_sweep(n_workers, fmu, sweep or load_sweep(sweep_file(folder, runs)), folder)
    return len(o.table.rows) / o.wall_s, statistics.mean(r["wall_time"] for r in o.table.rows), share


def timed_sweep(n_workers: int, fmu: Path | None, sweep, folder: Path, cpu: dict | None = None):
    """(SweepOutcome, CPU share of other processes) of ``sweep`` on a LocalCluster of
    ``n_workers``, each warmed up first with one run of the sweep's scenario (FMU extracted and
    loaded, or the batch engine imported): o.wall_s is the sweep's own wall time, without the
    cluster's start-up. ``fmu`` None: the batch engine (--engine batch). ``cpu``, if given, gets
    "own": the CPU seconds this process and the workers used during the sweep (the wall time an
    idle host of that many cores could reach, times the cores)."""
    import dataclasses
    import logging
    import dask
    from distributed import Client, LocalCluster
    first = sweep.runs[0]
    warm = [dataclasses.replace(first, run_id=-1 - k) for k in range(n_workers)]
    with dask.config.set(CLUSTER_CONFIG), LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                                                      dashboard_address=None, host="127.0.0.1",
                                                      silence_logs=logging.ERROR) as cluster, Client(cluster) as client:
        client.wait_for_workers(n_workers)
        workers = client.scheduler_info()["workers"]
        if fmu is None:
            futures = [client.submit(execute_chunk, [spec], workers=[w], pure=False) for spec, w in zip(warm, workers)]
        else:
            guid = fmu_guid(fmu)
            futures = [client.submit(execute_run, str(fmu), guid, spec, workers=[w], pure=False)
                       for spec, w in zip(warm, workers)]
        client.gather(futures)                                    # every worker: FMU loaded, one run done
        with ForeignLoad() as load:
            o = run_sweep(sweep, folder / f"out_{n_workers}_{time.monotonic_ns()}", fmu, client=client,
                          plots=False, progress=False, log=lambda *a: None)
            load.stop()
    if cpu is not None:
        cpu["own"], cpu["main"] = load.own, load.main
    assert all(r["status"] == "ok" for r in o.table.rows), [r["error"] for r in o.table.rows if r["error"]]
    return o, load.share


def overhead(fmu: Path, repeats: int) -> dict:
    """Seconds per run (medians): the 1500-step run, its metrics, and the instance life-cycle calls."""
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


def part_workers(fmu: Path, args, tmp: Path) -> None:
    trials = {1: [], 2: []}
    for _ in range(args.trials):
        for n in (1, 2):
            trials[n].append(throughput(n, fmu, args.runs, tmp))
    o = overhead(fmu, args.repeats)
    print(f"sweep throughput, {args.runs} runs of {STEPS} steps (level_run, run + metrics per task, pythonfmu "
          f"RailCar.fmu), best of {args.trials} trials:")
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


def part_kinds(fmus: dict, args, tmp: Path) -> None:
    """(a) the 1500-step sweep on 2 workers with each FMU kind, alternating, best of --trials."""
    trials = {k: [] for k in fmus}
    for _ in range(args.trials):
        for kind, fmu in fmus.items():
            trials[kind].append(throughput(2, fmu, args.runs, tmp))
    split = {kind: overhead(fmu, args.repeats) for kind, fmu in fmus.items()}
    print(f"FMU kind: {args.runs} runs of {STEPS} steps (level_run, run + metrics per task) on 2 workers, "
          f"best of {args.trials} trials:")
    for kind in fmus:
        for r, w, load in trials[kind]:
            print(f"  {kind:6s}: {r:6.2f} runs/s  (worker time per run {w:.3f} s; other processes took "
                  f"{100 * load:4.1f} % of the CPUs meanwhile)")
    best = {k: max(v) for k, v in trials.items()}
    print(f"  native vs python: {best['native'][0] / best['python'][0]:.2f}x the runs per second")
    for kind, o in split.items():
        print(f"  one run on one process, {kind:6s}: FMU run {o['run']:.3f} s + metrics {o['metrics']:.3f} s "
              f"(medians of {args.repeats})")
    py, na = split["python"], split["native"]
    print(f"  the FMU run alone: native {py['run'] / na['run']:.2f}x faster; the metrics (Python, the same for "
          f"both) are {100 * na['metrics'] / (na['run'] + na['metrics']):.0f} % of a native run's task")


def part_mc(fmus: dict, args, tmp: Path) -> None:
    """(b) the station_day Monte Carlo, seeds 0..N-1, on 2 workers with each kind."""
    sweep = load_sweep(sweep_file(tmp, args.mc, first_seed=0, scenario="station_day", duration_s=None))
    out = {}
    for kind, fmu in fmus.items():
        print(f"  Monte Carlo with the {kind} FMU ({fmu}) ...", flush=True)
        out[kind] = timed_sweep(2, fmu, sweep, tmp)
    print(f"Monte Carlo: station_day (900 s, 9000 steps), {args.mc} runs (seeds 0..{args.mc - 1}) on 2 local "
          f"dask worker processes (warmed up), run + metrics per task:")
    for kind, (o, load) in out.items():
        print(f"  {kind:6s}: {o.wall_s:8.1f} s wall  ({len(o.table.rows) / o.wall_s:.2f} runs/s; other processes "
              f"took {100 * load:4.1f} % of the CPUs meanwhile)")
    ratio = out["python"][0].wall_s / out["native"][0].wall_s
    print(f"  python / native wall time: {ratio:.2f}x")
    keep = ("wall_time", "fmu")
    same = out["python"][0].table.comparable(keep) == out["native"][0].table.comparable(keep)
    print(f"  the two results tables, every cell but wall_time and fmu: "
          f"{'identical bit for bit' if same else 'DIFFERENT'}")


def engine_split(sweep, repeats: int) -> dict:
    """Seconds per station_day run in this process (medians of ``repeats``): the batch engine
    (run_batch, CALL_RUNS runs a call, as execute_chunk calls it) and the row's metrics
    (harness.sweep.execute.add_metrics: summary, oracle filter, coast re-runs, calibration)."""
    from harness.run.batch import ENGINES, run_batch
    from harness.sweep.execute import add_metrics
    scenarios = [spec.scenario for spec in sweep.runs[:CALL_RUNS]]
    run_batch(scenarios[:1])                                       # warm-up (imports, profiles)
    engine, metrics = [], []
    c0 = ENGINES["c"]
    for _ in range(repeats):
        t0 = time.perf_counter()
        results = run_batch(scenarios)
        engine.append((time.perf_counter() - t0) / len(scenarios))
        t0 = time.perf_counter()
        rows = [add_metrics({}, r) for r in results]
        metrics.append((time.perf_counter() - t0) / len(scenarios))
        assert all(r["status"] == "ok" for r in rows), [r["error"] for r in rows]
    assert ENGINES["c"] - c0 == repeats * len(scenarios), "the runs did not go to the C batch engine"
    return {"engine": statistics.median(engine), "metrics": statistics.median(metrics),
            "steps": len(results[0].time) - 1}


def part_engines(fmus: dict, args, tmp: Path) -> None:
    """(c) N station_day runs (seeds 0..N-1) on 2 warmed-up workers: --engine batch vs --engine fmu
    with the native FMU, the ratio, the two tables compared, and a run's split engine / metrics."""
    sweep = load_sweep(sweep_file(tmp, args.engines, first_seed=0, scenario="station_day", duration_s=None))
    out = {}
    for engine, fmu in (("fmu", fmus["native"]), ("batch", None)):
        print(f"  station_day on --engine {engine} ...", flush=True)
        out[engine] = timed_sweep(2, fmu, sweep, tmp)
    split = engine_split(sweep, args.repeats)
    print(f"engines: station_day (900 s, {split['steps']} steps), {args.engines} runs (seeds 0..{args.engines - 1}) "
          f"on 2 local dask worker processes (warmed up), run + metrics per run:")
    for engine, (o, load) in out.items():
        print(f"  --engine {engine:5s}: {o.wall_s:8.2f} s wall  ({len(o.table.rows) / o.wall_s:7.2f} runs/s; other "
              f"processes took {100 * load:4.1f} % of the CPUs meanwhile)")
    print(f"  fmu (native) / batch wall time: {out['fmu'][0].wall_s / out['batch'][0].wall_s:.2f}x")
    keep = ("wall_time", "engine", "fmu")
    same = out["fmu"][0].table.comparable(keep) == out["batch"][0].table.comparable(keep)
    print(f"  the two results tables, every cell but wall_time, engine and fmu: "
          f"{'identical bit for bit' if same else 'DIFFERENT'}")
    e, m = split["engine"], split["metrics"]
    print(f"  one run on one process (medians of {args.repeats}, {CALL_RUNS} run(s) a call): batch engine {1000 * e:.1f} ms "
          f"({1e9 * e / split['steps']:.0f} ns/step) + metrics {1000 * m:.1f} ms = {1000 * (e + m):.1f} ms; "
          f"metrics {100 * m / (e + m):.0f} % of it")
    per_1000 = 1000 * (e + m) / 2
    print(f"  1000 runs on 2 workers at that rate: {per_1000:.1f} s of compute (target <= 5 s wall: "
          f"{'met' if per_1000 <= 5.0 else f'the engine alone {1000 * e / 2:.1f} s, the metrics {1000 * m / 2:.1f} s'})")


def part_thousand(fmus: dict, args, tmp: Path) -> None:
    """The issue's target: 1,000 station_day runs on 2 local workers, metrics included, <= 5 s."""
    sweep = load_sweep(sweep_file(tmp, args.thousand, first_seed=0, scenario="station_day", duration_s=None))
    print(f"  {args.thousand} station_day runs on --engine batch ...", flush=True)
    cpu: dict = {}
    batch, load_b = timed_sweep(2, None, sweep, tmp, cpu)
    n = min(args.fmu_runs, args.thousand)
    part = load_sweep(sweep_file(tmp, n, first_seed=0, scenario="station_day", duration_s=None))
    print(f"  the first {n} of them on --engine fmu (native FMU) ...", flush=True)
    fmu, load_f = timed_sweep(2, fmus["native"], part, tmp)
    print(f"thousand: station_day (up to 900 s at 0.1 s), seeds 0..{args.thousand - 1} on 2 local dask worker "
          f"processes (warmed up), run + metrics per run:")
    print(f"  --engine batch: {batch.wall_s:7.2f} s wall for {args.thousand} runs ({args.thousand / batch.wall_s:.0f} "
          f"runs/s; other processes took {100 * load_b:4.1f} % of the CPUs) -- target <= 5 s: "
          f"{'met' if batch.wall_s <= 5.0 and args.thousand >= 1000 else 'MISSED' if args.thousand >= 1000 else 'n/a'}")
    print(f"  --engine batch CPU: {cpu['own']:.2f} s of this process and the 2 workers together "
          f"({1000 * cpu['own'] / args.thousand:.2f} ms a run; / 2 cores: {cpu['own'] / 2:.2f} s, the wall time's "
          f"floor on an idle host), of it this process (the sweep, the scheduler, the rows written) {cpu['main']:.2f} s")
    scaled = fmu.wall_s * args.thousand / n
    print(f"  --engine fmu  : {fmu.wall_s:7.2f} s wall for {n} runs (other processes took {100 * load_f:4.1f} %); "
          f"scaled to {args.thousand} runs: {scaled:.1f} s ({'measured' if n == args.thousand else 'scaled linearly'})")
    print(f"  fmu / batch wall time: {scaled / batch.wall_s:.1f}x")
    keep = ("wall_time", "engine", "fmu")
    same = batch.table.comparable(keep)[:n] == fmu.table.comparable(keep)
    print(f"  the first {n} rows of the two tables, every cell but wall_time, engine and fmu: "
          f"{'identical bit for bit' if same else 'DIFFERENT'}")


def part_ratio(fmus: dict, args, tmp: Path) -> None:
    """The batch engine's time per step vs the model's in a C host (target <= 3x)."""
    import native_benchmark as nb
    from fmu_src.build.native import build_native_fmu
    sweep = load_sweep(sweep_file(tmp, CALL_RUNS, first_seed=0, scenario="station_day", duration_s=None))
    split = engine_split(sweep, args.repeats)
    engine_ns = 1e9 * split["engine"] / split["steps"]
    native_fmu = build_native_fmu(tmp, fmus["python"])
    exe = nb.build_host(tmp)
    cycle = nb.host_rate(exe, native_fmu, 200_000, 5, cycle_s=nb.CYCLE_S)
    once = nb.host_rate(exe, native_fmu, 200_000, 5)
    print(f"ratio: the batch engine's time per step (station_day, {CALL_RUNS} run(s) a call, driver + wind + chain, "
          f"no metrics; median of {args.repeats}) vs the model in a C host (native_benchmark.py's host, best of 5, "
          f"FMI calls and every output read included):")
    print(f"  batch engine               {engine_ns:8.0f} ns/step")
    print(f"  C host, (a1) runs and stops every {nb.CYCLE_S:g} s {1e9 / cycle:8.0f} ns/step   engine / host: "
          f"{engine_ns * cycle / 1e9:.2f}x (target <= 3x: {'met' if engine_ns * cycle / 1e9 <= 3.0 else 'MISSED'})")
    print(f"  C host, (a) stands after 150 s   {1e9 / once:8.0f} ns/step   engine / host: {engine_ns * once / 1e9:.2f}x")


class MemorySampler:
    """RSS of this process and of its child processes (the local cluster's workers; its scheduler
    is in this process), or of given processes (an external cluster's scheduler and workers), now and
    at most, sampled every ``period_s`` in a thread."""

    def __init__(self, processes=None, period_s: float = 0.5):
        import psutil
        import threading
        self.psutil, self.given, self.period_s = psutil, processes, period_s
        self.peak_main = self.peak_workers = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True)

    def now(self) -> tuple[int, list[int]]:
        """(RSS of this process, RSS of each worker process) [bytes]."""
        me = self.psutil.Process()
        others = self.given if self.given is not None else me.children(recursive=True)
        rss = []
        for p in others:
            try:
                rss.append(p.memory_info().rss)
            except self.psutil.Error:
                pass
        return me.memory_info().rss, rss

    def _loop(self) -> None:
        while not self._stop.wait(self.period_s):
            main, workers = self.now()
            self.peak_main = max(self.peak_main, main)
            self.peak_workers = max([self.peak_workers] + workers)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        return False

    def line(self, what: str) -> str:
        main, workers = self.now()
        mb = 1e-6
        return (f"  {what}: main {main * mb:6.0f} MB (at most {self.peak_main * mb:6.0f}), the two largest "
                f"cluster processes "
                f"{', '.join(f'{w * mb:.0f}' for w in sorted(workers)[-2:])} MB (at most {self.peak_workers * mb:.0f})")


def count_ids(csv_path: Path) -> tuple[int, int]:
    """(rows, distinct run ids) of a results.csv, reading only its first column."""
    ids, rows = set(), 0
    with open(csv_path, encoding="utf-8") as f:
        next(f)
        for line in f:
            rows += 1
            ids.add(int(line.split(",", 1)[0]))
    return rows, len(ids)


def hundredk_legs(sweep, out: Path, first: int, sampler: MemorySampler, **where) -> None:
    """The sweep in two legs (``first`` runs, then --resume), RSS and row counts after each."""
    t0 = time.monotonic()
    o1 = run_sweep(sweep, out, plots=True, progress=False, limit=first, log=lambda *a: None, **where)
    print(f"  after {first:,} runs ({time.monotonic() - t0:.0f} s; {o1.ran:,} rows this call):", flush=True)
    print(sampler.line(f"RSS at {first:,} runs"), flush=True)
    t1 = time.monotonic()
    o2 = run_sweep(sweep, out, plots=True, progress=False, resume=True, log=lambda *a: None, **where)
    n = len(sweep.runs)
    rows, ids = count_ids(out / "results.csv")
    print(f"  after {n:,} runs ({time.monotonic() - t1:.0f} s more, {o2.wall_s:.0f} s of it the sweep; "
          f"{o2.resumed:,} kept + {o2.ran:,} ran; summary: {o2.stats.ok:,} ok, {o2.stats.failed} failed):", flush=True)
    print(sampler.line(f"RSS at {n:,} runs"), flush=True)
    print(f"  results.csv: {rows:,} rows, {ids:,} distinct run ids of {n:,}: "
          f"{'none lost, none doubled' if rows == ids == n else 'ROWS LOST OR DOUBLED'}", flush=True)


def part_hundredk(args, tmp: Path) -> None:
    """100,000 short runs on a local cluster, then through an external scheduler: RSS and row counts."""
    import logging
    import resource
    import subprocess
    import dataclasses
    from distributed import Client, LocalCluster
    import psutil
    rss0 = psutil.Process().memory_info().rss
    t0 = time.monotonic()
    sweep = load_sweep(ROOT / "scenarios" / "sweeps" / "mc_short_run.toml")
    load_s, rss1 = time.monotonic() - t0, psutil.Process().memory_info().rss
    total = len(sweep.runs)
    if args.hundredk < len(sweep.runs):
        sweep = dataclasses.replace(sweep, runs=sweep.runs[:args.hundredk])
    n = len(sweep.runs)
    first = max(1, n // 10)
    print(f"hundredk: {sweep.name}, {n:,} runs of 300 steps{f' (cut from {total:,})' if n < total else ''}; the "
          f"sweep file ({total:,} runs) loaded in {load_s:.1f} s, main RSS {rss0 * 1e-6:.0f} -> {rss1 * 1e-6:.0f} MB "
          f"(the runs are built a chunk at a time as the sweep runs, none at load)", flush=True)
    print(" local cluster of 2 worker processes:", flush=True)
    import dask
    with dask.config.set(CLUSTER_CONFIG), LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                                      dashboard_address=None, host="127.0.0.1",
                                                      silence_logs=logging.ERROR) as cluster, \
            Client(cluster) as client, MemorySampler() as sampler:
        hundredk_legs(sweep, tmp / "hundredk_local", first, sampler, client=client)
    print(" external scheduler (python -m dask scheduler + 2 x dask worker --nthreads 1 on 127.0.0.1):", flush=True)
    sched_file = tmp / "scheduler.json"
    procs = []
    env = dict(__import__("os").environ, PYTHONPATH=str(ROOT))
    try:
        procs.append(subprocess.Popen([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1", "--port", "0",
                                       "--no-dashboard", "--scheduler-file", str(sched_file)], cwd=ROOT, env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        deadline = time.monotonic() + 60
        while not sched_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.1)
        time.sleep(0.3)
        import json
        address = json.loads(sched_file.read_text())["address"]
        for _ in range(2):
            procs.append(subprocess.Popen([sys.executable, "-m", "dask", "worker", address, "--nthreads", "1",
                                           "--nworkers", "1", "--no-dashboard", "--host", "127.0.0.1"], cwd=ROOT,
                                          env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        with Client(address, timeout="30s") as c:
            c.wait_for_workers(2, timeout=60)
        watched = [psutil.Process(p.pid) for p in procs]          # the scheduler and the worker trees
        watched += [c for p in watched[1:] for c in p.children(recursive=True)]
        with MemorySampler(watched) as sampler:
            hundredk_legs(sweep, tmp / "hundredk_external", first, sampler, scheduler=address)
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
    print(f"  main process peak RSS over the part (getrusage): {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3:.0f} MB")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=40, help="runs per throughput measurement (default 40)")
    ap.add_argument("--repeats", type=int, default=10, help="repeats of the overhead measurement (default 10)")
    ap.add_argument("--trials", type=int, default=2, help="throughput trials per worker count or kind; the best counts")
    ap.add_argument("--mc", type=int, default=1000, help="runs of the station_day Monte Carlo per kind (default 1000)")
    ap.add_argument("--engines", type=int, default=200, help="station_day runs per engine of the engines "
                    "part (default 200)")
    ap.add_argument("--thousand", type=int, default=1000, help="station_day runs of the thousand part (default 1000)")
    ap.add_argument("--fmu-runs", type=int, default=200, help="of them on the FMU path, scaled (default 200)")
    ap.add_argument("--hundredk", type=int, default=100_000, help="runs of mc_short_run.toml (default 100000)")
    ap.add_argument("--part", action="append",
                    choices=("workers", "kinds", "mc", "engines", "thousand", "ratio", "hundredk"),
                    help="measure only this (repeatable; default: all)")
    ap.add_argument("--dist", help="folder of the FMUs (default: dist/, built if stale)")
    args = ap.parse_args(argv)
    dist = Path(args.dist) if args.dist else DIST
    fmu = ensure_built(dist)["RailCar"]
    fmus = {"python": fmu, "native": native_path("RailCar", dist)}
    parts = args.part or ["workers", "kinds", "mc", "engines", "thousand", "ratio", "hundredk"]
    with tempfile.TemporaryDirectory() as tmp:
        if "workers" in parts:
            part_workers(fmu, args, Path(tmp))
        if "kinds" in parts:
            part_kinds(fmus, args, Path(tmp))
        if "mc" in parts and args.mc > 0:
            part_mc(fmus, args, Path(tmp))
        if "engines" in parts and args.engines > 0:
            part_engines(fmus, args, Path(tmp))
        if "thousand" in parts and args.thousand > 0:
            part_thousand(fmus, args, Path(tmp))
        if "ratio" in parts:
            part_ratio(fmus, args, Path(tmp))
        if "hundredk" in parts and args.hundredk > 0:
            part_hundredk(args, Path(tmp))
    return 0


if __name__ == "__main__":
    sys.exit(main())
