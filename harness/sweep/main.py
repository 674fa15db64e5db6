"""Batch parameter sweeps of RailCar on dask.distributed worker processes: ``run_sweep`` and the
command ``python -m harness sweep`` (``cli_sweep``; its arguments are in harness/__main__.py).

A sweep file names a base scenario and the values to run it with; each run becomes one row of
``DIR/results.csv`` (and results.parquet), with ``DIR/summary.md`` and plots in ``DIR/plots``.
The parts, one module each:

- harness/sweep/spec.py: the sweep file (grid, zip, Latin hypercube, seeds) -> ``Sweep`` of ``RunSpec``
- harness/sweep/execute.py: the dask cluster, the workers' FMU instances, one run -> one row (--engine
  fmu) or a chunk of runs on the C batch engine -> their rows (--engine batch, the default where it covers)
- harness/sweep/table.py: the columns, a run's result -> row, the summary text (pure computing)
- harness/sweep/results.py: the results folder: CSV/Parquet, sweep.json, lock, --resume/--overwrite
- harness/sweep/plots.py: the plots

The end of a sweep reads results.csv once, a row at a time, in the pass that writes results.parquet
(``StreamedEnd``; ``streamed_end`` without pyarrow): the summary from SweepStats, the plots from a
bounded sample, so that it ends in flat memory at any number of runs.
"""
from __future__ import annotations

import itertools
import os
import sys
import time
from pathlib import Path

from harness.sweep.execute import ENGINES, core_identity, execute_runs
from harness.sweep.plots import PLOT_SAMPLE_ROWS, PlotSample, plot_sweep
from harness.sweep.results import (ResultsWriter, check_rerun, iter_csv_rows, read_meta, read_results,
                                   write_summary)
from harness.sweep.spec import Sweep, load_sweep
from harness.sweep.table import TEXT_STATUS_OK, Column, SweepOutcome, SweepStats, Table, format_sweep_summary
from harness.textio import check_out_dir

# Re-exported: tests/harness_tests/run/test_cli_errors.py and tests/harness_tests/run/test_harness_fmu_kind.py import them
# (read_results too) from here.
__all__ = ["read_results", "run_sweep", "cli_sweep", "streamed_end"]
from harness.sweep.execute import _WORKER_FMUS, execute_run, worker_runner  # noqa: F401
from harness.sweep.spec import RunSpec, SweepError  # noqa: F401


class _Progress:
    """harness.progress.Progress (runs done/failed, ETA) on a terminal; else a line every 10 %
    of the runs (at most one per 5 s, and the last)."""

    def __init__(self, total: int, label: str, enabled: bool | None):
        from harness.progress import Progress
        self.bar = Progress(total, label, enabled)
        self.lines = enabled is None and not self.bar.enabled
        self.next_share, self.last_line = 0.1, 0.0

    def advance(self, what: str, failed: bool) -> None:
        self.bar.advance(what, failed)
        b = self.bar
        if not self.lines or not b.total:
            return
        now = time.monotonic()
        if b.done == b.total or (b.done / b.total >= self.next_share and now - self.last_line >= 5.0):
            self.next_share = b.done / b.total + 0.1
            self.last_line = now
            elapsed = now - b.t0
            eta = elapsed / b.done * (b.total - b.done)
            print(f"  {b.done}/{b.total} runs, {b.failed} failed, {elapsed:.0f} s, ETA {eta:.0f} s", flush=True)


