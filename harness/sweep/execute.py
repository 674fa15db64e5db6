"""Running a sweep's runs on dask.distributed worker processes: the cluster, the workers' FMU
instances, one run turned into one row (the FMU path) and a chunk of runs turned into rows (the
batch engine).

Two engines (``--engine``), the same rows bit for bit but for the ``engine``, ``fmu`` and
``wall_time`` columns (add_metrics builds the rest for both). The batch engine (execute_chunk):
a dask task runs a chunk of runs (sized by harness/sweep/chunks.py next_chunk, smaller towards the
sweep's end) through harness.run.batch.run_batch -- whole runs in the C core, CALL_RUNS (1) a call -- and
computes their rows; a run that fails becomes its failed row and the chunk's other runs keep
theirs. The FMU path (execute_run), below.

With the FMU path every run is one dask task on a worker *process* (one thread each: FMU calls hold the GIL).
Each worker process extracts the FMU once and keeps one live instance, reset between runs
(``fmi2Reset``; gives the same results bit for bit as a fresh instance, see the tests); after
an initialisation failure (pythonfmu: fmi2Fatal) that instance is leaked, never called again,
and the next run gets a fresh one. The FMU is shipped by *path*: a remote cluster must see the
same path (and the project on its PYTHONPATH). A run whose scenario is invalid or whose FMU
fails becomes a row with status "failed" and the message, and the sweep goes on.

Which FMU: ``--fmu`` (harness.run.fmus.choose). One FMU runs the whole sweep: by default (``auto``)
the native RailCar (the C core, no Python, bit-identical rows) when the C core covers every
valid run's parameters, else the pythonfmu RailCar. The ``fmu`` column (last) of every row that
ran says which kind ran it. A worker that finds a rebuilt native FMU at the same path loads the
new one (no Python modules are cached for it); a rebuilt pythonfmu FMU still needs fresh worker
processes.

The embedded cluster's scratch space and its workers' FMU extractions live in one temporary
folder, removed when the sweep ends, also on an error, Ctrl-C or SIGTERM.
"""
from __future__ import annotations

import pythonfmu  # noqa: F401  (import before any FMU is loaded in this process)

import contextlib
import os
import pickle
import shutil
import signal
import tempfile
import threading
import time
import uuid
import zlib
from collections import Counter
from pathlib import Path
from typing import Callable, Sequence

from harness.run.runner import FmuRunner, RunError
from harness.sweep.chunks import MIN_CHUNK, RunStream, heap_kept, next_chunk  # noqa: F401 (MIN_CHUNK: tests)
from harness.sweep.spec import RunSpec, Sweep
from harness.sweep.table import TEXT_STATUS_FAILED, TEXT_STATUS_OK, calibration, flatten_summary, run_ato_row

_LEAKED: list = []            # instances after fmi2Fatal: FMI allows no further call (pythonfmu segfaults)
_WORKER_FMUS: dict = {}       # per process: FMU path -> ReusableRunner (one extraction, one live instance)
FATAL = 4
ENGINE_FMU, ENGINE_C, ENGINE_PYTHON = "fmu", "c", "python"
"""The ``engine`` column: the FMU (``fmu`` column: which), the C batch engine, or run_on_chain (the
Python reference, for runs the C core does not cover)."""
ENGINES = ("auto", "batch", "fmu")
CALL_RUNS = 1
"""Runs per run_batch call inside a chunk: the call's output arrays hold every run's rows at once
(~2.5 MB for a 9000-step run) and the run's RunResult turns them into columns; one run a call
turns them while they are still in the cache (measured on a station_day chunk: 7.95 ms a run with
its metrics, against 8.26 ms at 8 runs a call), and keeps a worker's memory flat in the chunk's size."""
MAX_CHUNK = 100


# ======================================================================== the worker side

class _Lease:
    """The live instance lent to one FmuRunner.run: freeInstance() hands it back instead of freeing."""

    def __init__(self, fmu, owner: "ReusableRunner"):
        self._fmu, self._owner, self.fatal = fmu, owner, False

    def __getattr__(self, name):
        attr = getattr(self._fmu, name)
        if name in ("doStep", "terminate", "exitInitializationMode"):
            def call(*a, **k):
                try:
                    return attr(*a, **k)
                except Exception as e:
                    if getattr(e, "status", FATAL) >= FATAL:
                        self.fatal = True
                    raise
            return call
        setattr(self, name, attr)          # cache plain forwards (getReal, setReal, ...)
        return attr

    def freeInstance(self):
        self._owner._give_back(self._fmu, self.fatal)


