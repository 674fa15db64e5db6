"""A sweep's results folder: results.csv, results.parquet, sweep.json, summary.md and the lock.

One row per run is appended to ``DIR/results.csv`` as runs finish (completion order, units in
the header cells ``name [unit]``); the writer keeps only the run ids, so its memory does not grow
with the rows' contents. ``DIR/results.parquet`` (when pyarrow is importable) is written from the
CSV when the sweep ends, also after an error or Ctrl-C, streamed in row groups of PARQUET_ROWS;
that pass also feeds the sweep's summary and plot sample (``close(on_row)``).
``read_results(DIR)`` returns the table sorted by run id. ``--resume`` skips the run ids
already in results.csv (ok or failed) if the sweep, its base scenario and the FMU build are
unchanged (``DIR/sweep.json``: the FMU's GUID, or for the batch engine the C core's identity,
harness.sweep.execute.core_identity); without ``--resume``, a folder that holds results is refused
(SweepError) unless ``--overwrite`` says to start again. ``DIR/sweep.lock`` keeps a second
sweep from writing the same folder meanwhile.
"""
from __future__ import annotations

import csv
import io
import json
import os
from pathlib import Path

from harness.sweep.spec import Sweep, SweepError
from harness.sweep.table import Column, SweepOutcome, Table, cell_text, format_sweep_summary, parse_cell, sweep_columns
from harness.textio import read_text

PARQUET_ROWS = 10_000
"""Rows per Parquet row group: the CSV is read and converted this many rows at a time."""


def read_meta(meta_path: Path) -> dict:
    """A sweep folder's sweep.json (UTF-8 JSON object); SweepError names the file."""
    try:
        meta = json.loads(read_text(meta_path, SweepError))
    except json.JSONDecodeError as e:
        raise SweepError(f"{meta_path}: not valid JSON: {e}") from None
    if not isinstance(meta, dict):
        raise SweepError(f"{meta_path}: not a sweep's sweep.json (expected a JSON object)")
    return meta


def held_results(out_dir: Path) -> tuple[int, dict]:
    """(number of distinct run ids in DIR/results.csv, DIR/sweep.json or {}): what a rerun
    without --resume would discard."""
    csv_path, meta_path = out_dir / "results.csv", out_dir / "sweep.json"
    meta = read_meta(meta_path) if meta_path.is_file() else {}
    if not csv_path.is_file():
        return 0, meta
    ids = set()
    try:
        for cells in list(csv.reader(io.StringIO(read_text(csv_path, SweepError))))[1:]:
            if cells and cells[0].strip().isdigit():
                ids.add(int(cells[0]))
    except csv.Error as e:
        raise SweepError(f"{csv_path}: not valid CSV: {e}") from None
    return len(ids), meta


def check_rerun(out_dir: Path, fingerprint: str, resume: bool, overwrite: bool) -> dict:
    """DIR's sweep.json ({} if none); SweepError if DIR holds results and neither ``resume`` nor
    ``overwrite`` is given: a folder that holds results of a sweep is not silently emptied."""
    held, meta = held_results(out_dir)
    if held and not resume and not overwrite:
        name = meta.get("name") or "(unknown)"
        if meta.get("fingerprint") in (None, fingerprint):
            raise SweepError(f"{out_dir} already holds {held} results of sweep '{name}': use --resume to continue "
                             f"or --overwrite to start again")
        raise SweepError(f"{out_dir} already holds {held} results of sweep '{name}', another sweep (its runs, "
                         f"fixed values or base scenario differ): use another --out, or --overwrite to start again")
    return meta


def clear_outputs(out_dir: Path) -> None:
    """--overwrite: drop the previous sweep's derived files (results.csv is rewritten anyway)."""
    for name in ("results.parquet", "summary.md"):
        (out_dir / name).unlink(missing_ok=True)
    plots = out_dir / "plots"
    if plots.is_dir():
        for png in plots.glob("*.png"):
            png.unlink(missing_ok=True)


def read_results(out_dir: str | Path, sort: bool = True) -> Table:
    """The results of a sweep folder (results.csv + sweep.json), sorted by run id (or as written)."""
    out_dir = Path(out_dir)
    meta = read_meta(out_dir / "sweep.json")
    cols = [Column(*c) for c in meta["columns"]]
    rows = _read_csv_rows(out_dir / "results.csv", cols)
    if sort:
        rows.sort(key=lambda r: r["run_id"])
    return Table(cols, rows)


def _read_csv_rows(path: Path, cols: list[Column]) -> list[dict]:
    """Well-formed rows of results.csv (a line cut short by an interruption is dropped)."""
    return list(iter_csv_rows(path, cols))


