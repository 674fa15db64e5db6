"""Wall time of the ATO closed-loop study (studies/ato_closed_loop.py) with the Python controller
against the native one (issue 30: >= 20x faster, the same table; issue 31: <= 15 s for 100 seeds
per case on 2 cores).

    python benchmarks/ato_study_benchmark.py [--seeds 10] [--full-seeds 100] [--workers 2]

Prints, measured in one run on --workers processes (the study's own study(): its runs and its
references, the Python planners' energies, which take the same ~5 s of CPU with either controller):
  - the study for --seeds seeds per case and variant with --controller python, then native, and
    the ratio;
  - both tables and whether they are equal (string compare; tests/model_tests/core/
    test_core_ato_closed_loop.py holds the runs bit-equal);
  - the native study for --full-seeds seeds per case (the study's default, 100), and against it
    the Python study projected linearly from --seeds (an upper bound: the references do not grow
    with the seeds).
The host is shared and its speed varies (other jobs on the 2 cores), so compare the ratio, measured
in one run; `user` CPU seconds of the workers are printed too (less sensitive to other load).
"""
from __future__ import annotations

import argparse
import os
import resource
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "studies"))

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # one thread per worker: before numpy
os.environ.setdefault("OMP_NUM_THREADS", "1")

import ato_closed_loop as study  # noqa: E402


def children_cpu() -> float:
    """CPU seconds [s] (user + system) of the finished worker processes so far."""
    r = resource.getrusage(resource.RUSAGE_CHILDREN)
    return r.ru_utime + r.ru_stime


def timed_study(n_seeds: int, workers: int, controller: str):
    """(table, wall time [s], workers' CPU time [s]) of the whole study."""
    cpu0, t0 = children_cpu(), time.perf_counter()
    results, refs = study.study(list(study.CASES), n_seeds, workers, controller)
    wall, cpu = time.perf_counter() - t0, children_cpu() - cpu0
    return study.table(results, refs), wall, cpu


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=10, help="seeds per case for the comparison")
    ap.add_argument("--full-seeds", type=int, default=100,
                    help="seeds per case for the native study alone (0: skip)")
    ap.add_argument("--workers", type=int, default=2, help="processes")
    args = ap.parse_args(argv)
    if study.default_controller() != "native":
        sys.exit("the C core is not compiled or is switched off (RAILCAR_PURE_PYTHON): "
                 "python setup.py build_ext --inplace")
    n_runs = len(study.CASES) * len(study.VARIANTS) * args.seeds
    print(f"ATO closed-loop study, {args.seeds} seeds per case and variant ({n_runs} runs), "
          f"{args.workers} workers")
    py_table, py_wall, py_cpu = timed_study(args.seeds, args.workers, "python")
    print(f"  --controller python: {py_wall:7.1f} s wall ({py_cpu:6.1f} s CPU)")
    c_table, c_wall, c_cpu = timed_study(args.seeds, args.workers, "native")
    print(f"  --controller native: {c_wall:7.1f} s wall ({c_cpu:6.1f} s CPU)")
    print(f"  ratio python / native: {py_wall / c_wall:.1f}x wall, {py_cpu / c_cpu:.1f}x CPU")
    print(f"\nthe table, --controller python:\n{py_table}\nthe table, --controller native:\n{c_table}")
    print(f"tables equal (string compare): {'yes' if py_table == c_table else 'NO'}")
    if args.full_seeds:
        _, full_wall, full_cpu = timed_study(args.full_seeds, args.workers, "native")
        scale = args.full_seeds / args.seeds
        print(f"\n{args.full_seeds} seeds per case, --controller native: {full_wall:.1f} s wall "
              f"({full_cpu:.1f} s CPU; issue 31's target <= 15 s on 2 cores)")
        print(f"  --controller python projected from {args.seeds} seeds: {py_wall * scale:.0f} s wall, "
              f"{py_cpu * scale:.0f} s CPU -> ratio {py_wall * scale / full_wall:.1f}x wall, "
              f"{py_cpu * scale / full_cpu:.1f}x CPU (issue 30's target >= 20x)")


if __name__ == "__main__":
    main()
