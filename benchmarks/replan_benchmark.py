"""The ATO's re-plan in C (models/core/ato_planner.c) vs the Python reference (models/ato/planner.py).

    python benchmarks/replan_benchmark.py [--scenarios ato_nominal ato_mass_plus20 ...] [--repeat 3]

Runs a few library ATO scenarios on the models chain and records every ReducedPlanner.plan call
the controllers make (the PlanCar, s0, v0, t0, arrival), then replays each span's calls in order on
a fresh Python planner and on a fresh C planner (through tests/core_cases/ato_plan_shim.c, built
here with -O2; its ctypes call is inside the C time), interleaved call by call so that both see
the same machine load, each call timed --repeat times on planners in the same warm-start state
(the best of the repeats: the machine is shared). Prints per implementation the median and the
99th percentile of the per-call times and their ratios C / Python, and how many of the replayed
plans agree bit for bit (arrival, hold speed, energy). Issue 30's target: C <= 5 % of Python's
time.
"""
from __future__ import annotations

import argparse
import ctypes
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import fields
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from harness.run.driver import run_on_chain  # noqa: E402
from harness.run.scenario import load_scenario  # noqa: E402
from models.ato.motion import PlanCar  # noqa: E402
from models.ato.planner import ReducedPlanner, plan_setup  # noqa: E402
from models.planning.span import CarTraction  # noqa: E402

CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_plan_shim.c"
SOURCES = ["ato_span.c", "ato_motion.c", "ato_stopping.c", "ato_planner.c", "repr.c"]
DEFAULT_SCENARIOS = ("ato_nominal", "ato_mass_plus20", "ato_speed_noise", "ato_line")
D = ctypes.POINTER(ctypes.c_double)


def build_shim(directory: Path):
    so = directory / "libato_plan.so"
    subprocess.run([shutil.which("gcc") or "gcc", "-std=c99", "-O2", "-ffp-contract=off", "-fPIC",
                    "-shared", f"-I{CORE}", str(SHIM), *(str(CORE / s) for s in SOURCES), "-o",
                    str(so), "-lm"], check=True)
    lib = ctypes.CDLL(str(so))
    ci, vp = ctypes.c_int, ctypes.c_void_p
    lib.shim_new.restype = vp
    lib.shim_new.argtypes = [D, D, D, ci, D, D, ci, D, D, ci, ci, ctypes.POINTER(ci), ctypes.c_char_p]
    lib.shim_free.argtypes = [vp]
    lib.shim_set_car.argtypes = [vp, D]
    lib.shim_plan.argtypes = [vp, ctypes.c_double, ctypes.c_double, ctypes.c_double,
                              ctypes.c_double, D, D]
    return lib


def arr(values):
    values = [float(x) for x in values]
    return (ctypes.c_double * max(len(values), 1))(*values)


def record(names) -> list:
    """[(span, car, tuning, [(PlanCar, s0, v0, t0, arrival, qU or None), ...]), ...]: each
    controller's plan calls, in order, over the scenarios' runs."""
    calls: dict[int, list] = {}
    owners: dict[int, ReducedPlanner] = {}
    original = ReducedPlanner.plan

    def spy(self, car, s0, v0, t0, arrival, qU=None):
        calls.setdefault(id(self), []).append((car, s0, v0, t0, arrival, qU))
        owners[id(self)] = self
        return original(self, car, s0, v0, t0, arrival, qU)

    out = []
    ReducedPlanner.plan = spy
    try:
        for name in names:
            scenario = load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml")
            setup = scenario.ato_setup()
            calls.clear()
            owners.clear()
            run_on_chain(scenario)
            for key, seq in calls.items():
                span = owners[key].c.span
                match = [ls for ls in setup.spans if ls.span == span]
                out.append((f"{name}:{setup.spans.index(match[0])}", span, setup.car,
                            setup.tuning, seq))
    finally:
        ReducedPlanner.plan = original
    return out


def percentile(values, q: float) -> float:
    v = sorted(values)
    return v[min(len(v) - 1, int(round(q * (len(v) - 1))))]