class ReusableRunner(FmuRunner):
    """An FmuRunner whose runs share one live FMU instance, reset between runs.

    ``run(scenario)`` is FmuRunner.run (same stepping, same results); only the instance's life
    cycle differs: instantiate once, then fmi2Reset before each later run. An instance whose
    initialisation failed (pythonfmu reports fmi2Fatal) is leaked and replaced by a fresh one.
    """

    def __init__(self, fmu_path, unzip_root=None):
        super().__init__(fmu_path, unzip_root)
        self.live = None                  # the instance kept between runs
        self.sink: list[str] = []         # the current run's log
        self.counts = Counter()           # instantiate / reset / leaked

    def _instantiate(self, log):
        self.counts["instantiate"] += 1      # messages go into the current run's log
        return self._new_instance(lambda: self.sink,
                                  f"{self.md.modelName}_{os.getpid()}_{self.counts['instantiate']}")

    def _leak(self, fmu) -> None:
        _LEAKED.append(fmu)
        self.counts["leaked"] += 1

    def start(self, parameters, stop_time, log, what):
        """The live instance reset (or a new one), initialised with ``parameters``; RunError if that fails."""
        self.sink = log
        fmu, self.live = self.live, None
        if fmu is not None:
            try:
                fmu.reset()
                self.counts["reset"] += 1
            except Exception:
                self._leak(fmu)
                fmu = None
        if fmu is None:
            fmu = self._instantiate(log)
        try:
            self.initialise(fmu, parameters, stop_time, log, what)
        except RunError:
            self._leak(fmu)                   # fmi2Fatal: never call this instance again
            raise
        return _Lease(fmu, self)

    def _give_back(self, fmu, fatal: bool) -> None:
        if fatal:
            self._leak(fmu)
        else:
            self.live = fmu

    def close(self) -> None:
        fmu, self.live = self.live, None
        if fmu is not None:
            for call in (fmu.terminate, fmu.freeInstance):
                try:
                    call()
                except Exception:
                    pass
        super().close()


def worker_runner(fmu_path: str, guid: str | None = None, extract_root: str | None = None):
    """This process's runner of ``fmu_path`` (extracted once, below ``extract_root`` if given);
    checks it is the build expected. A native FMU rebuilt at the same path replaces the old one
    (a fresh extraction, its own shared library); a pythonfmu one cannot (its Python modules are
    cached in the process)."""
    runner = _WORKER_FMUS.get(fmu_path)
    if runner is not None and guid is not None and runner.md.guid != guid and runner.kind == "native":
        _WORKER_FMUS.pop(fmu_path).close()
        runner = None
    if runner is None:
        runner = _WORKER_FMUS[fmu_path] = ReusableRunner(fmu_path, extract_root)
    if guid is not None and runner.md.guid != guid:
        raise RuntimeError(f"this worker process (pid {os.getpid()}) already loaded another build of "
                           f"{fmu_path} (GUID {runner.md.guid}, wanted {guid}); a process caches the FMU's "
                           f"Python modules: restart the workers")
    return runner


def _one_line(text: str, limit: int = 600) -> str:
    s = " | ".join(line.strip() for line in str(text).splitlines() if line.strip())
    return s if len(s) <= limit else s[:limit - 3] + "..."


def base_row(spec: RunSpec) -> dict:
    row = {"run_id": spec.run_id, **dict(spec.values)}
    if spec.scenario is not None:
        row["seed"] = spec.scenario.parameter("seed")
    elif "seed" not in row:
        row["seed"] = None
    return row


def execute_run(fmu_path: str, guid: str | None, spec: RunSpec, extract_root: str | None = None) -> dict:
    """Run one sweep point in this (worker) process; never raises: a failure is a row. The FMU is
    extracted below ``extract_root`` (the embedded cluster's scratch folder, removed at its end)
    or, by default, in the system's temporary folder for the worker process's life."""
    row = base_row(spec)
    t0 = time.perf_counter()
    if spec.error is not None:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(spec.error), wall_time=0.0)
        return row
    row["engine"] = ENGINE_FMU
    try:
        runner = worker_runner(fmu_path, guid, extract_root)
        row["fmu"] = runner.kind
        result = runner.run(spec.scenario)
    except RunError as e:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(e))
    except Exception as e:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(f"{type(e).__name__}: {e}"))
    else:
        add_metrics(row, result)
    row["wall_time"] = time.perf_counter() - t0
    return row


