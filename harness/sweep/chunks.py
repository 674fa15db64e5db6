"""How a sweep's runs are cut into chunks for the batch engine, and what a worker does around one:
the run ids handed out a chunk at a time (``RunStream``), the chunks' sizes shrinking towards the
sweep's end (``next_chunk``), and the worker's heap kept while a chunk runs (``heap_kept``). Used by
harness/sweep/execute.py; no dask here.
"""
from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence

MIN_CHUNK = 8
"""The fewest runs of a chunk that next_chunk cuts (the last one may have fewer): a dask task costs a
few milliseconds of this process's and the scheduler's time."""


class RunStream:
    """The run ids of a sweep's runs not taken yet, a chunk at a time (``take``); the runs
    themselves are built where they run (execute_packed_chunk)."""

    def __init__(self, ids: Sequence[int]):
        self.ids, self.pos = ids, 0

    def take(self, n: int) -> Sequence[int]:
        """The next ``n`` run ids (fewer only at the end)."""
        part = self.ids[self.pos:self.pos + n]
        self.pos += len(part)
        return part

    def left(self) -> int:
        """Run ids not taken yet."""
        return len(self.ids) - self.pos


TAIL_SHARE = 2
"""A chunk of the default size (chunk_size) takes at most 1 / (TAIL_SHARE x workers) of the runs
not submitted yet: chunks shrink towards the sweep's end, so that the workers end together (one
chunk of 100 station_day runs left to one worker is ~0.9 s of the other one idle)."""


def next_chunk(first: int, left: int, workers: int) -> int:
    """Runs of the next chunk of a sweep in chunks of at most ``first`` (chunk_size) runs with
    ``left`` runs not submitted yet on ``workers``: ``first``, shrinking towards the end (TAIL_SHARE),
    never below MIN_CHUNK (nor ``first``)."""
    return max(min(first, MIN_CHUNK), min(first, -(-left // (TAIL_SHARE * max(1, workers)))))


M_TRIM_THRESHOLD, M_MMAP_THRESHOLD = -1, -3      # glibc's mallopt parameters (malloc.h)
GLIBC_MMAP_THRESHOLD = 128 * 1024
"""glibc's default M_MMAP_THRESHOLD, fixed once MALLOC_TRIM_THRESHOLD_ is set (that stops its
dynamic adjustment)."""
CHUNK_HEAP_KEPT = 32 * 1024 * 1024
"""Freed heap a worker keeps while it runs a chunk (heap_kept); blocks up to this size come from the
heap, not from mmap."""


def _glibc():
    """glibc's libc (ctypes) when this process uses it, else None (another C library, Windows)."""
    import ctypes
    import ctypes.util
    import platform
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc":
        return None
    try:
        return ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
    except OSError:
        return None


@contextlib.contextmanager
def heap_kept():
    """While a chunk runs, freed memory stays in the process's heap, then is handed back.

    dask's nanny starts its workers with MALLOC_TRIM_THRESHOLD_=65536 (distributed.nanny.pre-spawn-environ),
    so that a worker hands freed memory back to the system at once; it also fixes glibc's mmap
    threshold at 128 kB. A batch run allocates and frees its arrays (2.4 MB of outputs and as much
    of columns for station_day, hundreds of 72 kB metric temporaries): each was mapped again, page
    by page (measured: 9.95 instead of 8.40 ms a station_day run). Here both thresholds are raised
    to CHUNK_HEAP_KEPT for the chunk, then set back to the worker's and the heap trimmed
    (malloc_trim), so that between chunks the worker holds what dask expects. Nothing changes where
    MALLOC_TRIM_THRESHOLD_ is not set (glibc adjusts its thresholds itself) or glibc is not the C
    library. The thresholds are the process's: in a worker of several threads (a sweep warns about
    those) one chunk's end sets them back while another runs, which costs time, not results."""
    trim = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    libc = _glibc() if trim is not None and trim.strip().isdigit() else None
    if libc is None:
        yield
        return
    libc.mallopt(M_TRIM_THRESHOLD, CHUNK_HEAP_KEPT)
    libc.mallopt(M_MMAP_THRESHOLD, CHUNK_HEAP_KEPT)
    try:
        yield
    finally:
        mmap = os.environ.get("MALLOC_MMAP_THRESHOLD_", "")        # the worker's own, if it set one
        libc.mallopt(M_MMAP_THRESHOLD, int(mmap) if mmap.strip().isdigit() else GLIBC_MMAP_THRESHOLD)
        libc.mallopt(M_TRIM_THRESHOLD, int(trim))
        libc.malloc_trim(0)
