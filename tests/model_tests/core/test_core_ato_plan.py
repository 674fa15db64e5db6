"""The C re-planner (models/core/ato_{span,motion,stopping,planner}.c) against models/ato/planner.py,
motion.py, stopping.py and models/planning/span.py, bit for bit (issue 30).

The C pieces are driven through tests/core_cases/ato_plan_shim.c (ctypes). The courses are the
library's ATO scenarios' spans and cars (scenarios/library/ato_*.toml, as
harness/run/span_scenario.py builds them) plus two variants that reach what those leave out (a car
with a length, over which the grade is averaged, and a rotating-mass factor; a wider speed
margin and a finer grid). Compared by their bits:

- the course (nodes, cell grades, planning limits, the EP curve's node), the envelope qU and
  min_time for the configured car and for random PlanCars (mass, A0..A2, braking mass);
- plan() from a sequence of states along and off the planned run (s0, v0, t0, arrival, PlanCar)
  on one planner per course, so that the warm starts (last V_c and its slope, last cap, the coast
  hints) are exercised as the controller exercises them: every scalar of the ReducedPlan, its
  s, v, t, mode, qU and coasts, speed_at at random distances, and the planner's state after it
  (coast_runs, last V_c, its slope, last cap); the statuses ok/late/early and both policies met;
- ValueError messages word for word (the course's, the envelope's, check_span_for_car's);
- PlanCar's methods, accel, free_step, coast_step, hold_forces, step_time, Trace.cut_at, q_at,
  blend_estimates, heavier_mass, braking_mass, resistance_margins over random inputs; the span
  and CarTraction lookups; RelayBrake.command sequences of a simulated stop; ep_deceleration;
- a one-ulp mutation of a planner expression makes the plan comparison fail, and the shim built
  with -fsanitize=address,undefined runs a plan sequence without a report.
"""
from __future__ import annotations

import ctypes
import math
import os
import random
import shutil
import subprocess
import sys
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import pytest

from harness.run.scenario import load_scenario
from models.ato.interface import AtoTuning
from models.ato.motion import (
    PlanCar, Trace, accel, blend_estimates, braking_mass, coast_step, free_step, heavier_mass,
    hold_forces, q_at, resistance_margins, step_time,
)
from models.ato.planner import ReducedCourse, ReducedPlanner, fastest_run, plan_setup
from models.ato.stopping import RelayBrake, ep_deceleration, track_force
from models.planning.span import CarTraction, Span, check_span_for_car

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_plan_shim.c"
SOURCES = ["ato_span.c", "track.c", "ato_motion.c", "ato_stopping.c", "ato_planner.c", "repr.c"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]
MAX_NODES = 10_003          # models.ato.controller.MAX_GRID_NODES + 3 (ato_planner.h)
D = ctypes.POINTER(ctypes.c_double)
CAR_FIELDS = [f.name for f in fields(CarTraction) if f.init]
STATUS = {0: "ok", 1: "late", 2: "early"}
POLICY = {0: "energy", 1: "capped"}


