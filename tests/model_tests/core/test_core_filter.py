"""The C motion filter (models/core/filter.c) against models.filtering.motion_filter.MotionFilter, call for call.

Kinds 1 (linearised around V_zad), 2 (EKF), 3 (paper verbatim) and 0 (auto) must give the very
doubles the Python reference gives: the same sequence of calls (restart, start_from_measurement,
gate, hold, update, update_speed, predict) drives both, and after every call the whole state
(every field of rc_filter that mirrors an attribute, the counters and flags included) and the
eight properties are compared bit for bit. The sequences come from a simulated car on a
multi-grade track under the default speed profile, with injected sensor faults (speed spikes,
NaN, a stuck speed sensor, a distance jump the filter reacquires after 50 refusals, both
measurements lost), and from random calls with hostile values (NaN, inf, overflowing squares,
division by zero: Python's exceptions are RC_MATH). Compiled here with gcc (-Werror, no FMA);
tests/core_cases/filter_shim.c is the flat interface ctypes calls.
"""
from __future__ import annotations

import ctypes
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from models.filtering.motion_filter import FilterConfig, MotionFilter
from models.plant.track import GradeProfile, SpeedProfile
from models.units import G

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "filter_shim.c"
SOURCES = [CORE / "filter.c", CORE / "singer.c", CORE / "repr.c", CORE / "track.c", CORE / "fpmath.c"]
CFLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
          "-fPIC"]
RC_OK, RC_BAD_CONFIG, RC_MATH = 0, 2, 3

RESTART, START, GATE, HOLD, UPDATE, UPDATE_SPEED, PREDICT = range(7)   # filter_shim.c's OP_*
OP_SIZE = 9                   # code and up to 8 arguments
# every value rc_filter mirrors, then the properties (filter_shim.c's shim_state order); the
# covariances are symmetric: M[1][0], P[1][0] are checked against M[0][1], P[0][1] in py_fields
FIELDS = ("kind", "R[0]", "R[1]", "x_bar[0]", "x_bar[1]", "M[0][0]", "M[0][1]", "M[1][1]",
          "x_hat[0]", "x_hat[1]", "P[0][0]", "P[0][1]", "P[1][1]", "vzad_hat", "vzad_bar",
          "rejected", "speed_run", "position_run", "reacquired",
          "speed_fit", "_use_speed", "_use_position", "_reacquire",
          "speed", "position", "speed_std", "position_std", "predicted_speed",
          "predicted_position", "predicted_speed_std", "predicted_position_std")
OUT_NAMES = ("status", "use_v", "use_x") + FIELDS
NOUT = len(OUT_NAMES)

GRADE = GradeProfile((0.0, 150.0, 300.0, 520.0, 800.0, 1100.0, 1350.0),
                     (0.0, 8.0, 15.0, -5.0, -10.0, 3.0, 0.0))
SPEED_CSV = ROOT / "scenarios" / "profiles" / "default_speed.csv"
SPEED = SpeedProfile.from_csv_text(SPEED_CSV.read_text(), "default_speed.csv")
THETA_TRUE = (1.0 / (40.0 * G), 1.5, 0.02, 0.0004)     # 40 t car [N/kN per N], A0, A1, A2