def iter_csv_rows(path: Path, cols: list[Column]):
    """The well-formed rows of results.csv one at a time (memory flat in the file's length); a
    last line cut short by an interruption (no newline at the end) is dropped."""
    if not path.is_file():
        return
    with open(path, "rb") as f:
        f.seek(0, os.SEEK_END)
        size = f.tell()
        if size:
            f.seek(size - 1)
        complete = not size or f.read(1) == b"\n"
    try:
        with open(path, newline="", encoding="utf-8") as f:
            reader = csv.reader(f)
            header = next(reader, None)
            if header != [c.header for c in cols]:
                raise SweepError(f"{path}: header does not match the sweep's columns")
            pending = None               # a row is yielded once the next one shows it was not the last
            for cells in reader:
                if pending is not None:
                    yield pending
                pending = None
                if len(cells) != len(cols):
                    continue
                try:
                    pending = {c.key: parse_cell(x, c.kind) for c, x in zip(cols, cells)}
                except ValueError:
                    continue
            if pending is not None and complete:
                yield pending
    except UnicodeDecodeError as e:
        raise SweepError(f"{path}: not UTF-8 text: {e}") from None
    except csv.Error as e:
        raise SweepError(f"{path}: not valid CSV: {e}") from None


class ResultsWriter:
    """Appends rows to DIR/results.csv as they come (deduplicated by run id), Parquet alongside."""

    def __init__(self, out_dir: Path, sweep: Sweep, fmu_guid: str | None, resume: bool, overwrite: bool = False,
                 fmu_kind: str | None = None, engine: str = "fmu", core: str | None = None):
        self.out_dir = out_dir
        self.core = core
        self.fmu_kind = fmu_kind
        self.engine = engine
        self.cols = sweep_columns(sweep)
        self.csv_path = out_dir / "results.csv"
        self.parquet_path = out_dir / "results.parquet"
        meta_path = out_dir / "sweep.json"
        meta = {"sweep": str(sweep.path.resolve()), "name": sweep.name, "fingerprint": sweep.fingerprint,
                "engine": engine, "fmu_guid": fmu_guid, "fmu_kind": fmu_kind, "core": core, "runs": len(sweep.runs),
                "columns": [[c.key, c.unit, c.kind] for c in self.cols]}
        out_dir.mkdir(parents=True, exist_ok=True)
        self._lock = _lock_folder(out_dir)
        try:
            rows = self._previous_rows(sweep, fmu_guid, resume, overwrite)
        except BaseException:
            self._unlock()
            raise
        meta_path.write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
        self.done = {r["run_id"] for r in rows}
        tmp = self.csv_path.with_suffix(".csv.tmp")       # a clean file: header + the complete rows kept
        with open(tmp, "w", newline="", encoding="utf-8") as f:
            w = csv.writer(f)
            w.writerow([c.header for c in self.cols])
            for r in rows:
                w.writerow([cell_text(r.get(c.key)) for c in self.cols])
        os.replace(tmp, self.csv_path)
        self._f = open(self.csv_path, "a", newline="", encoding="utf-8")
        self._w = csv.writer(self._f)
        self.resumed = len(rows)

    def _previous_rows(self, sweep: Sweep, fmu_guid, resume: bool, overwrite: bool) -> list[dict]:
        """The rows kept from an earlier call (--resume); a folder that holds results is refused
        without --resume or --overwrite (its rows would be discarded silently)."""
        old = check_rerun(self.out_dir, sweep.fingerprint, resume, overwrite)
        if overwrite:
            clear_outputs(self.out_dir)
            return []
        if not resume or not old:
            return []
        if old.get("fingerprint") != sweep.fingerprint:
            raise SweepError(f"{self.out_dir}: --resume: the results there are of another sweep (its runs, "
                             f"fixed values or base scenario differ); use another --out or drop --resume")
        if old.get("engine", "fmu") != self.engine:
            raise SweepError(f"{self.out_dir}: --resume: the results there ran on the {old.get('engine', 'fmu')} "
                             f"engine, this call would run the {self.engine} one; give --engine "
                             f"{old.get('engine', 'fmu')} to continue, or use another --out")
        if old.get("fmu_kind") and self.fmu_kind and old["fmu_kind"] != self.fmu_kind:
            raise SweepError(f"{self.out_dir}: --resume: the results there ran on the {old['fmu_kind']} FMU, this "
                             f"call would run the {self.fmu_kind} one; give --fmu {old['fmu_kind']} to continue, "
                             f"or use another --out")
        if old.get("fmu_guid") != fmu_guid:
            raise SweepError(f"{self.out_dir}: --resume: the FMU was rebuilt since (GUID {old.get('fmu_guid')} "
                             f"-> {fmu_guid}); rows of two builds would mix: use another --out or drop --resume")
        if old.get("core") != self.core:
            raise SweepError(f"{self.out_dir}: --resume: the results there ran on another build of the batch engine "
                             f"(core {old.get('core')!r}, now {self.core!r}); rows of two builds would mix: use "
                             f"another --out or drop --resume")
        seen, kept = set(), []
        for r in _read_csv_rows(self.csv_path, self.cols):      # the first row of a run id wins
            if r["run_id"] not in seen:
                seen.add(r["run_id"])
                kept.append(r)
        return kept

    def _unlock(self) -> None:
        if self._lock is not None:
            self._lock.close()            # releases the lock
            self._lock = None

    def write(self, row: dict) -> bool:
        """Append a row unless its run id is already there; False for a duplicate."""
        if row["run_id"] in self.done:
            return False
        self.done.add(row["run_id"])
        self._w.writerow([cell_text(row.get(c.key)) for c in self.cols])
        self._f.flush()
        return True

    def write_parquet(self, on_row=None) -> Path | None:
        """DIR/results.parquet from results.csv (every row there, as written); None without pyarrow.
        ``on_row``: called with each row read, as it is converted (the sweep's end needs one pass
        over the rows, harness.sweep.main.StreamedEnd: this one), unless pyarrow is missing."""
        rows = iter_csv_rows(self.csv_path, self.cols)
        if on_row is not None:
            rows = _passed_to(on_row, rows)
        return write_parquet_rows(self.cols, rows, self.parquet_path)

    def close(self, on_row=None) -> bool:
        """Close results.csv, write results.parquet (``on_row`` sees each row then: write_parquet)
        and release the lock; True if ``on_row`` saw every row of results.csv, False if not (no
        pyarrow: no pass was made)."""
        if not self._f.closed:
            self._f.close()
        try:
            return self.write_parquet(on_row) is not None
        finally:
            self._unlock()