def build(directory: Path, sources_dir: Path = CORE, extra=()) -> Path:
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    so = directory / "libato_plan.so"
    proc = subprocess.run([gcc, *FLAGS, *extra, "-fPIC", "-shared", f"-I{sources_dir}", str(SHIM),
                           *(str(sources_dir / s) for s in SOURCES), "-o", str(so), "-lm"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    return so


def load(so: Path):
    dll = ctypes.CDLL(str(so))
    vp, ci = ctypes.c_void_p, ctypes.c_int
    dll.shim_new.restype = vp
    dll.shim_new.argtypes = [D, D, D, ci, D, D, ci, D, D, ci, ci, ctypes.POINTER(ci), ctypes.c_char_p]
    dll.shim_free.argtypes = [vp]
    dll.shim_msg.argtypes = [vp]
    dll.shim_msg.restype = ctypes.c_char_p
    dll.shim_course.argtypes = [vp, D, D, D, D, ci]
    dll.shim_set_car.argtypes = [vp, D]
    dll.shim_envelope.argtypes = [vp, D]
    dll.shim_min_time.argtypes = [vp, D, D]
    dll.shim_plan.argtypes = [vp, ctypes.c_double, ctypes.c_double, ctypes.c_double,
                              ctypes.c_double, D, D]
    dll.shim_plan_arrays.argtypes = [vp, D, D, D, D, D, D]
    dll.shim_speed_at.argtypes = [vp, ctypes.c_double]
    dll.shim_speed_at.restype = ctypes.c_double
    dll.shim_span_lookups.argtypes = [vp, D, ci, D]
    dll.shim_breakpoints.argtypes = [vp, ctypes.c_double, D, ci]
    dll.shim_check_span.argtypes = [vp]
    dll.shim_ep_deceleration.argtypes = [vp, ctypes.c_double, ci, ctypes.c_double, ctypes.c_double]
    dll.shim_ep_deceleration.restype = ctypes.c_double
    dll.shim_plancar.argtypes = [vp, ctypes.c_double, ctypes.c_double, D]
    dll.shim_steps.argtypes = [vp] + [ctypes.c_double] * 6 + [D]
    dll.shim_blend.argtypes = [D, D, D, D, D, ci, D]
    dll.shim_masses.argtypes = [D, D]
    dll.shim_margins.argtypes = [ctypes.c_double] * 5 + [D]
    dll.shim_trace_cut.argtypes = [D, D, D, D, D, D, ci, ctypes.c_double, D, ctypes.POINTER(ci)]
    dll.shim_trace_cut.restype = ctypes.c_double
    dll.shim_relay_new.argtypes = [D]
    dll.shim_relay_new.restype = vp
    dll.shim_relay_free.argtypes = [vp]
    dll.shim_relay_command.argtypes = [vp, vp] + [ctypes.c_double] * 4 + [D, ctypes.c_char_p]
    dll.shim_track_force.argtypes = [vp] + [ctypes.c_double] * 5
    dll.shim_track_force.restype = ctypes.c_double
    dll.shim_course_error.argtypes = [vp] + [ctypes.c_double] * 4 + [ctypes.c_char_p]
    return dll


def arr(values, n=None):
    values = [float(x) for x in values]
    if n is not None:
        values += [0.0] * (n - len(values))
    return (ctypes.c_double * max(len(values), 1))(*values)


def bits(values) -> list:
    return [int(x) for x in np.array([float(v) for v in values], dtype=float).view(np.uint64)]


def same(a, b) -> bool:
    """Equal bit for bit (lists or scalars; NaN equals NaN of the same bits)."""
    if not isinstance(a, (list, tuple)):
        a, b = [a], [b]
    return len(a) == len(b) and bits(a) == bits(b)


def tuning_vector(tn: AtoTuning) -> list:
    return [tn.grid_step, tn.limit_margin, tn.time_tol, tn.a_ep, tn.ep_stages, tn.mass_reserve,
            tn.brake_share]


class CPlanner:
    """The C span, car, course and planner of plan_setup(span, car, tuning) (setup=False: the span
    and the car only)."""

    def __init__(self, lib, span: Span, car: CarTraction, tuning: AtoTuning, setup: bool = True):
        self.lib = lib
        status, msg = ctypes.c_int(), ctypes.create_string_buffer(512)
        self.h = lib.shim_new(arr([span.length, span.schedule, span.stop]), arr(span.grade.distances),
                              arr(span.grade.grades), len(span.grade.grades), arr(span.limit_distances),
                              arr(span.limit_speeds), len(span.limit_speeds),
                              arr([getattr(car, f) for f in CAR_FIELDS]), arr(tuning_vector(tuning)),
                              MAX_NODES, int(setup), ctypes.byref(status), msg)
        self.status, self.msg = status.value, msg.value.decode()
        self.n = 0
        if self.h and setup:
            self.n = self.course()[0]
            self.set_car(None)

    def close(self):
        if self.h:
            self.lib.shim_free(self.h)
            self.h = None

    def error(self) -> str:
        return self.lib.shim_msg(self.h).decode()

    def course(self, cap=MAX_NODES + 10):
        s, g, q, sc = arr([], cap), arr([], cap), arr([], cap), arr([], 3)
        n = self.lib.shim_course(self.h, s, g, q, sc, cap)
        return n, list(s[:n]), list(g[:n - 1]), list(q[:n]), list(sc)

    def set_car(self, pc: PlanCar | None):
        self.lib.shim_set_car(self.h, None if pc is None else arr(
            [pc.mass, pc.A0, pc.A1, pc.A2, pc.share, pc.brake_mass]))

    def envelope(self):
        qU = arr([], self.n)
        rc = self.lib.shim_envelope(self.h, qU)
        return rc, list(qU)

    def min_time(self, qU=None):
        t = arr([0.0])
        rc = self.lib.shim_min_time(self.h, None if qU is None else arr(qU), t)
        return rc, t[0]

    def plan(self, s0, v0, t0, arrival, qU=None):
        out = arr([], 15)
        rc = self.lib.shim_plan(self.h, s0, v0, t0, arrival, None if qU is None else arr(qU), out)
        sc = list(out)
        if rc != 0:
            return rc, sc, None
        n, nc = int(sc[9]), int(sc[10])
        s, v, t, q, m, c = (arr([], n), arr([], n), arr([], n), arr([], self.n), arr([], n),
                            arr([], 2 * nc + 2))
        self.lib.shim_plan_arrays(self.h, s, v, t, q, m, c)
        arrays = dict(s=list(s), v=list(v), t=list(t), qU=list(q), mode=[int(x) for x in m[:n - 1]],
                      coasts=[(c[2 * k], c[2 * k + 1]) for k in range(nc)])
        return rc, sc, arrays

    def speed_at(self, x):
        return self.lib.shim_speed_at(self.h, x)


def courses():
    """(name, span, car, tuning): the library's ATO spans and cars, distinct, plus two variants."""
    out, seen = [], set()
    for path in sorted((ROOT / "scenarios" / "library").glob("ato_*.toml")):
        setup = load_scenario(path).ato_setup()
        for k, ls in enumerate(setup.spans):
            key = (ls.span, setup.car, setup.tuning)
            if key not in seen:
                seen.add(key)
                out.append((f"{path.stem}[{k}]", ls.span, setup.car, setup.tuning))
    _, span, car, tuning = out[0]
    out.append(("long_car", span, replace(car, length=25.0, gamma=0.08, mass=34.0), tuning))
    out.append(("margin_fine_grid", span, car, replace(tuning, limit_margin=1.5, grid_step=4.0)))
    return out


COURSES = courses()
PLANS_PER_COURSE = 40


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    return load(build(tmp_path_factory.mktemp("ato_plan")))


def random_plancar(rng: random.Random, car: CarTraction, tuning: AtoTuning) -> PlanCar:
    mass = car.mass * rng.uniform(0.8, 1.45)
    A0 = car.A0 * rng.uniform(0.5, 1.6)
    A1 = car.A1 * rng.uniform(0.3, 2.0)
    A2 = car.A2 * rng.uniform(0.6, 1.5)
    brake = braking_mass(mass, car.mass) if rng.random() < 0.7 else mass
    return PlanCar(car, mass, A0, A1, A2, tuning.brake_share, brake_mass=brake)


# ---------------------------------------------------------------- course, envelope, min_time

@pytest.mark.parametrize("name, span, car, tuning", COURSES, ids=[c[0] for c in COURSES])
def test_course_envelope_and_min_time_are_python_s(lib, name, span, car, tuning):
    course, planner, configured = plan_setup(span, car, tuning)
    cp = CPlanner(lib, span, car, tuning)
    try:
        assert cp.status == 0, cp.msg
        n, s, g, qlim, scalars = cp.course()
        assert n == course.n
        assert same(s, course.s) and same(g, course.g) and same(qlim, course.qlim)
        assert same(scalars, [course.d_relay, course.a_ep, course.i_relay])
        rng = random.Random(hash(name) % 1000)
        cars = [configured] + [random_plancar(rng, car, tuning) for _ in range(12)]
        for pc in cars:
            cp.set_car(pc)
            qU = planner.envelope(pc)
            rc, cq = cp.envelope()
            assert rc == 0 and same(cq, qU)
            rc, t_min = cp.min_time()
            assert rc == 0 and same(t_min, planner.min_time(pc, qU))
            rc, t_given = cp.min_time(qU)
            assert rc == 0 and same(t_given, t_min)
    finally:
        cp.close()


def test_fastest_run_through_plan_setup(lib):
    """min_time of the configured car from plan_setup's course (fastest_run's number)."""
    for _, span, car, tuning in COURSES:
        cp = CPlanner(lib, span, car, tuning)
        try:
            assert same(cp.min_time()[1], fastest_run(span, car, tuning))
        finally:
            cp.close()


# ---------------------------------------------------------------- plan()

def compare_plan(cp: CPlanner, planner: ReducedPlanner, pc: PlanCar, state, rng):
    """(the differences between the Python and the C plan from ``state`` (empty: bit-identical),
    (status, policy) or the error)."""
    s0, v0, t0, arrival = state
    try:
        p = planner.plan(pc, s0, v0, t0, arrival)
        py_err = None
    except ValueError as e:
        p, py_err = None, str(e)
    rc, sc, a = cp.plan(s0, v0, t0, arrival)
    if py_err is not None:
        ok = rc != 0 and cp.error() == py_err
        return ([] if ok else [f"error: {py_err!r} vs rc {rc} {cp.error()!r}"]), ("error", py_err)
    if rc != 0:
        return [f"C failed: {cp.error()}"], None
    bad = []
    want = [p.hold_speed, p.regen_speed, p.arrival, p.energy_kwh, p.traction_kwh, p.regen_kwh]
    if not same(sc[:6], want):
        bad.append(f"scalars {sc[:6]} vs {want}")
    if (STATUS[int(sc[6])], int(sc[7]), POLICY[int(sc[8])]) != (p.status, p.trials, p.policy):
        bad.append(f"status {sc[6:9]} vs {(p.status, p.trials, p.policy)}")
    for key in ("s", "v", "t", "qU"):
        if not same(a[key], getattr(p, key)):
            bad.append(key)
    if a["mode"] != list(p.mode):
        bad.append("mode")
    if not same([x for c in a["coasts"] for x in c], [x for c in p.coasts for x in c]):
        bad.append("coasts")
    xs = [rng.uniform(-10.0, p.s[-1] + 10.0) for _ in range(5)] + [p.s[0], p.s[-1]]
    if not same([cp.speed_at(x) for x in xs], [p.speed_at(x) for x in xs]):
        bad.append("speed_at")
    none = float("nan")
    state_py = [planner.coast_runs, none if planner._last_vc is None else planner._last_vc,
                none if planner._vc_slope is None else planner._vc_slope,
                none if planner._last_cap is None else planner._last_cap]
    if not same(sc[11:15], state_py):
        bad.append(f"planner state {sc[11:15]} vs {state_py}")
    return bad, (p.status, p.policy)


def plan_states(rng: random.Random, span: Span, reference, n: int):
    """States for re-plans: along the reference plan with speed, position and time errors, a
    schedule that moves (the controller's reserve), some far too early/late, some off the plan."""
    for k in range(n):
        x = rng.uniform(0.0, span.stop * 0.97) if k else 0.0
        v = max(reference.speed_at(x) * rng.uniform(0.8, 1.2) + rng.uniform(-1.0, 1.0), 0.0)
        if k == 0:
            v = 0.0
        i = max(0, min(len(reference.s) - 2, np.searchsorted(reference.s, x) - 1))
        t = reference.t[i] + rng.uniform(-8.0, 8.0) if k else 0.0
        r = rng.random()
        if r < 0.1:
            arrival = t + rng.uniform(1.0, 20.0)               # late: far too little time
        elif r < 0.2:
            arrival = t + 1.5 * (span.stop - x) + rng.uniform(100.0, 400.0)   # early: slower
            #                                          than holding v_min = 1 m/s all the way
        else:
            arrival = span.schedule - rng.uniform(0.0, 6.0)
        yield x, v, max(t, 0.0), arrival


@pytest.mark.parametrize("name, span, car, tuning", COURSES, ids=[c[0] for c in COURSES])
def test_plan_is_python_s_bit_for_bit(lib, name, span, car, tuning):
    course, planner, configured = plan_setup(span, car, tuning)
    reference = planner.plan(configured, 0.0, 0.0, 0.0, span.schedule)
    planner = ReducedPlanner(course, tol=tuning.time_tol)          # fresh: both start alike
    cp = CPlanner(lib, span, car, tuning)
    rng = random.Random(7 + len(name))
    met = set()
    try:
        pc = configured
        for k, state in enumerate(plan_states(rng, span, reference, PLANS_PER_COURSE)):
            if k % 5 == 4:                    # a new identified car now and then, as the controller
                pc = random_plancar(rng, car, tuning)
            cp.set_car(pc)
            bad, what = compare_plan(cp, planner, pc, state, rng)
            assert not bad, f"{name} state {k} {state}: {bad}"
            met.add(what)
    finally:
        cp.close()
    # the states reach both policies and the fallback's statuses on every course
    assert {("ok", "energy"), ("late", "capped"), ("early", "capped")} <= met, met


def test_plan_meets_every_status_and_policy(lib):
    """The sequences above, counted: ok/late/early, energy/capped all compared (nominal span)."""
    _, span, car, tuning = COURSES[0]
    course, planner, configured = plan_setup(span, car, tuning)
    cp = CPlanner(lib, span, car, tuning)
    met = set()
    rng = random.Random(3)
    try:
        states = [(0.0, 0.0, 0.0, span.schedule), (0.0, 0.0, 0.0, 60.0), (0.0, 0.0, 0.0, 4e3),
                  (900.0, 14.0, 60.0, 80.0), (1500.0, 18.0, 75.0, 200.0), (2100.0, 6.0, 130.0, 133.0),
                  (300.0, 12.0, 25.0, 135.0), (0.0, 0.0, 0.0, 150.0), (1200.0, 16.0, 70.0, 120.0)]
        for st in states:
            bad, what = compare_plan(cp, planner, configured, st, rng)
            assert not bad, f"{st}: {bad}"
            met.add(what)
    finally:
        cp.close()
    assert {("ok", "energy"), ("late", "capped"), ("early", "capped")} <= met, met


# ---------------------------------------------------------------- errors, word for word

def _span(**kw) -> Span:
    _, span, _, _ = COURSES[0]
    args = dict(length=span.length, schedule=span.schedule, stop=span.stop, grade=span.grade,
                limit_distances=span.limit_distances, limit_speeds=span.limit_speeds)
    args.update(kw)
    return Span(**args)


def _python_error(fn) -> str:
    with pytest.raises(ValueError) as e:
        fn()
    return str(e.value)


@pytest.mark.parametrize("case", ["step", "a_ep", "margin", "v_relay", "limit", "stop"])
def test_course_errors_are_python_s(lib, case):
    _, span, car, tuning = COURSES[0]
    kw = dict(step=tuning.grid_step, limit_margin=tuning.limit_margin,
              v_relay=car.regen_fade_speed, a_ep=0.6)
    if case == "step":
        kw["step"] = -0.25
    elif case == "a_ep":
        kw["a_ep"] = float("inf")
    elif case == "margin":
        kw["limit_margin"] = -1e-7
    elif case == "v_relay":
        kw["v_relay"] = float("nan")
    elif case == "limit":
        kw["limit_margin"] = 15.123456789
    else:
        span = _span(stop=3.125, length=10.0, limit_distances=(0.0,), limit_speeds=(20.0,))
    want = _python_error(lambda: ReducedCourse(span, car, **kw))
    cp = CPlanner(lib, span, car, tuning, setup=False)
    try:
        msg = ctypes.create_string_buffer(512)
        rc = lib.shim_course_error(cp.h, kw["step"], kw["limit_margin"], kw["v_relay"], kw["a_ep"],
                                   msg)
    finally:
        cp.close()
    assert rc != 0 and msg.value.decode() == want


def test_envelope_and_plan_errors_are_python_s(lib):
    """A service brake too weak for the descent: envelope's ValueError, also through plan()."""
    _, span, car, tuning = COURSES[0]
    span = _span(grade=type(span.grade)((0.0, 1000.0), (0.0, -39.0)))
    course, planner, configured = plan_setup(span, car, tuning)
    weak = PlanCar(car, 30.0, car.A0, car.A1, car.A2, 0.02, brake_mass=41.5)
    want = _python_error(lambda: planner.envelope(weak))
    cp = CPlanner(lib, span, car, tuning)
    try:
        cp.set_car(weak)
        rc, _ = cp.envelope()
        assert rc != 0 and cp.error() == want
        rc, _, _ = cp.plan(100.0, 10.0, 10.0, 130.0)
        assert rc != 0 and cp.error() == _python_error(
            lambda: planner.plan(weak, 100.0, 10.0, 10.0, 130.0))
    finally:
        cp.close()


@pytest.mark.parametrize("case", ["start", "limit", "ok"])
def test_check_span_for_car_is_python_s(lib, case):
    _, span, car, _ = COURSES[0]
    if case == "start":
        car = replace(car, traction_force_max=200.0)
    elif case == "limit":
        span = _span(grade=type(span.grade)((0.0, 500.0), (0.0, -38.5)))
        car = replace(car, brake_force_max=5e3, mech_force_max=1e3)
    cp = CPlanner(lib, span, car, AtoTuning(), setup=False)
    try:
        rc = lib.shim_check_span(cp.h)
        if case == "ok":
            check_span_for_car(span, car)
            assert rc == 0
        else:
            assert rc != 0 and cp.error() == _python_error(lambda: check_span_for_car(span, car))
    finally:
        cp.close()


# ---------------------------------------------------------------- the span, the car, motion

def test_span_and_car_lookups_are_python_s(lib):
    rng = random.Random(11)
    for name, span, car, _ in COURSES:
        for length in (0.0, 17.5):
            car_l = replace(car, length=length, regen_off_speed=car.regen_off_speed * (length > 0))
            cp = CPlanner(lib, span, car_l, AtoTuning(), setup=False)
            try:
                xs = [rng.uniform(-50.0, span.length + 50.0) for _ in range(200)]
                xs += list(span.limit_distances) + list(span.grade.distances) + [0.0, 1e-12,
                                                                                  car.regen_fade_speed]
                out = arr([], 10 * len(xs))
                lib.shim_span_lookups(cp.h, arr(xs), len(xs), out)
                want = []
                for x in xs:
                    want += [span.grade.at(x), span.grade.average(x, car_l.length), span.v_lim(x),
                             span.v_lim_at_node(x), car_l.f_max(x), car_l.r_max(x),
                             car_l.brake_total_max(x), *car_l.service_brake(x),
                             car_l.hold_speed_regen(x) if x > 0.0 else math.nan]
                got = list(out)
                for k, x in enumerate(xs):      # V_hold <= 0 is outside hold_speed_regen's domain
                    got[10 * k + 9] = got[10 * k + 9] if x > 0.0 else math.nan
                assert same(got, want), name
                bp = arr([], 400)
                n = lib.shim_breakpoints(cp.h, length, bp, 400)
                assert same(list(bp[:n]), span.breakpoints(length))
            finally:
                cp.close()


def test_plancar_and_steps_are_python_s(lib):
    rng = random.Random(5)
    _, span, car, tuning = COURSES[0]
    cp = CPlanner(lib, span, replace(car, gamma=0.06), tuning)
    car = replace(car, gamma=0.06)
    try:
        for _ in range(300):
            pc = random_plancar(rng, car, tuning)
            if rng.random() < 0.2:
                pc = PlanCar(car, pc.mass, pc.A0, rng.choice([0.0, -0.01, pc.A1]),
                             rng.choice([0.0, -1e-3, pc.A2]), rng.uniform(0.3, 1.0))
            cp.set_car(pc)
            v = rng.choice([0.0, rng.uniform(0.0, 2.0), rng.uniform(0.0, 35.0), 1.9444444444444444])
            g = rng.uniform(-40.0, 40.0)
            out = arr([], 10)
            lib.shim_plancar(cp.h, v, g, out)
            # hold_regen_speed(0) divides 0 by 0 in Python (ZeroDivisionError): the planner asks
            # for V_c >= v_min only
            want = [pc.adhesion(v), pc.f_max(v), pc.r_full(v), pc.b_service(v), pc.w0(v),
                    pc.w_slope(v), pc.hold_regen_speed(v) if v > 0.0 else math.nan,
                    *(accel(pc, v, g, k) for k in range(3))]
            got = list(out)
            got[6] = got[6] if v > 0.0 else math.nan
            assert same(got, want)
            q0, q1 = rng.uniform(0.0, 600.0), rng.uniform(-5.0, 600.0)
            if rng.random() < 0.1:
                q0 = 0.0
            p0, h = rng.uniform(0.5, 1.5), rng.choice([rng.uniform(0.1, 12.0), -rng.uniform(0.1, 12.0)])
            k_lam = rng.uniform(0.0, 1e5)
            out = arr([], 13)
            lib.shim_steps(cp.h, q0, q1, p0, h, g, k_lam, out)
            want = []
            for k in range(3):
                want += list(free_step(pc, q0, h, g, k))
            want += list(coast_step(pc, q0, p0, h, g, k_lam))
            F, R, M, ok = hold_forces(pc, q0, q1, abs(h), g)
            want += [F, R, M, float(ok), step_time(h, q0, q1)]
            lib.shim_steps(cp.h, q0, q1, p0, h, g, k_lam, out)
            # hold_forces is called with |h| in Python above: the shim's with h; redo for |h|
            out2 = arr([], 13)
            lib.shim_steps(cp.h, q0, q1, p0, abs(h), g, k_lam, out2)
            assert same(list(out)[:8], want[:8])
            assert same(list(out2)[8:12], want[8:12])
            assert same(out[12], want[12])
            v_ref, a_ref, gain = rng.uniform(0, 30), rng.uniform(-1, 1), rng.uniform(0, 2)
            assert same(lib.shim_track_force(cp.h, v, v_ref, a_ref, g, gain),
                        track_force(pc, v, v_ref, a_ref, g, gain))
    finally:
        cp.close()


def test_trace_cut_and_q_at_are_python_s(lib):
    rng = random.Random(9)
    for _ in range(200):
        n = rng.randint(1, 12)
        s = sorted(rng.uniform(0.0, 1000.0) for _ in range(n))
        tr = Trace(s[0], rng.uniform(0.0, 500.0), rng.uniform(0.0, 10.0))
        for x in s[1:]:
            tr.add(x, rng.uniform(0.0, 500.0), rng.uniform(0.1, 5.0), rng.randint(0, 6),
                   rng.uniform(0.0, 1e5), rng.uniform(0.0, 1e5))
        x = rng.choice([rng.uniform(-10.0, 1010.0), s[rng.randrange(n)],
                        s[rng.randrange(n)] + 5e-10])
        out = arr([], 6 * (n + 2))
        n_out = ctypes.c_int()
        qa = lib.shim_trace_cut(arr(tr.s), arr(tr.q), arr(tr.t), arr(tr.wF + [0.0]),
                                arr(tr.wR + [0.0]), arr(tr.mode + [0]), n, x, out,
                                ctypes.byref(n_out))
        cut = tr.cut_at(x)
        assert same(qa, q_at(tr, x))
        m = n_out.value
        assert m == len(cut.s)
        rows = [out[6 * k:6 * k + 6] for k in range(m)]
        assert same([r[0] for r in rows], cut.s) and same([r[1] for r in rows], cut.q)
        assert same([r[2] for r in rows], cut.t)
        assert [int(r[3]) for r in rows[:m - 1]] == cut.mode
        assert same([r[4] for r in rows[:m - 1]], cut.wF) and same([r[5] for r in rows[:m - 1]], cut.wR)


def test_blend_and_masses_are_python_s(lib):
    rng = random.Random(13)
    for k in range(2000):
        cfg = (rng.uniform(25, 40), rng.uniform(0.5, 1.5), rng.uniform(0.0, 0.05), rng.uniform(0.005, 0.02))
        est = (cfg[0] * rng.uniform(0.7, 1.5), cfg[1] * rng.uniform(-1.0, 3.0),
               cfg[2] * rng.uniform(-3.0, 3.0), cfg[3] * rng.uniform(-1.0, 3.0))
        stated = [rng.uniform(-0.1, 5.0), rng.uniform(-0.02, 0.5), rng.uniform(-0.002, 0.05),
                  rng.uniform(-1e-4, 2e-3), rng.uniform(-0.01, 0.01), rng.uniform(-1e-3, 1e-3),
                  rng.uniform(-1e-4, 1e-4)]
        speeds = sorted(rng.uniform(1.0, 25.0) for _ in range(rng.randint(1, 6)))
        ramp = rng.choice([0.0, 1.0, rng.uniform(-0.2, 1.0)])
        args = [ramp, rng.uniform(0.5, 5.0), rng.uniform(0.05, 0.5), rng.uniform(1.5, 4.0),
                rng.uniform(1.1, 2.0), rng.uniform(0.0, 1.0), rng.choice([math.inf, rng.uniform(0, 0.3)])]
        out = arr([], 8)
        lib.shim_blend(arr(cfg), arr(est), arr(stated), arr(args), arr(speeds), len(speeds), out)
        want = blend_estimates(cfg, est, stated, args[0], args[1], args[2], args[3], speeds,
                               args[4], args[5], args[6])
        assert same(list(out), list(want)), k
        margins = arr([], 3)
        lib.shim_margins(*est[1:], speeds[0], speeds[-1], margins)
        assert same(list(margins), list(resistance_marginsof(est, speeds)))
        m_args = [rng.uniform(20, 50), rng.choice([rng.uniform(20, 60), math.inf, math.nan]),
                  rng.randint(0, 1), cfg[0], rng.uniform(1.1, 2.0)]
        out = arr([], 2)
        lib.shim_masses(arr(m_args), out)
        assert same(list(out), [heavier_mass(m_args[0], m_args[1], bool(m_args[2]), m_args[3], m_args[4]),
                                braking_mass(m_args[0], m_args[3])])


def resistance_marginsof(est, speeds):
    return resistance_margins(est[1], est[2], est[3], speeds[0], speeds[-1])


# ---------------------------------------------------------------- stopping

def test_relay_command_sequences_are_python_s(lib):
    """A car braking to the stop mark under the relay (its own simple motion), with speed noise,
    a coming-in above / below the programmed curve, standing short and creeping: every command's
    outputs and the relay's a_prog and creep integral compared by their bits."""
    _, span, car, tuning = COURSES[0]
    cp = CPlanner(lib, span, car, tuning)
    rng = random.Random(17)
    stages = set()
    try:
        for run in range(40):
            pc = random_plancar(rng, car, tuning)
            cp.set_car(pc)
            stop = 500.0
            a_ep = ep_deceleration(car, tuning, rng.uniform(-30.0, 30.0))
            args = [stop, a_ep, car.mech_force_max / tuning.ep_stages, tuning.ep_stages,
                    tuning.relay_hysteresis, tuning.relay_stage_speed, tuning.relay_dwell,
                    tuning.creep_speed, tuning.creep_accel, tuning.stop_window]
            relay = RelayBrake(*args)
            cr = lib.shim_relay_new(arr(args))
            try:
                s = stop - rng.uniform(0.5, 4.0)
                v = math.sqrt(2.0 * a_ep * (stop - s)) * rng.uniform(0.5, 1.4)
                grade = rng.uniform(-30.0, 30.0)
                t = 0.0
                for k in range(400):
                    v_meas = max(v + rng.gauss(0.0, 0.02), 0.0)
                    want = relay.command(t, s, v_meas, pc, grade)
                    out, msg = arr([], 6), ctypes.create_string_buffer(256)
                    rc = lib.shim_relay_command(cr, cp.h, t, s, v_meas, grade, out, msg)
                    assert rc == 0
                    assert same(list(out), [*want[:2], float(want[2]), want[3], relay.a_prog,
                                            relay._creep_int]), (run, k)
                    stages.add(want[2])
                    F, B = want[0], want[1]
                    acc = (F - B) / pc.m_in - pc.pg * (pc.w0(v) + grade) / pc.m_in
                    v = max(v + 0.1 * acc, 0.0)
                    s += 0.1 * v
                    t += 0.1
            finally:
                lib.shim_relay_free(cr)
    finally:
        cp.close()
    assert {-1, 0, tuning.ep_stages} <= stages and len(stages) >= 5, stages   # creep, off, full


def test_relay_refuses_a_nan_stage_count_as_python(lib):
    _, span, car, tuning = COURSES[0]
    cp = CPlanner(lib, span, car, tuning)
    try:
        args = [500.0, 1.0, math.nan, 6, 0.03, 0.1, 0.3, 0.3, 0.2, 0.15]
        relay, cr = RelayBrake(*args), lib.shim_relay_new(arr(args))
        with pytest.raises(ValueError) as e:
            relay.command(0.0, 499.0, 1.0, plan_setup(span, car, tuning)[2], 0.0)
        out, msg = arr([], 6), ctypes.create_string_buffer(256)
        assert lib.shim_relay_command(cr, cp.h, 0.0, 499.0, 1.0, 0.0, out, msg) != 0
        assert msg.value.decode() == str(e.value)
        lib.shim_relay_free(cr)
    finally:
        cp.close()


def test_ep_deceleration_is_python_s(lib):
    rng = random.Random(19)
    _, span, car, tuning = COURSES[0]
    for _ in range(300):
        c = replace(car, mass=rng.uniform(20, 50), A0=rng.uniform(0.3, 2.0), gamma=rng.uniform(0, 0.1),
                    mech_force_max=rng.uniform(10e3, 80e3))
        tn = replace(tuning, a_ep=rng.uniform(0.3, 1.5), ep_stages=rng.randint(1, 12),
                     mass_reserve=rng.uniform(0.0, 0.5))
        grade = rng.uniform(-40.0, 40.0)
        cp = CPlanner(lib, span, c, tn, setup=False)
        try:
            assert same(lib.shim_ep_deceleration(cp.h, tn.a_ep, tn.ep_stages, tn.mass_reserve, grade),
                        ep_deceleration(c, tn, grade))
        finally:
            cp.close()


# ---------------------------------------------------------------- mutations and sanitizers

ONE_ULP = "(1.0 + 2.220446049250313e-16)"
MUTATIONS = {
    # the arrival error a V_c trial returns to the solve, one ulp off
    "trial_error": ("double y = stalled ? INFINITY : p->work->t[p->work->n - 1] - p->arrival;\n"
                    "    new_trial(p, v_c, y, stalled);\n    if (!p->has_best",
                    f"double y = stalled ? INFINITY : (p->work->t[p->work->n - 1] - p->arrival)"
                    f" * {ONE_ULP};\n    new_trial(p, v_c, y, stalled);\n    if (!p->has_best"),
    # the time of a held step, one operand one ulp off
    "held_step_time": ("o->dt = dt1 + rc_ato_step_time(rest, qx, bound);",
                       f"o->dt = dt1 + rc_ato_step_time(rest, qx, bound) * {ONE_ULP};"),
    # the envelope's backward braking step, its length one ulp off
    "envelope_step": ("qb = rc_ato_free_step(car, qU[i + 1], s[i] - s[i + 1], g[i], RC_ATO_K_BRAKE, &vm);",
                      f"qb = rc_ato_free_step(car, qU[i + 1], (s[i] - s[i + 1]) * {ONE_ULP}, g[i], "
                      f"RC_ATO_K_BRAKE, &vm);"),
}
# (one ulp in the work of a held step, in U between nodes or in a coast's co-state residual
# left every plan of the sequence bit-identical: absorbed by the sums, rare, or inside the
# coast point's 1e-4 tolerance; and the EP curve 2 a_ep (stop - s) re-associated is exact at
# a_ep = 1)


def plan_mismatches(lib, states=12) -> int:
    """How many of a plan sequence's plans (nominal course) differ from Python's."""
    _, span, car, tuning = COURSES[0]
    course, planner, configured = plan_setup(span, car, tuning)
    reference = planner.plan(configured, 0.0, 0.0, 0.0, span.schedule)
    planner = ReducedPlanner(course, tol=tuning.time_tol)
    cp = CPlanner(lib, span, car, tuning)
    rng = random.Random(23)
    bad = 0
    try:
        for state in plan_states(rng, span, reference, states):
            bad += bool(compare_plan(cp, planner, configured, state, rng)[0])
    finally:
        cp.close()
    return bad


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_a_one_ulp_mutation_of_the_planner_is_caught(mutation, tmp_path):
    target, replacement = MUTATIONS[mutation]
    for name in SOURCES + ["ato_span.h", "track.h", "ato_motion.h", "ato_stopping.h", "ato_planner.h",
                           "rc_common.h", "rc_fp_contract.h"]:
        shutil.copy(CORE / name, tmp_path / name)
    source = tmp_path / "ato_planner.c"
    text = source.read_text()
    assert text.count(target) == 1, f"the mutation's target occurs {text.count(target)} times"
    source.write_text(text.replace(target, replacement))
    assert plan_mismatches(load(build(tmp_path, tmp_path))) > 0


def test_the_unmutated_copy_matches(lib):
    assert plan_mismatches(lib) == 0


SANITIZED_RUN = r"""
import sys
sys.path.insert(0, {test_dir!r})
import test_core_ato_plan as t
lib = t.load(t.Path({so!r}))
t.test_envelope_and_plan_errors_are_python_s(lib)
for case in ("step", "limit", "stop"):
    t.test_course_errors_are_python_s(lib, case)
t.test_check_span_for_car_is_python_s(lib, "limit")
t.test_trace_cut_and_q_at_are_python_s(lib)
print("mismatches", t.plan_mismatches(lib, 8))
"""


def test_the_shim_under_address_and_undefined_sanitizers(tmp_path):
    """The shim built with -fsanitize=address,undefined runs a plan sequence bit-identically and
    the error paths (course, envelope, plan, check_span_for_car) and Trace.cut_at, with no
    sanitizer report on stderr."""
    asan = subprocess.run([shutil.which("gcc"), "-print-file-name=libasan.so"], capture_output=True,
                          text=True).stdout.strip()
    so = build(tmp_path, extra=["-g", "-O1", "-fsanitize=address,undefined",
                                "-fno-sanitize-recover=all"])
    env = dict(os.environ, LD_PRELOAD=asan, ASAN_OPTIONS="detect_leaks=0",
               PYTHONPATH=str(ROOT))
    proc = subprocess.run([sys.executable, "-c", SANITIZED_RUN.format(
        test_dir=str(Path(__file__).parent), so=str(so))], capture_output=True, text=True,
        env=env, timeout=600, cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "mismatches 0" in proc.stdout
    assert "runtime error" not in proc.stderr and "AddressSanitizer" not in proc.stderr, proc.stderr


# ---------------------------------------------------------------- the controller's own re-plans

def test_an_ato_run_s_replans_are_python_s(lib, monkeypatch):
    """Every plan() call the controller makes in a library ATO run under speed noise (the
    estimates move the PlanCar, the schedule's reserve moves the arrival) replayed in order on a
    fresh Python and a fresh C planner: every plan compared in full."""
    from harness.run.driver import run_on_chain

    scenario = load_scenario(ROOT / "scenarios" / "library" / "ato_speed_noise.toml")
    setup = scenario.ato_setup()
    calls = []
    original = ReducedPlanner.plan

    def spy(self, car, s0, v0, t0, arrival, qU=None):
        calls.append((car, s0, v0, t0, arrival))
        return original(self, car, s0, v0, t0, arrival, qU)

    monkeypatch.setattr(ReducedPlanner, "plan", spy)
    run_on_chain(scenario)
    monkeypatch.setattr(ReducedPlanner, "plan", original)
    assert len(calls) > 30 and len({c[0].mass for c in calls}) > 3     # the car moved
    span, car, tuning = setup.spans[0].span, setup.car, setup.tuning
    _, planner, _ = plan_setup(span, car, tuning)
    cp = CPlanner(lib, span, car, tuning)
    rng = random.Random(29)
    try:
        for k, (pc, *state) in enumerate(calls):
            cp.set_car(pc)
            bad, _ = compare_plan(cp, planner, pc, state, rng)
            assert not bad, f"call {k} {state}: {bad}"
    finally:
        cp.close()


def test_a_grid_beyond_the_node_limit_is_refused_before_allocation(lib):
    """C only (the controller refuses it first in Python): a step that puts 215,000 nodes on the
    grid is refused with its size; the library grids are far below the limit."""
    _, span, car, tuning = COURSES[0]
    cp = CPlanner(lib, span, car, tuning, setup=False)
    try:
        msg = ctypes.create_string_buffer(512)
        rc = lib.shim_course_error(cp.h, 0.01, tuning.limit_margin, car.regen_fade_speed, 0.6, msg)
        assert rc != 0
        assert msg.value.decode() == ("the re-planner's grid would have at least 2.15e+05 nodes "
                                      "(span.stop = 2150 m, step 0.01 m): at most 10000")
        assert lib.shim_course_error(cp.h, 0.25, tuning.limit_margin, car.regen_fade_speed, 0.6,
                                     msg) == 0          # 8,600 cells and the breakpoints
    finally:
        cp.close()


def test_relay_first_stage_rounds_half_to_even_as_python(lib):
    """The first command's stage count is Python's round(): a need of exactly 2.5 and 3.5
    stages gives 2 and 4 stages, in C as in Python."""
    _, span, car, tuning = COURSES[0]
    _, _, pc = plan_setup(span, car, tuning)
    cp = CPlanner(lib, span, car, tuning)
    met = set()
    try:
        for half in (2.5, 3.5):
            for k in range(200):
                v, s, grade, stop, a_ep = 1.5 + 0.001 * k, 498.5, -3.0, 500.0, 1.0
                d = stop - s
                a_prog = min(max(v * v / (2.0 * d), 0.3 * a_ep), a_ep)
                need = pc.m_in * max(a_prog, v * v / (2.0 * d)) - pc.pg * (pc.w0(v) + grade)
                force = need / half
                if need / force != half:
                    continue
                args = [stop, a_ep, force, 8, 0.03, 0.1, 0.3, 0.3, 0.2, 0.15]
                relay, cr = RelayBrake(*args), lib.shim_relay_new(arr(args))
                try:
                    want = relay.command(0.0, s, v, pc, grade)
                    out, msg = arr([], 6), ctypes.create_string_buffer(256)
                    assert lib.shim_relay_command(cr, cp.h, 0.0, s, v, grade, out, msg) == 0
                    assert int(out[2]) == want[2] == round(half)
                    met.add(half)
                finally:
                    lib.shim_relay_free(cr)
                break
    finally:
        cp.close()
    assert met == {2.5, 3.5}


def test_memory_is_allocated_only_at_set_up():
    """No allocation per re-plan: malloc/calloc/realloc are called in the course's and the
    planner's init, in check_span_for_car and in the line files' parsers (set-up time: an FMU's
    initialisation) and nowhere else in the C ATO core."""
    import re

    allowed = {"rc_ato_course_init", "rc_ato_planner_init", "rc_ato_check_span_for_car",
               "ato_line_profile_parse", "ato_line_limits_parse"}
    callers = set()
    for path in sorted(CORE.glob("ato_*.c")):
        function = None
        for line in path.read_text().splitlines():
            head = re.match(r"^[a-z_][\w \*]*?\b(\w+)\(", line)
            if head and not line.startswith((" ", "\t", "#", "/")):
                function = head.group(1)
            if re.search(r"\b(malloc|calloc|realloc)\(", line):
                callers.add((path.name, function))
    assert callers and {f for _, f in callers} <= allowed, callers


def random_span(rng: random.Random):
    """A span with random grades (to +-30 permille) and 1-4 limit zones (40-100 km/h), a car of
    random mass and length; None if Python refuses it (check_span_for_car, the course, min_time)."""
    from models.plant.track import GradeProfile

    length = rng.uniform(1200.0, 4000.0)
    stop = length - rng.uniform(0.0, 50.0)
    n_g = rng.randint(2, 12)
    gd = [0.0] + sorted(rng.uniform(10.0, length) for _ in range(n_g - 1))
    gg = [rng.uniform(-30.0, 30.0) for _ in range(n_g)]
    n_l = rng.randint(1, 4)
    ld = [0.0] + sorted(rng.uniform(100.0, stop - 100.0) for _ in range(n_l - 1))
    lv = [rng.uniform(40.0, 100.0) / 3.6 for _ in range(n_l)]
    car = CarTraction(mass=rng.uniform(25.0, 45.0), length=rng.choice([0.0, rng.uniform(5.0, 40.0)]))
    tuning = AtoTuning()
    try:
        span = Span(length, 1.0, stop, GradeProfile(tuple(gd), tuple(gg)), tuple(ld), tuple(lv))
        check_span_for_car(span, car)
        t_min = fastest_run(span, car, tuning)
    except (ValueError, ArithmeticError):    # a span this car cannot run: draw another
        return None
    return span.with_schedule(t_min * rng.uniform(1.02, 1.5)), car, tuning


def test_plan_on_random_spans_is_python_s(lib):
    """Spans beyond the library's (several lower-limit zones, steep grades, long cars): plan()
    from 25 states each, compared in full."""
    rng = random.Random(31)
    done = 0
    while done < 8:
        made = random_span(rng)
        if made is None:
            continue
        span, car, tuning = made
        course, planner, configured = plan_setup(span, car, tuning)
        reference = planner.plan(configured, 0.0, 0.0, 0.0, span.schedule)
        planner = ReducedPlanner(course, tol=tuning.time_tol)
        cp = CPlanner(lib, span, car, tuning)
        try:
            assert cp.status == 0, cp.msg
            rc, t_min = cp.min_time()
            assert rc == 0 and same(t_min, planner.min_time(configured))
            pc = configured
            for k, state in enumerate(plan_states(rng, span, reference, 25)):
                if k % 4 == 3:
                    pc = random_plancar(rng, car, tuning)
                cp.set_car(pc)
                bad, _ = compare_plan(cp, planner, pc, state, rng)
                assert not bad, f"random span {done} state {k} {state}: {bad}"
        finally:
            cp.close()
        done += 1


def test_a_stalling_car_fails_as_in_python(lib):
    """A resistance above the traction limit: plan() raises its ValueError (no holding speed
    runs the rest of the span), min_time says where the fastest run stalls (it let a bare
    _Stall escape, "1150.0"); C returns RC_BAD_CONFIG with the same words."""

    _, span, car, tuning = COURSES[0]
    _, planner, _ = plan_setup(span, car, tuning)
    heavy = PlanCar(car, 30.0, 200.0, car.A1, car.A2, tuning.brake_share)
    cp = CPlanner(lib, span, car, tuning)
    try:
        cp.set_car(heavy)
        rc, _, _ = cp.plan(500.0, 10.0, 30.0, 135.0)
        assert rc != 0 and cp.error() == _python_error(lambda: planner.plan(heavy, 500.0, 10.0, 30.0, 135.0))
        assert cp.error().startswith("no holding speed runs the rest of the span from s = 500.0 m")
        with pytest.raises(ValueError, match=r"the span cannot be run: at full traction from rest "
                                             r"the 30\.0 t car comes to rest at s = ") as e:
            planner.min_time(heavy)
        rc, _ = cp.min_time()
        assert rc == 2 and cp.error() == str(e.value)         # RC_BAD_CONFIG
    finally:
        cp.close()