def add_metrics(row: dict, result) -> dict:
    """``row`` with the run's metrics, calibration and (span scenario) ATO columns and status ok;
    status failed and the message if computing them raises. The one row builder of both engines."""
    from harness.metrics.estimation import summarise
    try:
        row.update(flatten_summary(summarise(result)))
        row.update(calibration(result))
        row.update(run_ato_row(result))        # a span scenario's: the ATO's metrics
        row.update(status=TEXT_STATUS_OK, error="")
    except Exception as e:
        row.update(status=TEXT_STATUS_FAILED, error=_one_line(f"metrics: {type(e).__name__}: {e}"))
    return row


def execute_chunk(specs: list[RunSpec], call_runs: int = CALL_RUNS) -> list[dict]:
    """Rows of ``specs`` in order, run on the batch engine (harness.run.batch.run_batch, ``call_runs``
    runs per call) in this (worker) process; never raises: a failed run is a row. The rows are
    execute_run's (the same metrics code on the same arrays) but for ``engine`` ("c", or "python"
    for a run the C core does not cover: run_on_chain), ``fmu`` ('': no FMU ran) and
    ``wall_time`` (the run's share of its call plus its metrics)."""
    with heap_kept():
        return _chunk_rows(specs, call_runs)


def _chunk_rows(specs: list[RunSpec], call_runs: int = CALL_RUNS) -> list[dict]:
    rows = []
    for k in range(0, len(specs), call_runs):
        rows += _batch_rows(specs[k:k + call_runs])
    return rows


def pack_chunk(recipe, points: list[tuple[int, dict]]) -> bytes:
    """A chunk as one compressed pickle: the sweep's ``recipe`` (harness.sweep.spec.RunPlan.recipe:
    the base scenario's data and the fixed values, a few kB) and each run's (run id, swept values):
    the worker builds the runs (execute_packed_chunk), so that this process, which also hosts an
    embedded cluster's scheduler, is free to hand out chunks and write rows. Bytes: the dask
    scheduler keeps the arguments of tasks it has finished (measured: ~11 kB a run of a 300-step
    sweep as objects, 1 GB at 100,000 runs)."""
    return zlib.compress(pickle.dumps((recipe, points), protocol=pickle.HIGHEST_PROTOCOL), 1)


def execute_packed_chunk(packed: bytes) -> list[dict]:
    """execute_chunk of a pack_chunk'ed chunk, its runs built here first (on a worker; ~0.4 ms a
    station_day run, not in its wall_time, as building at load was not)."""
    recipe, points = pickle.loads(zlib.decompress(packed))
    with heap_kept():
        return _chunk_rows([recipe.make(run_id, values) for run_id, values in points])


def _batch_rows(specs: list[RunSpec]) -> list[dict]:
    from harness.run.batch import not_covered, run_batch
    rows = [base_row(s) for s in specs]
    valid = []
    for row, spec in zip(rows, specs):
        if spec.error is not None:
            row.update(status=TEXT_STATUS_FAILED, error=_one_line(spec.error), wall_time=0.0)
        else:
            valid.append((row, spec))
    if not valid:
        return rows
    scenarios = [spec.scenario for _, spec in valid]
    t0 = time.perf_counter()
    try:
        results = run_batch(scenarios)
        share = (time.perf_counter() - t0) / len(scenarios)
        outcomes = [(r, None, share) for r in results]
    except Exception as e:
        if len(scenarios) == 1:                  # the run alone: its error is its own
            outcomes = [(None, e, time.perf_counter() - t0)]
        else:
            outcomes = None
    if outcomes is None:
        # one run refused or rejected a step: the call raises for all; each alone keeps the others' rows
        outcomes = []
        for sc in scenarios:
            t1 = time.perf_counter()
            try:
                outcomes.append((run_batch([sc])[0], None, time.perf_counter() - t1))
            except Exception as e:
                outcomes.append((None, e, time.perf_counter() - t1))
    for (row, spec), (result, error, engine_s) in zip(valid, outcomes):
        t1 = time.perf_counter()
        row["fmu"] = ""
        if result is not None:
            row["engine"] = result.engine    # run_batch's own: a run it moved to Python says so
        else:
            try:
                row["engine"] = ENGINE_C if not_covered(spec.scenario) is None else ENGINE_PYTHON
            except Exception:
                row["engine"] = ""           # its parameters were refused: no engine ran it
        if error is not None:
            row.update(status=TEXT_STATUS_FAILED, error=_one_line(f"{type(error).__name__}: {error}"))
        else:
            add_metrics(row, result)
        row["wall_time"] = engine_s + time.perf_counter() - t1
    return rows