def _passed_to(on_row, rows):
    for row in rows:
        on_row(row)
        yield row


def _lock_folder(out_dir: Path):
    """An exclusive lock on DIR/sweep.lock for the sweep's life: two sweeps writing one folder
    would lose rows (a --resume rewrites results.csv). None where fcntl is missing (Windows)."""
    try:
        import fcntl
    except ImportError:
        return None
    f = open(out_dir / "sweep.lock", "a+", encoding="utf-8")
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        f.seek(0)
        holder = f.read().strip()
        f.close()
        raise SweepError(f"{out_dir}: another sweep is writing there ({holder or 'unknown process'}); "
                         f"wait for it or use another --out") from None
    f.seek(0)
    f.truncate()
    f.write(f"pid {os.getpid()}\n")
    f.flush()
    return f


def write_parquet(table: Table, path: Path) -> Path | None:
    """The table as Parquet (units in each field's metadata); None when pyarrow is missing."""
    return write_parquet_rows(table.columns, table.rows, path)


def write_parquet_rows(columns: list[Column], rows, path: Path, group: int = PARQUET_ROWS) -> Path | None:
    """``rows`` (any iterable of row dicts, read once) as Parquet, ``group`` rows at a time (a row
    group each), units in each field's metadata; written to a temporary file and moved into place,
    so ``path`` is always a whole file. None when pyarrow is missing."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        return None
    types = {"int": pa.int64(), "float": pa.float64(), "str": pa.string()}
    schema = pa.schema([pa.field(c.key, types[c.kind], metadata={"unit": c.unit}) for c in columns])
    tmp = path.with_suffix(".parquet.tmp")

    def flush(writer, batch):
        writer.write_table(pa.Table.from_arrays(
            [pa.array([r.get(c.key) for r in batch], type=types[c.kind]) for c in columns], schema=schema))

    with pq.ParquetWriter(tmp, schema) as writer:
        batch = []
        for row in rows:
            batch.append(row)
            if len(batch) >= group:
                flush(writer, batch)
                batch = []
        if batch:
            flush(writer, batch)
    os.replace(tmp, path)
    return path


def write_summary(out_dir: Path, sweep: Sweep, outcome: SweepOutcome) -> Path:
    """DIR/summary.md: the sweep's title, purpose and format_sweep_summary's text."""
    path = out_dir / "summary.md"
    text = format_sweep_summary(sweep, outcome)
    path.write_text(f"# Sweep: {sweep.name}\n\n{sweep.purpose}\n\n```\n{text}\n```\n", encoding="utf-8")
    return path
