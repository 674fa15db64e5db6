"""Steps per second of the default native RailCar in a C host: this checkout against an earlier
revision, measured in one run (issue 27's target: a better default estimator may cost at most
half the speed).

    python benchmarks/native_baseline.py --baseline REV [--host-steps 200000] [--rounds 5]

REV's sources come from ``git archive`` into a temporary folder and build there with their own
build.py; both RailCarNative.fmu (FMI 2.0, their own default parameters, all outputs read every
step, step 0.1 s) run in benchmarks/native_host_bench.c, interleaved round by round so that both
see the same machine; the best round of each is printed with the ratio now / baseline.
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(HERE))

from native_benchmark import build_host, host_rate  # noqa: E402

TARGET = 0.5
"""now / baseline steps per second the default may not fall below."""


def baseline_fmu(rev: str, tmp: Path) -> Path:
    """RailCarNative.fmu of revision ``rev``, built by that revision's build.py."""
    src = tmp / "baseline"
    src.mkdir()
    archive = tmp / "baseline.tar"
    subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", "-o", str(archive), rev],
                   check=True)
    with tarfile.open(archive) as tar:
        tar.extractall(src, filter="data")
    env = {**os.environ, "PYTHONPATH": str(src)}
    proc = subprocess.run([sys.executable, "build.py", "--dest", str(src / "dist")], cwd=src,
                          env=env, capture_output=True, text=True)
    if proc.returncode:
        raise SystemExit(f"building {rev} failed:\n{proc.stdout}{proc.stderr}")
    return src / "dist" / "native" / "RailCarNative.fmu"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, help="git revision to compare with (e.g. fe660f8)")
    ap.add_argument("--host-steps", type=int, default=200_000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    from harness.run.fmus import ensure_built
    now_fmu = ensure_built(quiet=True)["RailCar"].parent / "native" / "RailCarNative.fmu"
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        base_fmu = baseline_fmu(args.baseline, tmp)
        exe = build_host(tmp)
        now = base = 0.0
        for _ in range(args.rounds):
            now = max(now, host_rate(exe, now_fmu, args.host_steps, 1))
            base = max(base, host_rate(exe, base_fmu, args.host_steps, 1))
    head = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--short", "HEAD"],
                          capture_output=True, text=True).stdout.strip()
    print(f"default native RailCar (FMI 2.0) in the C host, {args.host_steps:,} steps of 0.1 s, "
          f"all outputs read, best of {args.rounds} interleaved rounds")
    print(f"  baseline {args.baseline:<10} {base:>12,.0f} steps/s {1e6 / base:8.3f} us/step")
    print(f"  now      {head:<10} {now:>12,.0f} steps/s {1e6 / now:8.3f} us/step")
    ratio = now / base
    print(f"  now / baseline: {ratio:.2f} (target >= {TARGET}: {'met' if ratio >= TARGET else 'MISSED'})")


if __name__ == "__main__":
    main()
