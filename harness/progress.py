"""A dependency-free progress bar on stderr (only when stderr is a terminal, or forced)."""
from __future__ import annotations

import sys
import time


class Progress:
    def __init__(self, total: int, label: str = "", enabled: bool | None = None):
        self.total, self.label, self.done, self.failed = total, label, 0, 0
        self.t0 = time.monotonic()
        self.enabled = sys.stderr.isatty() if enabled is None else enabled

    def advance(self, what: str = "", failed: bool = False) -> None:
        self.done += 1
        self.failed += failed
        if not self.enabled:
            return
        elapsed = time.monotonic() - self.t0
        eta = elapsed / self.done * (self.total - self.done)
        width = 30
        filled = int(width * self.done / max(self.total, 1))
        sys.stderr.write(f"\r{self.label} [{'#' * filled}{'.' * (width - filled)}] {self.done}/{self.total}"
                         f" failed {self.failed} ETA {eta:5.0f} s {what[:30]:<30}")
        if self.done == self.total:
            sys.stderr.write("\n")
        sys.stderr.flush()