def replay(lib, span, car, tuning, seq, repeat: int):
    """Per-call times [s] in Python and in C, and the number of plans that agree bit for bit."""
    t_py, t_c, agree = [], [], 0
    status, msg = ctypes.c_int(), ctypes.create_string_buffer(512)
    tn = [tuning.grid_step, tuning.limit_margin, tuning.time_tol, tuning.a_ep, tuning.ep_stages,
          tuning.mass_reserve, tuning.brake_share]
    carv = [getattr(car, f.name) for f in fields(CarTraction) if f.init]
    handles = []
    planners = []
    for _ in range(repeat):
        h = lib.shim_new(arr([span.length, span.schedule, span.stop]), arr(span.grade.distances),
                         arr(span.grade.grades), len(span.grade.grades), arr(span.limit_distances),
                         arr(span.limit_speeds), len(span.limit_speeds), arr(carv), arr(tn), 10_003,
                         1, ctypes.byref(status), msg)
        assert h, msg.value.decode()
        handles.append(h)
        planners.append(plan_setup(span, car, tuning)[1])
    out = arr([0.0] * 15)
    try:
        for pc, s0, v0, t0, arrival, qU in seq:
            pc_vec = arr([pc.mass, pc.A0, pc.A1, pc.A2, pc.share, pc.brake_mass])
            qU_c = None if qU is None else arr(qU)
            best_py = best_c = float("inf")
            plan = None
            for planner, h in zip(planners, handles):      # each copy in the same state
                tic = time.perf_counter()
                try:
                    plan = planner.plan(pc, s0, v0, t0, arrival, qU)
                except ValueError:
                    plan = None
                best_py = min(best_py, time.perf_counter() - tic)
                lib.shim_set_car(h, pc_vec)
                tic = time.perf_counter()
                rc = lib.shim_plan(h, s0, v0, t0, arrival, qU_c, out)
                best_c = min(best_c, time.perf_counter() - tic)
            t_py.append(best_py)
            t_c.append(best_c)
            if plan is None:
                agree += rc != 0
            else:
                agree += (rc == 0 and out[2] == plan.arrival and out[0] == plan.hold_speed
                          and out[3] == plan.energy_kwh)
    finally:
        for h in handles:
            lib.shim_free(h)
    return t_py, t_c, agree


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", nargs="+", default=list(DEFAULT_SCENARIOS))
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        lib = build_shim(Path(tmp))
        recorded = record(args.scenarios)
        all_py, all_c, total, agree_all = [], [], 0, 0
        print(f"{'span':24s} {'plans':>6s} {'Python median/p99 [ms]':>24s} {'C median/p99 [ms]':>20s}"
              f" {'C/Python median':>16s} {'p99':>6s} {'bit-identical':>14s}")
        for name, span, car, tuning, seq in recorded:
            t_py, t_c, agree = replay(lib, span, car, tuning, seq, args.repeat)
            all_py += t_py
            all_c += t_c
            total += len(seq)
            agree_all += agree
            mp, pp = statistics.median(t_py), percentile(t_py, 0.99)
            mc, pc_ = statistics.median(t_c), percentile(t_c, 0.99)
            print(f"{name:24s} {len(seq):6d} {1e3 * mp:11.3f} / {1e3 * pp:9.3f} "
                  f"{1e3 * mc:9.4f} / {1e3 * pc_:8.4f} {100 * mc / mp:15.2f}% "
                  f"{100 * pc_ / pp:5.2f}% {agree:6d} / {len(seq)}")
    mp, pp = statistics.median(all_py), percentile(all_py, 0.99)
    mc, pc_ = statistics.median(all_c), percentile(all_c, 0.99)
    ratio_m, ratio_p = mc / mp, pc_ / pp
    print(f"{'all':24s} {total:6d} {1e3 * mp:11.3f} / {1e3 * pp:9.3f} {1e3 * mc:9.4f} / "
          f"{1e3 * pc_:8.4f} {100 * ratio_m:15.2f}% {100 * ratio_p:5.2f}% {agree_all:6d} / {total}")
    verdict = "met" if max(ratio_m, ratio_p) <= 0.05 else "NOT met"
    print(f"re-plan time C / Python: median {100 * ratio_m:.2f} %, 99th percentile "
          f"{100 * ratio_p:.2f} % (issue 30's target <= 5 %: {verdict}); "
          f"{agree_all} of {total} plans bit-identical")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