def run_sweep(sweep: Sweep, out_dir: str | Path, fmu_path: str | Path | None = None, scheduler: str | None = None,
              workers: int | None = None, resume: bool = False, limit: int | None = None,
              progress: bool | None = None, plots: bool = True, client=None, log=print,
              overwrite: bool = False, fmu_note: str = "", engine: str | None = None,
              chunk: int | None = None, engine_note: str = "") -> SweepOutcome:
    """Run the sweep's runs (those not in DIR yet with ``resume``; the first ``limit`` of them).
    A DIR that holds results is refused (SweepError) unless ``resume`` or ``overwrite``.

    Runs on ``client`` if given, else on the dask scheduler at ``scheduler``, else on a
    LocalCluster of ``workers`` (default: one per core) single-threaded worker processes whose
    scratch space and FMU extractions are in one temporary folder, removed when the sweep ends.
    ``engine``: "fmu", a run a task through ``fmu_path``, either kind of RailCar FMU
    (harness.run.fmus; ``fmu_note`` says which and why, for the summary, default its kind and
    path); "batch", ``chunk`` runs a task (default execute.chunk_size) on the C batch engine
    (harness.run.batch; ``engine_note`` says why, for the summary). Default: "fmu" when
    ``fmu_path`` is given, else "batch". The rows are the same bit for bit but for ``engine``,
    ``fmu`` and ``wall_time``.
    """
    engine = engine or ("fmu" if fmu_path is not None else "batch")
    if engine not in ("fmu", "batch"):
        raise ValueError(f"engine: expected 'fmu' or 'batch', got {engine!r}")
    if chunk is not None and chunk < 1:
        raise ValueError(f"chunk: expected a number of runs >= 1, got {chunk}")
    out_dir = Path(out_dir)
    guid, kind = None, None
    if engine == "fmu":
        from fmpy import read_model_description
        from harness.run.fmus import fmu_guid, is_native
        if fmu_path is None:
            raise ValueError("engine 'fmu': give fmu_path, the RailCar FMU to run")
        fmu_path = Path(fmu_path).resolve()
        if not fmu_path.is_file():
            raise FileNotFoundError(f"FMU not found: {fmu_path}")
        guid = fmu_guid(fmu_path)
        kind = "native" if is_native(read_model_description(str(fmu_path))) else "python"
        core = None
    else:
        fmu_path = None
        core = core_identity()
    writer = ResultsWriter(out_dir, sweep, guid, resume, overwrite, fmu_kind=kind, engine=engine, core=core)
    # run ids, not runs: a run is built when its chunk is prepared (harness.sweep.execute)
    todo = [i for i in sweep.runs.ids if i not in writer.done] if writer.done else sweep.runs.ids
    if limit is not None:
        todo = todo[:limit]
    t0 = time.monotonic()
    bar = _Progress(len(todo), f"sweep {sweep.name}", progress)

    def record(row: dict) -> bool:
        if not writer.write(row):            # a run id already written (a retried task)
            return False
        bar.advance(f"run {row['run_id']}", failed=row["status"] != TEXT_STATUS_OK)
        return True

    end = StreamedEnd(out_dir, sweep, plots)
    passed = False
    try:
        ran, n_workers = execute_runs(sweep, todo, fmu_path, guid, record, client=client, scheduler=scheduler,
                                      workers=workers, log=log, engine=engine, chunk=chunk)
    finally:
        passed = writer.close(on_row=end.add)       # the Parquet pass over results.csv feeds ``end``
    stats, done, sample = end.result() if passed else streamed_end(out_dir, sweep, plots)
    outcome = SweepOutcome(stats=stats, ran=ran, resumed=writer.resumed,
                           missing=[i for i in sweep.runs.ids if i not in done],
                           wall_s=time.monotonic() - t0, workers=n_workers,
                           fmu=(fmu_note or f"{kind} {fmu_path}") if engine == "fmu" else "",
                           engine=(engine_note or "batch") if engine == "batch" else "",
                           read_table=lambda: read_results(out_dir))
    outcome.files = [out_dir / "results.csv"] + ([writer.parquet_path] if writer.parquet_path.is_file() else [])
    outcome.files.append(write_summary(out_dir, sweep, outcome))
    if plots:
        outcome.files += plot_sweep(sweep, sample, out_dir / "plots", ok_runs=stats.ok)
    return outcome


class StreamedEnd:
    """What the end of a sweep needs from DIR/results.csv, gathered a row at a time (``add``): the
    summary's SweepStats, the run ids there, the plots' sample (at most PLOT_SAMPLE_ROWS rows, by
    run id, of the plots' columns only). Its memory is that of the sample, the ids and the
    summary's 8 bytes per run and metric, whatever the number of runs."""

    def __init__(self, out_dir: Path, sweep: Sweep, plots: bool = True):
        self.cols = [Column(*c) for c in read_meta(out_dir / "sweep.json")["columns"]]
        self.keep = {c.key for c in self.cols if c.kind != "str"} | {"status"} | set(sweep.axes)
        self.plots = plots
        self.stats, self.done, self.sample = SweepStats(), set(), PlotSample(PLOT_SAMPLE_ROWS)

    def add(self, row: dict) -> None:
        self.stats.add(row)
        self.done.add(row["run_id"])
        if self.plots:
            self.sample.offer({k: v for k, v in row.items() if k in self.keep})

    def result(self) -> tuple[SweepStats, set, Table]:
        return self.stats, self.done, Table(self.cols, self.sample.rows())


def streamed_end(out_dir: Path, sweep: Sweep, plots: bool = True) -> tuple[SweepStats, set, Table]:
    """One pass over DIR/results.csv, a row at a time: StreamedEnd's (SweepStats, run ids, plot
    sample); a sweep of at most PLOT_SAMPLE_ROWS runs is plotted whole. run_sweep gathers the same
    in the pass that writes results.parquet (ResultsWriter.close), and calls this without pyarrow."""
    end = StreamedEnd(out_dir, sweep, plots)
    for row in iter_csv_rows(out_dir / "results.csv", end.cols):
        end.add(row)
    return end.result()


