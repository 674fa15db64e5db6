"""Running a sanitized C host in a subprocess and reading what it prints: shared by the native
FMI 2 and FMI 3 sanitizer tests (tests/fmu_tests/test_native_sanitized.py, tests/fmu_tests/test_native3_sanitized.py).

A host prints "rss_kb CYCLE KB" and "live_bytes CYCLE BYTES" lines at cycles 100 and 1000, and
ends with "ok" when every expectation held."""
from __future__ import annotations

import os
import re
import subprocess

from conftest import ROOT

RSS_GROWTH_LIMIT_KB = 1024
ASAN_DEFAULT = "detect_leaks=1:abort_on_error=0:halt_on_error=1"
ASAN_SMALL_QUARANTINE = ASAN_DEFAULT + ":quarantine_size_mb=1"
"""ASan's default quarantine keeps freed memory resident; 1 MB lets RSS show a real leak."""


def run_host(exe, args: list[str], asan_options: str = ASAN_DEFAULT):
    """(the finished process, {"rss_kb"|"live_bytes": {cycle: value}})."""
    env = dict(os.environ, ASAN_OPTIONS=asan_options,
               UBSAN_OPTIONS="print_stacktrace=1:halt_on_error=1")
    env.pop("LD_PRELOAD", None)
    proc = subprocess.run([str(exe), *args], capture_output=True, text=True, env=env,
                          timeout=120, cwd=str(ROOT))
    figures = {key: {int(c): int(v) for c, v in re.findall(rf"^{key} (\d+) (\d+)$",
                                                             proc.stdout, re.M)}
               for key in ("rss_kb", "live_bytes")}
    return proc, figures


def _report(proc) -> str:
    return proc.stdout[-2000:] + proc.stderr[-4000:]


def no_sanitizer_report(proc) -> None:
    assert "Sanitizer" not in proc.stderr and "runtime error" not in proc.stderr, _report(proc)


def clean(proc) -> None:
    """No sanitizer report, exit 0, every expectation held ("ok" last, no "FAILED")."""
    no_sanitizer_report(proc)
    assert proc.returncode == 0, _report(proc)
    assert proc.stdout.rstrip().endswith("ok"), _report(proc)
    assert "FAILED" not in proc.stdout, _report(proc)


def check_ato_host(proc, figures) -> None:
    """What tests/fmu_cases/native_ato_cycles.c (FMI 2 or, -DATO_FMI3, FMI 3) must print: a clean
    run, a bad input with the safe brake's warning, a discarded step, reset bit-identical to a
    fresh instance (one ulp off differing), 20 refused initialisations, 200 cycles, the live heap
    bytes equal after cycles 20 and 200; no sanitizer report."""
    clean(proc)
    out = proc.stdout
    assert "bad_input warning with the safe brake; step of 0 discarded" in out, out
    assert re.search(r"^reset 300 steps x 5 outputs bit-identical to a fresh instance; "
                     r"one ulp off differs from step \d+$", out, re.M), out
    assert "failed_inits 20 refused naming the parameter" in out and "cycles 200" in out, out
    live = figures["live_bytes"]
    assert set(live) == {20, 200} and live[200] == live[20], f"live heap bytes: {live}"
