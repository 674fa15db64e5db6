"""Helpers of harness/sweep.py for its files and folders: what a results folder already holds,
and the scratch folder of an embedded dask cluster (removed with everything its workers
extracted when the sweep ends, also on an error, Ctrl-C or SIGTERM).
"""
from __future__ import annotations

import contextlib
import csv
import io
import json
import shutil
import signal
import tempfile
import threading
from pathlib import Path

from .textio import InputError, read_text


def read_meta(meta_path: Path, error: type[Exception] = InputError) -> dict:
    """A sweep folder's sweep.json (UTF-8 JSON object); ``error`` names the file."""
    try:
        meta = json.loads(read_text(meta_path, error))
    except json.JSONDecodeError as e:
        raise error(f"{meta_path}: not valid JSON: {e}") from None
    if not isinstance(meta, dict):
        raise error(f"{meta_path}: not a sweep's sweep.json (expected a JSON object)")
    return meta


def held_results(out_dir: Path, error: type[Exception] = InputError) -> tuple[int, dict]:
    """(number of distinct run ids in DIR/results.csv, DIR/sweep.json or {}): what a rerun
    without --resume would discard."""
    csv_path, meta_path = out_dir / "results.csv", out_dir / "sweep.json"
    meta = read_meta(meta_path, error) if meta_path.is_file() else {}
    if not csv_path.is_file():
        return 0, meta
    ids = set()
    try:
        for cells in list(csv.reader(io.StringIO(read_text(csv_path, error))))[1:]:
            if cells and cells[0].strip().isdigit():
                ids.add(int(cells[0]))
    except csv.Error as e:
        raise error(f"{csv_path}: not valid CSV: {e}") from None
    return len(ids), meta


def check_rerun(out_dir: Path, fingerprint: str, resume: bool, overwrite: bool,
                error: type[Exception] = InputError) -> dict:
    """DIR's sweep.json ({} if none); ``error`` if DIR holds results and neither ``resume`` nor
    ``overwrite`` is given: a folder that holds results of a sweep is not silently emptied."""
    held, meta = held_results(out_dir, error)
    if held and not resume and not overwrite:
        _refuse(out_dir, held, meta, fingerprint, error)
    return meta


def _refuse(out_dir: Path, held: int, meta: dict, fingerprint: str, error: type[Exception]) -> None:
    name = meta.get("name") or "(unknown)"
    if meta.get("fingerprint") in (None, fingerprint):
        raise error(f"{out_dir} already holds {held} results of sweep '{name}': use --resume to continue "
                    f"or --overwrite to start again")
    raise error(f"{out_dir} already holds {held} results of sweep '{name}', another sweep (its runs, fixed "
                f"values or base scenario differ): use another --out, or --overwrite to start again")


def clear_outputs(out_dir: Path) -> None:
    """--overwrite: drop the previous sweep's derived files (results.csv is rewritten anyway)."""
    for name in ("results.parquet", "summary.md"):
        (out_dir / name).unlink(missing_ok=True)
    plots = out_dir / "plots"
    if plots.is_dir():
        for png in plots.glob("*.png"):
            png.unlink(missing_ok=True)


@contextlib.contextmanager
def scratch_folder(prefix: str = "railcar-sweep-"):
    """A temporary folder for an embedded cluster: dask's worker space and every FMU its worker
    processes extract (harness.sweep.execute_run's ``extract_root``). Removed on leaving, after
    the cluster is closed (the ``with`` encloses it), also on an exception or Ctrl-C; a SIGTERM
    is turned into KeyboardInterrupt meanwhile so that it is cleaned up too."""
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