def _usage_error(args) -> str | None:
    """What is wrong with the combination of sweep options, None if nothing."""
    if args.scheduler and args.workers:
        return "--workers sets the size of the embedded local cluster; not with --scheduler"
    if args.workers is not None and args.workers < 1:
        return "--workers must be >= 1"
    if args.limit is not None and args.limit < 0:
        return "--limit must be >= 0"
    if args.resume and args.overwrite:
        return "--resume continues the results in --out, --overwrite discards them: give one"
    if getattr(args, "chunk", None) is not None and args.chunk < 1:
        return "--chunk must be >= 1"
    if getattr(args, "chunk", None) is not None and getattr(args, "engine", "auto") == "fmu":
        return "--chunk sets the runs per task of the batch engine; not with --engine fmu (a run a task)"
    if getattr(args, "fmu", None) is not None and getattr(args, "engine", "auto") == "batch":
        return "--fmu picks the FMU of --engine fmu; the batch engine runs no FMU: give one of the two"
    return None


def choose_engine(asked: str, fmu_asked: str | None, sweep: Sweep) -> tuple[str, str]:
    """(engine, why) for ``--engine`` ``asked`` and ``--fmu`` ``fmu_asked`` (None: not given):
    ``auto`` is the batch engine when the C core covers every valid run
    (harness.run.batch.not_covered) and no --fmu was given (any --fmu, ``auto`` too, asks for the
    FMU path), else the FMU path; ``batch`` runs the batch engine even so (its uncovered runs on
    run_on_chain, the Python reference: the engine column says "python")."""
    from harness.run.batch import not_covered
    from models.compiled import COVERAGE_PARAMETERS
    if asked == "fmu":
        return "fmu", "--engine fmu"
    if asked == "auto" and fmu_asked is not None:
        return "fmu", f"--engine auto: --fmu {fmu_asked} asks for an FMU"
    if asked not in ENGINES:
        raise SweepError(f"--engine {asked}: expected one of {', '.join(ENGINES)}")
    # built here only when the answer needs it: one run per point (a seed changes no coverage), or
    # the first valid run alone when no axis sweeps a parameter coverage depends on
    valid = (s for s in sweep.runs.representatives() if s.scenario is not None)
    if not set(sweep.axes) & set(COVERAGE_PARAMETERS):
        valid = itertools.islice(valid, 1)
    uncovered = next(((s.run_id, why) for s in valid for why in [not_covered(s.scenario)] if why), None)
    if asked == "batch":
        return "batch", ("--engine batch: C core" if uncovered is None else
                         f"--engine batch: run {uncovered[0]} and maybe others on the Python reference: {uncovered[1]}")
    if uncovered is not None:
        return "fmu", f"--engine auto: the C batch engine does not cover run {uncovered[0]}: {uncovered[1]}"
    return "batch", "--engine auto: the C core covers every run"


def cli_sweep(args) -> int:
    """``python -m harness sweep``: see harness/__main__.py for the arguments."""
    from harness.run.fmus import select
    problem = _usage_error(args)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 2
    sweep = load_sweep(args.sweep)
    out = Path(args.out) if args.out else Path("out") / "sweeps" / sweep.name
    check_out_dir(out)
    check_rerun(out, sweep.fingerprint, args.resume, args.overwrite)   # before any build
    engine, why = choose_engine(getattr(args, "engine", "auto"), getattr(args, "fmu", None), sweep)
    choice = None
    if engine == "fmu":
        choice = select(getattr(args, "fmu", None) or "auto", "RailCar", args.dist, args.rebuild,
                        [(f"run {r.run_id}", r.scenario.parameters) for r in sweep.runs.representatives()
                         if r.scenario is not None])
    where = args.scheduler or f"a local cluster of {args.workers or os.cpu_count()} worker processes"
    print(f"sweep '{sweep.name}': {len(sweep.runs)} runs of {sweep.base_path} on {where} -> {out}", flush=True)
    print(f"engine: {engine} ({why})", flush=True)
    if choice is not None:
        print(choice.line(), flush=True)
    try:
        o = run_sweep(sweep, out, choice.path if choice else None, scheduler=args.scheduler, workers=args.workers,
                      resume=args.resume, limit=args.limit, plots=not args.no_plots, overwrite=args.overwrite,
                      fmu_note=choice.describe() if choice else "", engine=engine,
                      chunk=getattr(args, "chunk", None), engine_note=f"{engine} ({why})")
    except KeyboardInterrupt:
        print(f"\ninterrupted: the finished runs are in {out / 'results.csv'}; --resume continues", file=sys.stderr)
        return 1
    except (OSError, RuntimeError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    print(format_sweep_summary(sweep, o))
    print(f"results: {', '.join(str(p) for p in o.files if p.suffix != '.png')}"
          + (f"; plots: {out / 'plots'} ({sum(p.suffix == '.png' for p in o.files)} files)" if not args.no_plots else ""))
    failed = o.stats.failed
    if failed:
        print(f"{failed} run(s) failed (status and message in results.csv)", file=sys.stderr)
    return 1 if failed else 0