def build(gcc: str, out: Path, extra: list[str], sources: list[Path]) -> None:
    proc = subprocess.run([gcc, *CFLAGS, *extra, f"-I{CORE}", *map(str, sources), "-o", str(out),
                           "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core (it is on every machine we support)"
    so = tmp_path_factory.mktemp("core") / "libfilter.so"
    build(gcc, so, ["-shared"], [*SOURCES, SHIM])
    dll = ctypes.CDLL(str(so))
    P = ctypes.c_void_p
    dll.shim_new.restype = P
    dll.shim_new.argtypes = [ctypes.c_double] * 5 + [ctypes.c_int, ctypes.c_double, P, P,
                                                     ctypes.c_long, P, P, ctypes.c_long, P,
                                                     ctypes.c_double]
    dll.shim_free.argtypes = [P]
    dll.shim_apply.argtypes = [P, P, P]
    dll.shim_config.argtypes = [P, P]
    assert dll.shim_nstate() == len(FIELDS)
    return dll


class Case:
    """A filter configuration, its profiles and a sequence of calls (OP_SIZE floats each)."""

    def __init__(self, cfg: FilterConfig, speed: SpeedProfile | None, ops: list[tuple],
                 grade: GradeProfile = GRADE, numpy_theta: bool = True):
        self.cfg, self.speed, self.grade, self.ops = cfg, speed, grade, ops
        self.numpy_theta = numpy_theta      # theta as the estimator passes it (np.ndarray)

    def op_array(self) -> np.ndarray:
        a = np.zeros((len(self.ops), OP_SIZE))
        for i, op in enumerate(self.ops):
            a[i, :len(op)] = op
        return a


def c_new(lib, cfg: FilterConfig, speed: SpeedProfile | None, grade: GradeProfile = GRADE):
    """(handle or None, message)"""
    gd, gg = np.array(grade.distances), np.array(grade.grades)
    sd = np.array(speed.distances if speed else [0.0])
    ss = np.array(speed.speeds if speed else [0.0])
    msg = ctypes.create_string_buffer(256)
    h = lib.shim_new(cfg.dt, cfg.speed_std, cfg.position_std, cfg.position_std_rel, cfg.gamma,
                     cfg.kind, cfg.length, gd.ctypes.data, gg.ctypes.data, len(gd),
                     sd.ctypes.data, ss.ctypes.data, len(speed.distances) if speed else 0, msg,
                     cfg.speed_std_rel)
    return h, msg.value.decode()


def c_trace(lib, case: Case, ops: np.ndarray | None = None) -> np.ndarray:
    ops = case.op_array() if ops is None else ops
    h, msg = c_new(lib, case.cfg, case.speed, case.grade)
    assert h, msg
    try:
        out = np.zeros((len(ops), NOUT))
        for i in range(len(ops)):
            lib.shim_apply(h, ops[i].ctypes.data, out[i].ctypes.data)
        cfg = np.zeros(9)
        lib.shim_config(h, cfg.ctypes.data)
        c = case.cfg
        assert list(cfg) == [c.dt, c.speed_std, c.position_std, c.position_std_rel, c.gamma, c.kind,
                             c.length, case.speed is not None, c.speed_std_rel]
    finally:
        lib.shim_free(h)
    return out


def py_field(f: MotionFilter, name: str) -> float:
    """The value FIELDS' ``name`` names: an attribute, "M[0][1]" an entry of one."""
    attr, *index = name.replace("]", "").split("[")
    value = getattr(f, attr)
    for i in index:
        value = value[int(i)]
    return float(value)


def py_fields(f: MotionFilter) -> list[float]:
    """FIELDS' values of a MotionFilter."""
    for C in (f.M, f.P):
        assert len(C) == 2 and len(C[0]) == len(C[1]) == 2
        assert C[1][0] is C[0][1] or same_bits(C[1][0], C[0][1])
    return [py_field(f, n) for n in FIELDS]


def same_bits(a, b) -> bool:
    return np.array(float(a)).view(np.uint64) == np.array(float(b)).view(np.uint64) or (
        math.isnan(a) and math.isnan(b))


def py_apply(f: MotionFilter, op: tuple, numpy_theta: bool) -> list[float]:
    code, use, status = op[0], (False, False), RC_OK
    try:
        if code == RESTART:
            f.restart()
        elif code == START:
            f.start_from_measurement(op[1], op[2])
        elif code == GATE:
            use = f.gate(op[1], op[2])
        elif code == HOLD:
            f.hold()
        elif code == UPDATE:
            f.update(op[1], op[2])
        elif code == UPDATE_SPEED:
            f.update_speed(op[1], op[2])
        elif code == PREDICT:
            theta = np.array(op[3:7]) if numpy_theta else tuple(op[3:7])
            f.predict(op[1], op[2], theta, op[7], op[8])
        else:
            raise AssertionError(op)
    except (ZeroDivisionError, OverflowError):
        status = RC_MATH
    return [float(status), float(use[0]), float(use[1]), *py_fields(f)]


def py_trace(case: Case) -> np.ndarray:
    f = MotionFilter(case.cfg, case.grade, case.speed)
    with np.errstate(all="ignore"):
        return np.array([py_apply(f, op, case.numpy_theta) for op in case.ops])


def bits(a: np.ndarray) -> np.ndarray:
    """The values' bits, every NaN as one: a NaN's sign and payload are not Python's semantics
    (which NaN operand x86 passes on depends on the order the compiler puts a commutative
    operation's operands in, in CPython as in the core), -0.0 against 0.0 still counts."""
    return np.where(np.isnan(a), np.nan, a).view(np.uint64)


def first_difference(ours: np.ndarray, theirs: np.ndarray):
    """(row, name) of the first value that differs (bits; NaN equals NaN), or None"""
    bad = np.argwhere(bits(ours) != bits(theirs))
    if len(bad) == 0:
        return None
    i, j = bad[0]
    return int(i), OUT_NAMES[j]


def assert_same(ours: np.ndarray, theirs: np.ndarray, case: Case) -> None:
    diff = first_difference(ours, theirs)
    if diff is not None:
        i, name = diff
        j = OUT_NAMES.index(name)
        raise AssertionError(f"call {i} {case.ops[i]}: {name} C {ours[i, j]!r} != Python "
                             f"{theirs[i, j]!r} (kind {case.cfg.kind})")


# ---------------------------------------------------------------- realistic sequences

def station_runs(seed: int, cfg: FilterConfig, n: int = 3000, faults: bool = True,
                 start_measured: bool = False) -> list[tuple]:
    """The calls the estimator makes for a simulated car running station to station under the
    default speed profile (truth: eq. (2) with THETA_TRUE and process noise), measurements with
    seeded noise and, with ``faults``, a speed sensor frozen for 150 samples from the first
    braking after sample 300, a distance that
    jumps by 200 m at sample 900 (kept until the next station: reacquired), both measurements
    lost (1500-1559: the whole filter reacquired), NaN distances (2000-2059), spikes and NaN."""
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 6.28, 4)
    ops: list[tuple] = [(START, 0.0, 0.0) if start_measured else (RESTART,)]
    v = x = 0.0
    dwell = 0
    run = 0
    jump = 0.0
    stuck, stuck_until = None, 0
    for k in range(n):
        vt = SPEED.at(x + 2.0 * v)
        err = vt - v
        tr = min(max(40000.0 * err + 8000.0, 0.0), 60000.0) if err > -0.3 else 0.0
        br = min(-60000.0 * err, 80000.0) if err < -0.3 else 0.0
        if dwell:
            tr = br = 0.0
        grade = GRADE.average(x, cfg.length)
        snf = (THETA_TRUE[0] * (tr - br) - THETA_TRUE[1] - THETA_TRUE[2] * v
               - THETA_TRUE[3] * v * v - grade)
        dt = 0.05 if rng.random() < 0.05 else cfg.dt
        v_new = max(v + G / 1000.0 * snf * dt + rng.normal(0.0, 0.01), 0.0) if not dwell else 0.0
        # measurements of this sample
        vm = v + rng.normal(0.0, cfg.speed_std + cfg.speed_std_rel * v)   # rel 0: the same draws
        xm = x + rng.normal(0.0, cfg.position_std + cfg.position_std_rel * x) + jump
        if faults:
            if stuck is None and k >= 300 and br > 0.0:
                stuck, stuck_until = vm, k + 150                # frozen while the car brakes
            if stuck is not None and k < stuck_until:
                vm = stuck
            if k == 900:
                jump = 200.0
                xm += jump
            if 1500 <= k < 1560:
                vm, xm = vm + 6.0, xm + 300.0
            if 2000 <= k < 2060:
                xm = math.nan
            u = rng.random()
            if u < 0.01:
                vm += rng.choice([-1.0, 1.0]) * rng.uniform(2.0, 10.0)
            elif u < 0.015:
                vm = math.nan
            elif u < 0.019:
                xm = math.nan
            elif u < 0.021:
                vm = xm = math.nan
        vm, xm = float(vm), float(xm)
        ops.append((GATE, vm, xm))
        ops.append((HOLD,) if rng.random() < 0.05 else (UPDATE, vm, xm))
        if rng.random() < 0.1:
            ops.append((UPDATE_SPEED, float(vm + rng.normal(0.0, 0.1)), 0.01))
        theta = [float(t * (1.0 + 0.1 * math.sin(k / 500.0 + p)))
                 for t, p in zip(THETA_TRUE, phase)]
        q = 1e-4 * (1.0 + 0.5 * math.sin(k / 200.0))
        ops.append((PREDICT, float(tr), float(br), *theta, q, dt))
        # the truth moves on; a stop at the station, then the next run from X = 0
        x += dt * (v + v_new) / 2.0
        v = v_new
        if dwell:
            dwell -= 1
            if dwell == 0:
                run += 1
                x = v = 0.0
                jump = 0.0
                ops.append((START, 0.0, float(rng.normal(0.0, 1.0))) if run % 2 else (RESTART,))
        elif x > 1450.0 and v == 0.0:
            dwell = 30
    return ops


REALISTIC = [(kind, length, rel, gamma)
             for kind in (1, 2, 3) for length in (0.0, 60.0) for rel in (0.0, 0.01)
             for gamma in ((0.0,) if length == 0.0 else (0.08,))]


@pytest.mark.parametrize("kind,length,rel,gamma", REALISTIC)
def test_a_car_with_faulty_sensors_gives_the_same_filter_in_c(lib, kind, length, rel, gamma):
    cfg = FilterConfig(dt=0.1, speed_std=0.05, position_std=1.0, position_std_rel=rel, gamma=gamma,
                       kind=kind, length=length)
    case = Case(cfg, SPEED, station_runs(100 * kind + int(length) + int(1000 * rel), cfg,
                                         start_measured=kind == 2))
    theirs = py_trace(case)
    assert_same(c_trace(lib, case), theirs, case)
    # the sequence reached what it is meant to reach
    col = {n: OUT_NAMES.index(n) for n in OUT_NAMES}
    assert theirs[-1, col["reacquired"]] >= 3
    assert theirs[-1, col["rejected"]] > 300
    assert np.isnan(theirs[:, col["position"]]).any()      # a NaN distance reacquired
    assert (theirs[:, col["_reacquire"]] == 1).any() and (theirs[:, col["_reacquire"]] == 2).any()
    assert (theirs[:, col["speed_fit"]] == 0).any() and (theirs[:, col["speed_fit"]] == 1).any()
    assert (theirs[:, col["speed_run"]] >= 40).any()        # the frozen speed sensor
    assert np.isfinite(theirs[-1, col["speed"]])            # recovered from the NaN distances


@pytest.mark.parametrize("kind,with_profile", [(0, True), (0, False), (2, False)])
def test_auto_kind_and_the_ekf_without_a_speed_profile(lib, kind, with_profile):
    cfg = FilterConfig(dt=0.1, speed_std=0.08, position_std=2.0, position_std_rel=0.005,
                       kind=kind, length=25.0)
    speed = SPEED if with_profile else None
    case = Case(cfg, speed, station_runs(7 + kind + with_profile, cfg, n=2500,
                                         faults=not with_profile))
    theirs = py_trace(case)
    assert theirs[0, OUT_NAMES.index("kind")] == (1 if with_profile else 2)
    assert_same(c_trace(lib, case), theirs, case)


def test_one_ulp_of_one_input_shows_in_the_comparison(lib):
    """The comparison can fail: a measured speed one ulp off in any of 20 updates makes the C
    trace differ from that call on (not before); so does theta[0] one ulp off in some of 40
    predictions under traction (in the others the ulp is rounded away, in C as in Python)."""
    cfg = FilterConfig(dt=0.1, kind=1, length=60.0, position_std_rel=0.01)
    case = Case(cfg, SPEED, station_runs(3, cfg, n=800, faults=False))
    theirs = py_trace(case)
    ops = case.op_array()
    assert first_difference(c_trace(lib, case, ops), theirs) is None

    def bumped_at(i: int, j: int):
        bumped = ops.copy()
        bumped[i, j] = math.nextafter(bumped[i, j], math.inf)
        diff = first_difference(c_trace(lib, case, bumped), theirs)
        assert diff is None or diff[0] >= i
        return diff

    updates = [i for i, op in enumerate(case.ops) if op[0] == UPDATE and case.ops[i - 1][0] == GATE]
    for i in updates[100:600:25]:
        assert bumped_at(i, 1) is not None
    predicts = [i for i, op in enumerate(case.ops) if op[0] == PREDICT and op[1] > 0.0]
    assert sum(bumped_at(i, 3) is not None for i in predicts[:40]) >= 5


# ---------------------------------------------------------------- random calls, hostile values

def random_calls(rng, n: int) -> list[tuple]:
    def value(scale):
        u = rng.random()
        if u < 0.03:
            return math.nan
        if u < 0.05:
            return float(rng.choice([math.inf, -math.inf]))
        if u < 0.07:
            return float(rng.choice([1e200, -1e200, 1e160]))    # squares overflow
        if u < 0.1:
            return 0.0
        return float(rng.normal(0.0, scale))

    ops: list[tuple] = []
    for _ in range(n):
        code = int(rng.choice(7, p=[0.03, 0.04, 0.25, 0.05, 0.25, 0.1, 0.28]))
        if code in (START, GATE, UPDATE):
            ops.append((code, value(10.0), abs(value(500.0))))
        elif code == UPDATE_SPEED:
            ops.append((code, value(10.0), 0.0 if rng.random() < 0.2 else abs(value(0.1))))
        elif code == PREDICT:
            theta = [abs(t * (1.0 + rng.normal(0.0, 0.3))) if rng.random() > 0.05 else value(1.0)
                     for t in THETA_TRUE]
            ops.append((code, abs(value(30000.0)), abs(value(10000.0)), *theta,
                        abs(value(1e-3)), float(rng.choice([0.1, 0.05, 1.0]))))
        else:
            ops.append((code,))
    return ops


@pytest.mark.parametrize("seed", range(12))
def test_random_calls_with_hostile_values(lib, seed):
    """NaN, inf, squares that overflow (OverflowError), zero variances and 1 + gamma = 0
    (ZeroDivisionError): RC_MATH exactly where Python raises, the same state after it."""
    rng = np.random.default_rng(1000 + seed)
    kind = seed % 4
    speed = SPEED if kind in (1, 3) or seed % 3 == 0 else None
    gamma = -1.0 if seed == 5 else float(rng.choice([0.0, 0.1]))
    cfg = FilterConfig(dt=0.1, speed_std=float(rng.uniform(0.01, 0.2)),
                       position_std=float(rng.uniform(0.5, 3.0)),
                       position_std_rel=float(rng.choice([0.0, 0.01, 0.5])), gamma=gamma,
                       kind=kind, length=float(rng.choice([0.0, 60.0])))
    case = Case(cfg, speed, random_calls(rng, 3000), numpy_theta=False)
    theirs = py_trace(case)
    assert_same(c_trace(lib, case), theirs, case)
    if seed == 5:
        assert (theirs[:, 0] == RC_MATH).sum() > 500     # every prediction divides by zero


# ---------------------------------------------------------------- sensor.speed_std_rel

@pytest.mark.parametrize("kind,rel", [(1, 0.02), (2, 0.02), (3, 0.02), (2, 0.5), (0, 0.02)])
def test_relative_speed_noise_gives_the_same_filter_in_c(lib, kind, rel):
    """R_v = (speed_std + speed_std_rel |V_meas|)^2 at the measured speed in the gate, the
    update (both measurements and the speed alone), the start from a measurement and the
    reacquisitions: station_runs' faults, the whole state after every call, == Python's; and
    the relative part changes the trace (it is not ignored)."""
    cfg = FilterConfig(dt=0.1, speed_std=0.02, position_std=1.0, speed_std_rel=rel, kind=kind,
                       position_std_rel=0.01 if kind == 1 else 0.0, length=60.0 if kind == 1 else 0.0)
    case = Case(cfg, SPEED, station_runs(600 + kind + int(10 * rel), cfg, start_measured=kind == 2))
    theirs = py_trace(case)
    assert_same(c_trace(lib, case), theirs, case)
    col = {n: OUT_NAMES.index(n) for n in OUT_NAMES}
    assert theirs[-1, col["reacquired"]] >= 3
    absolute = py_trace(Case(FilterConfig(**{**cfg.__dict__, "speed_std_rel": 0.0}), SPEED, case.ops))
    p00 = col["P[0][0]"]
    assert not np.array_equal(np.nan_to_num(theirs[:, p00]), np.nan_to_num(absolute[:, p00]))


@pytest.mark.parametrize("seed", range(6))
def test_random_calls_with_relative_speed_noise(lib, seed):
    """Hostile calls (NaN, inf, speeds whose variance overflows only through the relative part:
    rel 1e150 at |V| > ~1e4) with speed_std_rel > 0: RC_MATH exactly where Python raises, the
    same state after it."""
    rng = np.random.default_rng(3000 + seed)
    kind = seed % 4
    speed = SPEED if kind in (1, 3) or seed % 3 == 0 else None
    rel = (0.02, 0.5, 1e150)[seed % 3]
    cfg = FilterConfig(dt=0.1, speed_std=float(rng.uniform(0.01, 0.2)),
                       position_std=float(rng.uniform(0.5, 3.0)),
                       position_std_rel=float(rng.choice([0.0, 0.01])), speed_std_rel=rel,
                       kind=kind, length=float(rng.choice([0.0, 60.0])))
    case = Case(cfg, speed, random_calls(rng, 3000), numpy_theta=False)
    theirs = py_trace(case)
    assert_same(c_trace(lib, case), theirs, case)
    assert (theirs[:, 0] == RC_MATH).sum() > 0


def test_the_math_errors_are_where_python_raises(lib):
    """Each RC_MATH on its own, with the state Python leaves at its exception."""
    cfg = FilterConfig(dt=0.1, position_std_rel=0.01, kind=2)
    ops = [(RESTART,), (UPDATE_SPEED, 1.0, 0.0),              # p00 + 0 == 0
           (START, 3.0, 1e200),                               # restart, state set, p's not
           (GATE, 1.0, 1e200),                                # nothing changed
           (START, 3.0, 10.0), (GATE, 0.0, 0.0), (UPDATE, 3.0, 1e200),    # the full update
           *[(GATE, 0.0, 1e6)] * 50,                          # reacquire the distance ...
           (UPDATE, 0.0, 1e200)]                              # ... its variance overflows
    case = Case(cfg, None, ops, numpy_theta=False)
    theirs = py_trace(case)
    col = {n: OUT_NAMES.index(n) for n in OUT_NAMES}
    assert list(theirs[:, 0]) == [RC_OK, RC_MATH, RC_MATH, RC_MATH, RC_OK, RC_OK, RC_MATH,
                                  *[RC_OK] * 50, RC_MATH]
    assert theirs[2, col["x_hat[0]"]] == 3.0 and theirs[2, col["P[0][0]"]] == 0.0
    assert theirs[-2, col["_reacquire"]] == 2
    assert theirs[-1, col["x_hat[1]"]] == 1e200 and theirs[-1, col["reacquired"]] == 1
    assert_same(c_trace(lib, case), theirs, case)
    for kind in (1, 2):                                       # 1 + gamma == 0
        gamma = FilterConfig(dt=0.1, gamma=-1.0, kind=kind)
        case = Case(gamma, SPEED, [(START, 3.0, 10.0), (PREDICT, 1e4, 0.0, *THETA_TRUE, 1e-4, 0.1)],
                    numpy_theta=False)
        theirs = py_trace(case)
        assert list(theirs[:, 0]) == [RC_OK, RC_MATH]
        assert_same(c_trace(lib, case), theirs, case)
    # the distance alone, its variance overflows (update takes another distance than gate)
    case = Case(cfg, None, [(GATE, 50.0, 0.0), (UPDATE, 0.0, 1e200)], numpy_theta=False)
    theirs = py_trace(case)
    assert list(theirs[:, 0]) == [RC_OK, RC_MATH]
    assert_same(c_trace(lib, case), theirs, case)
    # stds whose squares underflow to 0 (Python accepts them): divisions by zero in the updates
    tiny = FilterConfig(dt=0.1, speed_std=1e-170, position_std=1e-170, kind=2)
    ops = [(GATE, 0.0, 0.0), (UPDATE, 0.0, 0.0),                    # det == 0
           (GATE, 0.0, 1e6), (UPDATE, 0.0, 1e6),                    # the speed alone: s == 0
           (GATE, 1e3, 0.0), (UPDATE, 1e3, 0.0),                    # the distance alone: s == 0
           (PREDICT, 1e4, 0.0, *THETA_TRUE, 1e-4, 0.1),
           (GATE, 0.01, 0.0), (UPDATE, 0.01, 0.0),                   # det > 0, R^-1: r0 == 0
           (RESTART,), *[(GATE, 0.0, 1e6)] * 50, (UPDATE, 0.0, 1e6)]   # reacquired, s == 0
    case = Case(tiny, None, ops, numpy_theta=False)
    theirs = py_trace(case)
    assert list(theirs[:, 0]) == ([RC_OK, RC_MATH] * 3 + [RC_OK] * 2 + [RC_MATH]
                                  + [RC_OK] * 51 + [RC_MATH])
    assert theirs[-1, OUT_NAMES.index("reacquired")] == 1
    gates = [0, 2, 4, 7]
    assert list(theirs[gates, 1]) == [1, 1, 0, 1] and list(theirs[gates, 2]) == [1, 0, 1, 1]
    assert_same(c_trace(lib, case), theirs, case)


def test_the_configs_python_refuses_are_refused(lib):
    good = dict(dt=0.1, speed_std=0.05, position_std=1.0, position_std_rel=0.0, kind=1, length=0.0)
    bad = [dict(position_std_rel=-0.1), dict(position_std_rel=math.inf), dict(length=-1.0),
           dict(length=math.nan), dict(speed_std=0.0), dict(speed_std=math.inf),
           dict(position_std=-1.0), dict(kind=5), dict(kind=-1)]
    for change in bad:
        cfg = FilterConfig(**{**good, **change})
        with pytest.raises(ValueError) as exc:
            MotionFilter(cfg, GRADE, SPEED)
        h, msg = c_new(lib, cfg, SPEED)
        assert not h, change
        python = str(exc.value)
        assert msg.split(" got ")[0] == python.split(" got ")[0], (msg, python)
        if "kind" in change:
            assert msg == python
    for kind in (1, 3):                                   # linearised without V_zad
        cfg = FilterConfig(**{**good, "kind": kind})
        with pytest.raises(ValueError) as exc:
            MotionFilter(cfg, GRADE, None)
        h, msg = c_new(lib, cfg, None)
        assert not h and msg == str(exc.value)
    for name in ("speed_std", "position_std"):               # its square overflows
        cfg = FilterConfig(**{**good, name: 1e200})
        with pytest.raises(OverflowError):
            MotionFilter(cfg, GRADE, SPEED)
        h, msg = c_new(lib, cfg, SPEED)
        assert not h and f"sensor.{name} ** 2 overflows" in msg
    h, msg = c_new(lib, FilterConfig(**{**good, "kind": 4}), SPEED)   # Singer: in C now
    assert h, msg                                         # (tests/model_tests/core/test_core_singer.py)
    lib.shim_free(h)


# ---------------------------------------------------------------- sanitizers

SANITIZED_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include "filter_shim.c"
/* argv[1]: doubles: dt speed_std position_std rel gamma kind length, gn, gd[gn], gg[gn], sn,
 * sd[sn], ss[sn], nops, ops[nops][9]; writes the outputs of every call (shim_apply) to stdout */
static double *all;
static long at;
static double next(void) { return all[at++]; }
int main(int argc, char **argv)
{
    char msg[RC_MSG_SIZE];
    FILE *in;
    long size, gn, sn, nops;
    double c[8], out[3 + SHIM_NSTATE];
    const double *gd, *gg, *sd, *ss;
    shim *s;
    if (argc != 2 || !(in = fopen(argv[1], "rb"))) return 2;
    fseek(in, 0, SEEK_END);
    size = ftell(in) / (long)sizeof(double);
    rewind(in);
    all = malloc((size_t)size * sizeof *all);
    if (!all || fread(all, sizeof *all, (size_t)size, in) != (size_t)size) return 2;
    fclose(in);
    for (int i = 0; i < 8; i++) c[i] = next();
    gn = (long)next(); gd = all + at; at += gn; gg = all + at; at += gn;
    sn = (long)next(); sd = all + at; at += sn; ss = all + at; at += sn;
    nops = (long)next();
    if (shim_new(0.1, -1.0, 1.0, 0.0, 0.0, 1, 0.0, gd, gg, gn, sd, ss, sn, msg, 0.0) != NULL) return 3;
    s = shim_new(c[0], c[1], c[2], c[3], c[4], (int)c[5], c[6], gd, gg, gn, sd, ss, sn, msg, c[7]);
    if (!s) { fprintf(stderr, "%s\n", msg); return 2; }
    for (long i = 0; i < nops; i++) {
        shim_apply(s, all + at + 9 * i, out);
        fwrite(out, sizeof out[0], 3 + SHIM_NSTATE, stdout);
    }
    shim_free(s);
    shim_free(NULL);
    free(all);
    return 0;
}
"""


def test_the_filter_runs_clean_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    """filter.c, track.c and the shim under -fsanitize=address,undefined (any report aborts):
    a faulty run and hostile random calls, still equal to Python's."""
    gcc = shutil.which("gcc")
    assert gcc
    (tmp_path / "main.c").write_text(SANITIZED_MAIN)
    exe = tmp_path / "filter_run"
    build(gcc, exe, ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                     f"-I{SHIM.parent}"], [tmp_path / "main.c", *SOURCES])
    cfg_a = FilterConfig(dt=0.1, position_std_rel=0.01, kind=1, length=60.0, gamma=0.05)
    cfg_b = FilterConfig(dt=0.1, position_std_rel=0.5, kind=3, length=0.0)
    cases = [Case(cfg_a, SPEED, station_runs(11, cfg_a, n=2200)),
             Case(cfg_b, SPEED, random_calls(np.random.default_rng(5), 2000), numpy_theta=False)]
    for i, case in enumerate(cases):
        c = case.cfg
        g, s = case.grade, case.speed
        data = [c.dt, c.speed_std, c.position_std, c.position_std_rel, c.gamma, c.kind, c.length,
                c.speed_std_rel, len(g.distances), *g.distances, *g.grades, len(s.distances), *s.distances,
                *s.speeds, len(case.ops), *case.op_array().ravel()]
        (tmp_path / f"case{i}.bin").write_bytes(np.array(data, dtype=np.float64).tobytes())
        proc = subprocess.run([str(exe), str(tmp_path / f"case{i}.bin")], capture_output=True,
                              env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
        assert proc.returncode == 0, proc.stderr.decode(errors="replace")
        assert proc.stderr == b""
        ours = np.frombuffer(proc.stdout, dtype=np.float64).reshape(-1, NOUT)
        assert_same(ours, py_trace(case), case)