def core_identity() -> str:
    """What the batch engine runs in this process, for --resume to refuse mixing two builds' rows:
    ``c <sha256 of the compiled extensions' bytes, 16 hex digits>`` (models._batch and
    models._railcar: the C core is linked into both, so any rebuild that changes its code changes
    the hash), or ``python reference`` when the core is not compiled or RAILCAR_PURE_PYTHON is set.
    A few milliseconds: the two files are ~1 MB each."""
    import hashlib
    from models import batch, compiled
    if not batch.available() or not compiled.enabled():
        return "python reference"
    h = hashlib.sha256()
    for module in (batch._batch, compiled._railcar):
        with open(module.__file__, "rb") as f:
            h.update(f.read())
    return f"c {h.hexdigest()[:16]}"


def chunk_size(runs: int, workers: int) -> int:
    """Runs per dask task: about four tasks per worker (the progress bar moves, a killed worker
    costs one chunk), at most MAX_CHUNK runs (a chunk's rows are held until it ends)."""
    return max(1, min(MAX_CHUNK, -(-runs // (4 * max(1, workers)))))


def worker_check(fmu_path: str | None) -> dict:
    """Run on every worker before a sweep: can it import the harness and read the FMU path (None:
    no FMU, the batch engine), is the C batch engine compiled there?"""
    from models import batch
    return {"pid": os.getpid(), "fmu_readable": fmu_path is None or os.access(fmu_path, os.R_OK),
            "batch": batch.available(), "core": core_identity(), "harness": str(Path(__file__).resolve().parents[1]),
            "threads": threading.active_count()}


# ======================================================================== the cluster

@contextlib.contextmanager
def scratch_folder(prefix: str = "railcar-sweep-"):
    """A temporary folder for an embedded cluster: dask's worker space and every FMU its worker
    processes extract (execute_run's ``extract_root``). Removed on leaving, after the cluster is
    closed (the ``with`` encloses it), also on an exception or Ctrl-C; a SIGTERM is turned into
    KeyboardInterrupt meanwhile so that it is cleaned up too."""
    path = tempfile.mkdtemp(prefix=prefix)
    previous = None
    if threading.current_thread() is threading.main_thread():
        def on_term(signum, frame):
            raise KeyboardInterrupt(f"signal {signum}")
        previous = signal.signal(signal.SIGTERM, on_term)
    try:
        yield path
    finally:
        try:
            shutil.rmtree(path, ignore_errors=True)
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def workers_ignore_ctrl_c():
    """Worker processes started inside inherit SIGINT ignored (a Python process keeps an ignored
    SIGINT), so that a Ctrl-C on the terminal reaches the sweep's process alone: it stops the
    sweep and closes the cluster, instead of every worker printing a KeyboardInterrupt."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)


CLUSTER_CONFIG = {"distributed.worker.profile.enabled": False,
                  "distributed.admin.tick.interval": "1s",
                  "distributed.admin.system-monitor.interval": "5s",
                  "distributed.worker.memory.monitor-interval": "1s"}
"""dask settings of the embedded cluster (its scheduler and nannies live in the sweep's process):
no statistical profiler on the workers (it samples the running task's stack every 10 ms for the
dashboard, which an embedded cluster does not serve: 0.7 ms of a station_day run's ~10 ms on the
batch engine), and the event loop's tick check (default 20 ms), the system monitor (500 ms) and
the nannies' memory checks (100 ms) less often: with them the event loop took ~0.7 s of CPU while
1,000 station_day runs ran, ~0.3 s less this way. A worker over its memory limit is still stopped,
within a second."""


@contextlib.contextmanager
def dask_client(client=None, scheduler: str | None = None, workers: int | None = None):
    """(client, extract_root): ``client`` as given, or one of the scheduler at ``scheduler``, or
    one of an embedded LocalCluster of ``workers`` single-threaded processes (default: one per
    core) whose files are in a scratch folder (``extract_root``). What it opened it closes on
    leaving: the client, the cluster, then the scratch folder."""
    if client is not None:
        yield client, None
        return
    from distributed import Client, LocalCluster
    if scheduler:
        own = Client(scheduler, timeout="30s")
        try:
            yield own, None
        finally:
            own.close()
        return
    import logging
    import dask
    with scratch_folder() as root:
        with workers_ignore_ctrl_c(), dask.config.set(CLUSTER_CONFIG):
            # a free port for the scheduler's HTTP server: None still binds dask's 8787, which a
            # user's own dashboard or a second sweep may hold ("Port 8787 is already in use")
            cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1,
                                   processes=True, dashboard_address="127.0.0.1:0", host="127.0.0.1",
                                   silence_logs=logging.ERROR, local_directory=root,
                                   scheduler_kwargs={"local_directory": root})
        try:
            own = Client(cluster)
            try:
                yield own, root
            finally:
                own.close()
        finally:
            cluster.close()


def check_workers(client, fmu_path: Path | None, log) -> int:
    """The number of workers; RuntimeError if one cannot import the harness or read the FMU
    (None: the batch engine, no FMU; a worker without the compiled C batch engine is reported:
    its runs go to the Python reference, slower; one with another build of the C core than this
    process's, core_identity, is refused)."""
    info = client.scheduler_info()
    if not info.get("workers"):
        client.wait_for_workers(1, timeout=60)
    checks = client.run(worker_check, None if fmu_path is None else str(fmu_path), on_error="return")
    bad = {w: r for w, r in checks.items() if isinstance(r, BaseException)}
    if bad:
        w, e = next(iter(bad.items()))
        raise RuntimeError(f"{len(bad)} dask worker(s) cannot run the harness (e.g. {w}: {type(e).__name__}: {e}); "
                           f"start them from the project folder or with the project on PYTHONPATH")
    unreadable = [w for w, r in checks.items() if not r["fmu_readable"]]
    if unreadable:
        raise RuntimeError(f"{len(unreadable)} dask worker(s) cannot read {fmu_path} (e.g. {unreadable[0]}); "
                           f"the FMU is shipped by path: it must be reachable at that path on every worker")
    if fmu_path is None and not all(r["batch"] for r in checks.values()):
        log(f"warning: {sum(not r['batch'] for r in checks.values())} worker(s) have no compiled C batch engine "
            f"(models._batch): their runs go to the Python reference (engine column 'python'), slower")
    if fmu_path is None:
        mine = core_identity()
        other = {r["core"] for r in checks.values()
                 if r["core"] != mine and r["core"].startswith("c ") and mine.startswith("c ")}
        if other:
            raise RuntimeError(f"dask worker(s) run another build of the C core ({', '.join(sorted(other))}) than "
                               f"this process ({mine}, recorded in sweep.json for --resume): rebuild or restart them")
    threads = {w: n for w, n in client.nthreads().items() if n > 1}
    if threads:
        log(f"warning: {len(threads)} worker(s) run {max(threads.values())} threads: every FMU call takes "
            f"the GIL, so only one thread per worker is useful (dask worker --nthreads 1)")
    return len(checks)


def _dask_failed_row(spec: RunSpec, failure: BaseException) -> dict:
    """The failed row of a run whose task dask could not finish (KilledWorker, ...)."""
    row = base_row(spec)
    row.update(status=TEXT_STATUS_FAILED, wall_time=None,
               error=_one_line(f"dask: {type(failure).__name__}: {failure}"))
    return row


def _submit_all(client, sweep: Sweep, specs: list[RunSpec], fmu_path: str, guid, record: Callable[[dict], bool],
                extract_root: str | None) -> int:
    """Every spec as a dask task; each row goes to ``record`` as it comes. The rows recorded."""
    from distributed import as_completed
    nonce = uuid.uuid4().hex[:8]
    futures = {}
    for spec in specs:
        f = client.submit(execute_run, fmu_path, guid, spec, extract_root, pure=False, retries=2,
                          key=f"railcar-sweep-{sweep.fingerprint[:8]}-{nonce}-{spec.run_id}")
        futures[f.key] = (f, spec)
    ran = 0
    try:
        # with_results: results come in batches with the completions (no round trip per run)
        for f, result in as_completed([f for f, _ in futures.values()], with_results=True, raise_errors=False):
            _, spec = futures.pop(f.key)
            if isinstance(result, dict):
                row = result
            else:                    # an exception: KilledWorker (the run killed its worker every time), ...
                row = _dask_failed_row(spec, result)
            f.release()
            if record(row):
                ran += 1
    finally:
        for f, _ in futures.values():
            f.cancel()
    return ran


def _submit_chunks(client, sweep: Sweep, stream: RunStream, chunk: int | None, workers: int,
                   record: Callable[[dict], bool], in_flight: int) -> int:
    """The runs of ``stream``'s ids in chunks, a dask task each (execute_packed_chunk: its worker
    builds the runs), at most ``in_flight`` chunks submitted at a time (the next one as one ends),
    so that this process and the scheduler hold a bounded number of runs whatever the sweep's size; each row
    goes to ``record`` as its chunk ends. ``chunk`` runs a chunk if given, else next_chunk (at most
    chunk_size, shrinking at the end). A chunk that kept killing its worker becomes failed rows.
    The rows recorded (a retried chunk's rows come once: dask gives a task's result once, and
    ``record`` drops a run id it has)."""
    from distributed import as_completed
    nonce = uuid.uuid4().hex[:8]
    first = chunk or chunk_size(stream.left(), workers)
    futures = {}
    done = as_completed(with_results=True, raise_errors=False)

    plan = sweep.runs.plan
    recipe = plan.recipe()

    def submit_next() -> None:
        part = stream.take(chunk or next_chunk(first, stream.left(), workers))
        if part:
            packed = pack_chunk(recipe, [(i, plan.point(i)) for i in part])
            f = client.submit(execute_packed_chunk, packed, pure=False, retries=2,
                              key=f"railcar-sweep-{sweep.fingerprint[:8]}-{nonce}-{part[0]}-{part[-1]}")
            futures[f.key] = (f, part)
            done.add(f)

    ran = 0
    try:
        for _ in range(max(1, in_flight)):
            submit_next()
        for f, result in done:
            _, part = futures.pop(f.key)
            submit_next()
            if isinstance(result, list):
                rows = result
            else:                    # an exception: KilledWorker (the chunk killed its worker every time), ...
                rows = [_dask_failed_row(plan.build(run_id), result) for run_id in part]
            f.release()
            for row in rows:
                if record(row):
                    ran += 1
    finally:
        for f, _ in futures.values():
            f.cancel()
    return ran


IN_FLIGHT_PER_WORKER = 4
"""Chunks submitted ahead per worker (harness/sweep/execute.py _submit_chunks): enough to keep every
worker busy while rows come back, few enough that the scheduler's memory does not grow with the runs."""


def execute_runs(sweep: Sweep, ids: Sequence[int], fmu_path: Path | None, guid: str | None,
                 record: Callable[[dict], bool], client=None, scheduler: str | None = None,
                 workers: int | None = None, log=print, engine: str = "fmu",
                 chunk: int | None = None) -> tuple[int, int]:
    """Run the runs of ``sweep`` whose ids are ``ids`` and hand each row to ``record`` (True if it
    kept the row), on dask (see dask_client): ``engine`` "fmu", a run a task through the FMU at
    ``fmu_path``, every run built here (sweep.runs.build) before the first is submitted, as the
    tasks are, an invalid one's row recorded here at once; "batch", ``chunk`` runs a task (default
    next_chunk) on the batch engine (execute_chunk), each chunk's runs built by its worker (an
    invalid one's row made there). The runs up to the first valid one are built here: invalid, their
    rows now, and no cluster is started when none is valid. Returns (rows recorded, dask workers)."""
    if engine not in ("fmu", "batch"):
        raise ValueError(f"engine: expected 'fmu' or 'batch', got {engine!r}")
    invalid_rows, first_valid = 0, len(ids)
    for pos, run_id in enumerate(ids):
        spec = sweep.runs.build(run_id)
        if spec.error is None:
            first_valid = pos
            break
        record(execute_run(str(fmu_path), guid, spec) if engine == "fmu" else execute_chunk([spec])[0])
        invalid_rows += 1
    if first_valid == len(ids):
        return invalid_rows, 0
    ids = ids[first_valid:]
    with dask_client(client, scheduler, workers) as (c, extract_root):
        n_workers = check_workers(c, fmu_path if engine == "fmu" else None, log)
        if engine == "fmu":
            valid = []
            for spec in (sweep.runs.build(i) for i in ids):
                if spec.error is None:
                    valid.append(spec)
                else:
                    record(execute_run(str(fmu_path), guid, spec))
                    invalid_rows += 1
            ran = _submit_all(c, sweep, valid, str(fmu_path), guid, record, extract_root)
        else:
            ran = _submit_chunks(c, sweep, RunStream(ids), chunk, n_workers, record, IN_FLIGHT_PER_WORKER * n_workers)
    return ran + invalid_rows, n_workers
