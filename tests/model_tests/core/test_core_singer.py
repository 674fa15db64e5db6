"""The C Singer filter (models/core/singer.c, kind 4 of models/core/filter.c) against the Python
one (models/filtering/singer.py's scalar path, models/filtering/motion_filter.py's Singer branches), bit for bit.

- the parts: the Taylor coefficient table, J_ij / phi_k on both sides of SERIES_SWITCH, the
  discretisation (Phi, Q, u) over alpha dt from 1e-9 to 1e4, the filter.singer_* settings
  (moments and Python's messages);
- SingerFilter alone: random predictions and updates (speed, distance, both, any H and R, with
  and without the clip), x, P and NIS after every call;
- MotionFilter kind 4 in the estimator's call order (tests/model_tests/core/test_core_filter.py's station_runs:
  spikes, NaN, a stuck speed sensor, a distance jump reacquired, both measurements lost), with
  and without odometry drift, and hostile random calls: the whole state (MotionFilter's fields,
  the acceleration, the Singer filter's x, P, NIS) after every call; one ulp shows; clean under
  ASan/UBSan;
- the chains: RailCarChain against CompiledChain with filter.kind 4 on steep_grades and
  station_day (every output every step), the estimator chain through faults, stops and
  track-sensor speeds (the Singer acceleration carries them).
Compiled here with gcc (-Werror, no FMA); tests/core_cases/singer_shim.c is the flat interface.
"""
from __future__ import annotations

import ctypes
import functools
import math
import random
import shutil
import subprocess

import numpy as np
import pytest

from models.filtering import singer
from models.chain import ChainConfig, EstimatorChain, TrackSensorConfig
from models.compiled import CompiledEstimatorChain, open_chain
from models.estimation.online import StationConfig
from models.filtering.motion_filter import SINGER, FilterConfig, MotionFilter
from models.estimation.identification import IdentifierConfig
from models.filtering.singer import SingerFilter, SingerParams
from models.plant.track import GradeProfile
from test_core_chain import ROOT, assert_identical, measurements, replay, same, with_faults

measurements = functools.lru_cache(maxsize=4)(measurements)   # the same rows for each case
from test_core_filter import (FIELDS, GATE, HOLD, PREDICT, RESTART, START, THETA_TRUE,
                              UPDATE, UPDATE_SPEED, bits, py_fields, random_calls, station_runs)

CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "singer_shim.c"
SOURCES = [CORE / "singer.c", CORE / "filter.c", CORE / "track.c", CORE / "repr.c", CORE / "fpmath.c", SHIM]
CFLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
          "-fPIC"]
RC_OK, RC_BAD_CONFIG, RC_MATH = 0, 2, 3
NAMES = ("phi1", "phi2", "phi3", "ww", "wv", "wr", "vv", "vr", "rr")   # singer.h's RC_SF_*
# MotionFilter's fields (test_core_filter.FIELDS), its acceleration, then the Singer filter's
SINGER_FIELDS = ("w", "v", "r", *(f"P{i}{j}" for i in range(3) for j in range(3)), "nis",
                 "tau", "sigma_w", "m_w", "clip", "pad")
OUT_NAMES = ("status", "use_v", "use_x", *FIELDS, "acceleration", *SINGER_FIELDS)
NOUT = len(OUT_NAMES)
OP_SIZE = 9
P = ctypes.c_void_p


def build(out, extra):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    proc = subprocess.run([gcc, *CFLAGS, *extra, f"-I{CORE}", *map(str, SOURCES), "-o", str(out),
                           "-lm"], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


@pytest.fixture(scope="module")
def slib(tmp_path_factory):
    so = tmp_path_factory.mktemp("core") / "libsinger.so"
    build(so, ["-shared"])
    dll = ctypes.CDLL(str(so))
    dll.shim_new.restype = P
    dll.shim_new.argtypes = [P, P]
    dll.shim_free.argtypes = [P]
    dll.shim_apply.argtypes = [P, P, P]
    dll.singer_new.restype = P
    dll.singer_new.argtypes = [ctypes.c_double] * 3 + [P, P, ctypes.c_int]
    dll.singer_free.argtypes = [P]
    dll.singer_apply.argtypes = [P, P, P]
    dll.singer_f.argtypes = [ctypes.c_int, ctypes.c_double, P]
    dll.singer_coefficients.argtypes = [ctypes.c_int, P]
    dll.singer_discretisation.argtypes = [ctypes.c_double] * 4 + [P]
    dll.singer_params.argtypes = [P, P, P]
    assert dll.shim_nstate() == NOUT - 3
    return dll


def config_values(cfg: FilterConfig) -> list[float]:
    return [cfg.dt, cfg.speed_std, cfg.position_std, cfg.position_std_rel, cfg.gamma, cfg.kind,
            cfg.length, cfg.singer_tau, cfg.singer_p0, cfg.singer_p_plus, cfg.singer_p_minus,
            cfg.singer_w_max_plus, cfg.singer_w_max_minus, cfg.speed_std_rel]


def op_array(ops) -> np.ndarray:
    a = np.zeros((len(ops), OP_SIZE))
    for i, op in enumerate(ops):
        a[i, :len(op)] = op
    return a


def c_trace(lib, cfg: FilterConfig, ops: np.ndarray) -> np.ndarray:
    msg = ctypes.create_string_buffer(256)
    c = np.array(config_values(cfg))
    h = lib.shim_new(c.ctypes.data, msg)
    assert h, msg.value.decode()
    try:
        out = np.zeros((len(ops), NOUT))
        for i in range(len(ops)):
            lib.shim_apply(h, ops[i].ctypes.data, out[i].ctypes.data)
    finally:
        lib.shim_free(h)
    return out


def py_state(f: MotionFilter) -> list[float]:
    g, sp = f.algorithm.singer, f.algorithm.params
    return [*py_fields(f), f.acceleration, *g._x, *g._P, g.nis,
            sp.tau, sp.sigma_w, sp.m_w, float(g.clip), 0.0]


def py_trace(cfg: FilterConfig, ops) -> np.ndarray:
    f = MotionFilter(cfg, GradeProfile.level(), None)
    rows = []
    for op in ops:
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
                f.predict(op[1], op[2], tuple(op[3:7]), op[7], op[8])
            else:
                raise AssertionError(op)
        except (ZeroDivisionError, OverflowError, ValueError):
            status = RC_MATH
        rows.append([float(status), float(use[0]), float(use[1]), *py_state(f)])
    return np.array(rows)


def first_difference(ours: np.ndarray, theirs: np.ndarray):
    bad = np.argwhere(bits(ours) != bits(theirs))
    if len(bad) == 0:
        return None
    i, j = bad[0]
    return int(i), OUT_NAMES[j]


def assert_same(ours, theirs, ops):
    diff = first_difference(ours, theirs)
    if diff is not None:
        i, name = diff
        j = OUT_NAMES.index(name)
        raise AssertionError(f"call {i} {ops[i]}: {name} C {ours[i, j]!r} != Python "
                             f"{theirs[i, j]!r}")


# ---------------------------------------------------------------- the parts

def test_the_series_table_and_the_functions_are_pythons(slib):
    out = np.zeros(40)
    for k, name in enumerate(NAMES):
        slib.singer_coefficients(k, out.ctypes.data)
        assert out.tolist() == list(singer._COEFFS[name]), name
    rng = random.Random(1)
    xs = [0.0, 1e-300, 1e-9, 1e-4, 0.3, 1.0, math.nextafter(1.5, 0.0), 1.5, 1.5000000000000002,
          2.0, 10.0, 37.5, 700.0, 1e5, 1e20, 1e61, 1e62, 1e70, 1e80, 1e200, math.inf]
    xs += [10 ** rng.uniform(-9, 3) for _ in range(400)]
    y = np.zeros(1)
    for k, name in enumerate(NAMES):
        for x in xs:
            try:
                want, status = singer._f(name, x), RC_OK
            except (OverflowError, ZeroDivisionError):     # x ** n; 2 x x underflowing to 0
                want, status = math.nan, RC_MATH
            got = slib.singer_f(k, x, y.ctypes.data)
            assert got == status, (name, x)
            if status == RC_OK:
                assert bits(y)[0] == bits(np.array([want]))[0], (name, x, y[0], want)
    assert sum(1 for x in xs if x >= 1e62) > 3      # the closed forms' x ** 5 overflow is met


def test_the_discretisation_is_pythons(slib):
    rng = random.Random(2)
    cases = [(0.1, 0.1, 0.4, 0.05), (1e-3, 0.1, 0.0, 0.0), (0.2, 0.0, 0.5, -0.1),
             (1.0, 1.5, 0.3, 0.2), (1e5, 1e-2, 2.0, 0.0), (1.0, 1e300, 1.0, 0.0),
             (1.0, -0.1, 1.0, 0.0), (0.0, 0.1, 1.0, 0.0), (1.0, math.nan, 1.0, 0.0),
             (1.0, 0.1, -1.0, 0.0), (1e70, 1.0, 0.5, 0.1)]
    cases += [(10 ** rng.uniform(-4, 2), 10 ** rng.uniform(-3, 2), rng.uniform(0, 2),
               rng.uniform(-0.5, 0.5)) for _ in range(300)]
    out = np.zeros(21)
    statuses = []
    for alpha, dt, sigma, m in cases:
        try:
            Phi, Q, u = singer._discretisation_flat(alpha, dt, sigma, m)
            want, status = np.array([*Phi, *Q, *u]), RC_OK
        except (ValueError, OverflowError):
            want, status = None, RC_MATH
        got = slib.singer_discretisation(alpha, dt, sigma, m, out.ctypes.data)
        statuses.append(got)
        assert got == status, (alpha, dt, sigma, m)
        if status == RC_OK:
            assert (bits(out) == bits(want)).all(), (alpha, dt, sigma, m)
    assert statuses.count(RC_MATH) == 6


def test_the_settings_give_pythons_moments_and_messages(slib):
    good = dict(singer_tau=10.0, singer_p0=0.3, singer_p_plus=0.1, singer_p_minus=0.1,
                singer_w_max_plus=1.3, singer_w_max_minus=-1.5)
    variants = [{}, dict(singer_p0=0.0, singer_p_plus=0.0, singer_p_minus=0.0),
                dict(singer_p0=1.0, singer_p_plus=0.0, singer_p_minus=0.0),
                dict(singer_p0=0.5, singer_p_plus=0.3, singer_p_minus=0.2 + 5e-13),
                dict(singer_w_max_plus=0.0), dict(singer_w_max_minus=0.0, singer_w_max_plus=2.0),
                dict(singer_tau=1e-3), dict(singer_tau=0.0), dict(singer_tau=math.inf),
                dict(singer_tau=-1.0), dict(singer_p0=-0.1), dict(singer_p_plus=math.nan),
                dict(singer_p0=0.9, singer_p_plus=0.2), dict(singer_w_max_plus=-0.1),
                dict(singer_w_max_minus=0.5), dict(singer_w_max_plus=0.0, singer_w_max_minus=0.0),
                dict(singer_w_max_plus=math.inf), dict(singer_w_max_plus=1e308,
                                                       singer_w_max_minus=-1e308)]
    rng = random.Random(4)
    for _ in range(200):
        variants.append(dict(singer_tau=rng.uniform(0.5, 50), singer_p0=rng.uniform(0, 0.5),
                             singer_p_plus=rng.uniform(0, 0.25), singer_p_minus=rng.uniform(0, 0.25),
                             singer_w_max_plus=rng.uniform(0, 3), singer_w_max_minus=-rng.uniform(0.01, 3)))
    refused = 0
    for v in variants:
        cfg = FilterConfig(kind=SINGER, **{**good, **v})
        values = np.array(config_values(cfg)[7:])
        out, msg = np.zeros(2), ctypes.create_string_buffer(256)
        status = slib.singer_params(values.ctypes.data, out.ctypes.data, msg)
        try:
            sp = cfg.singer_params()
        except ValueError as e:
            assert status == RC_BAD_CONFIG and msg.value.decode() == str(e), (v, msg.value)
            refused += 1
            continue
        except OverflowError:
            assert status == RC_BAD_CONFIG and b"overflows" in msg.value
            refused += 1
            continue
        assert status == RC_OK, (v, msg.value)
        assert out.tolist() == [sp.m_w, sp.sigma_w], v
    assert refused == 11


# ---------------------------------------------------------------- SingerFilter alone

def singer_ops(rng: random.Random, n: int) -> list[list[float]]:
    ops = []
    for _ in range(n):
        u = rng.random()
        if u < 0.4:
            dt = rng.choice([0.1, 0.1, 0.05, 0.25, 0.0, 1e-7, 3.0, 40.0, rng.uniform(0.01, 2.0)])
            ops.append([0, dt])
        elif u < 0.55:
            ops.append([1, rng.gauss(10.0, 4.0), rng.choice([0.05, 0.01, 0.2])])
        elif u < 0.65:
            ops.append([2, rng.gauss(500.0, 300.0), rng.choice([1.0, 5.0, 0.3])])
        elif u < 0.85:
            ops.append([3, rng.gauss(10.0, 4.0), rng.gauss(500.0, 300.0), 0.05, 2.0])
        else:
            m = rng.choice([1, 2])
            H = [rng.gauss(0, 1) for _ in range(6)]
            if m == 1:
                H[3:] = [0.0] * 3
            A = [[rng.gauss(0, 1) for _ in range(m)] for _ in range(m)]
            R = [sum(A[a][k] * A[b][k] for k in range(m)) + (0.1 if a == b else 0.0)
                 for a in range(m) for b in range(m)]
            R += [0.0] * (4 - len(R))
            ops.append([4, m, rng.gauss(5, 5), rng.gauss(5, 5), *H, *R])
    return ops


def py_singer(f: SingerFilter, op) -> list[float]:
    status = RC_OK
    try:
        code = op[0]
        if code == 0:
            f.predict(op[1])
        elif code == 1:
            f.update_speed(op[1], op[2])
        elif code == 2:
            f.update_distance(op[1], op[2])
        elif code == 3:
            f.update_speed_distance(op[1], op[2], op[3], op[4])
        else:
            m = int(op[1])
            f.update(op[2:2 + m], np.array(op[4:4 + 3 * m]).reshape(m, 3),
                     np.array(op[10:10 + m * m]).reshape(m, m))
    except (ZeroDivisionError, OverflowError, ValueError):
        status = RC_MATH
    return [float(status), *f._x, *f._P, f.nis]


@pytest.mark.parametrize("seed,clip", [(0, True), (1, True), (2, False), (3, True)])
def test_singer_filter_alone_bit_identical(slib, seed, clip):
    rng = random.Random(seed)
    params = SingerParams(tau=rng.choice([2.0, 10.0, 0.05]), sigma_w=rng.uniform(0.1, 1.0),
                          m_w=rng.uniform(-0.3, 0.3))
    x0 = [rng.gauss(0, 0.5), rng.uniform(-1.0, 15.0), rng.uniform(0, 100)]
    P0 = np.diag([params.sigma_w ** 2, 0.04, 4.0])
    P0[0, 1] = P0[1, 0] = 0.01
    f = SingerFilter(params, x0=x0, P0=P0, clip=clip)
    x0a, P0a = np.array(x0), np.ascontiguousarray(P0)
    h = slib.singer_new(params.tau, params.sigma_w, params.m_w, x0a.ctypes.data, P0a.ctypes.data,
                        int(clip))
    try:
        ops = singer_ops(rng, 3000)
        out = np.zeros(14)
        assert out.size == 1 + len(f._x) + len(f._P) + 1
        statuses = set()
        negative = 0
        for i, op in enumerate(ops):
            want = np.array(py_singer(f, op))
            a = np.zeros(14)
            a[:len(op)] = op
            slib.singer_apply(h, a.ctypes.data, out.ctypes.data)
            assert (bits(out) == bits(want)).all(), (i, op, out, want)
            statuses.add(int(want[0]))
            negative += f._x[1] < 0.0
        assert statuses == {RC_OK}
        assert (negative > 0) == (not clip)
    finally:
        slib.singer_free(h)


# ---------------------------------------------------------------- MotionFilter kind 4

REALISTIC = [(seed, rel, tau) for seed, rel, tau in
             [(1, 0.0, 10.0), (2, 0.01, 10.0), (3, 0.0, 3.0), (4, 0.01, 40.0)]]


@pytest.mark.parametrize("seed,rel,tau", REALISTIC)
def test_a_car_with_faulty_sensors_gives_the_same_singer_filter_in_c(slib, seed, rel, tau):
    """station_runs' faults (spikes, NaN, a frozen speed sensor, a distance jump reacquired,
    both measurements lost), odometry drift or not, track-sensor speed updates, station
    restarts and starts from a measurement; the whole state after every call."""
    cfg = FilterConfig(dt=0.1, speed_std=0.05, position_std=1.0, position_std_rel=rel,
                       kind=SINGER, singer_tau=tau)
    ops = station_runs(40 + seed, cfg, n=2500, start_measured=seed % 2 == 0)
    theirs = py_trace(cfg, ops)
    assert_same(c_trace(slib, cfg, op_array(ops)), theirs, ops)
    col = {n: OUT_NAMES.index(n) for n in OUT_NAMES}
    assert theirs[-1, col["reacquired"]] >= 2
    assert theirs[-1, col["rejected"]] > 200
    assert (theirs[:, col["_reacquire"]] == 1).any() or (theirs[:, col["_reacquire"]] == 2).any()
    assert (theirs[:, col["speed_run"]] >= 40).any()        # the frozen speed sensor
    assert np.isfinite(theirs[-1, col["speed"]])
    assert (theirs[:, col["v"]] == 0.0).sum() > 10        # at rest (the clip and the restarts)
    acc = theirs[:, col["acceleration"]]
    assert np.nanmax(acc) - np.nanmin(acc) > 0.5


@pytest.mark.parametrize("seed,rel", [(5, 0.02), (6, 0.5)])
def test_relative_speed_noise_gives_the_same_singer_filter_in_c(slib, seed, rel):
    """sensor.speed_std_rel: the Singer updates take the speed's std speed_std + rel |V_meas|,
    the starts its square; station_runs' faults, the whole state after every call == Python's."""
    cfg = FilterConfig(dt=0.1, speed_std=0.02, position_std=1.0, position_std_rel=0.01,
                       speed_std_rel=rel, kind=SINGER)
    ops = station_runs(40 + seed, cfg, n=2500, start_measured=seed % 2 == 0)
    theirs = py_trace(cfg, ops)
    assert_same(c_trace(slib, cfg, op_array(ops)), theirs, ops)
    col = {n: OUT_NAMES.index(n) for n in OUT_NAMES}
    assert theirs[-1, col["reacquired"]] >= 2
    absolute = py_trace(FilterConfig(**{**cfg.__dict__, "speed_std_rel": 0.0}), ops)
    assert not np.array_equal(np.nan_to_num(theirs[:, col["v"]]), np.nan_to_num(absolute[:, col["v"]]))


@pytest.mark.parametrize("seed", range(3))
def test_random_calls_with_relative_speed_noise(slib, seed):
    """Hostile calls with speed_std_rel > 0 (1e150: the std's square overflows at |V| > ~1e4):
    RC_MATH exactly where Python raises, the same state after it."""
    rng = np.random.default_rng(2100 + seed)
    cfg = FilterConfig(dt=0.1, speed_std=float(rng.uniform(0.01, 0.2)),
                       position_std=float(rng.uniform(0.5, 3.0)), position_std_rel=0.01,
                       speed_std_rel=(0.02, 0.5, 1e150)[seed], kind=SINGER)
    ops = random_calls(rng, 2500)
    theirs = py_trace(cfg, ops)
    assert_same(c_trace(slib, cfg, op_array(ops)), theirs, ops)
    assert (theirs[:, 0] == RC_MATH).sum() > 0


@pytest.mark.parametrize("seed", range(6))
def test_random_calls_with_hostile_values(slib, seed):
    """NaN, inf, overflowing squares, zero and negative variances, bad steps (ValueError):
    RC_MATH exactly where Python raises, the same state after it."""
    rng = np.random.default_rng(2000 + seed)
    cfg = FilterConfig(dt=0.1, speed_std=float(rng.uniform(0.01, 0.2)),
                       position_std=float(rng.uniform(0.5, 3.0)),
                       position_std_rel=float(rng.choice([0.0, 0.01, 0.5])), kind=SINGER,
                       singer_tau=float(rng.choice([0.5, 10.0])))
    ops = random_calls(rng, 2500)
    steps = [0.1, 0.05, 0.0, -0.0, 1e-9, 5.0, 300.0, -0.1, math.nan, math.inf]
    ops = [(*op[:8], float(rng.choice(steps))) if op[0] == PREDICT else
           (op[0], op[1], -op[2]) if op[0] == UPDATE_SPEED and rng.random() < 0.1 else op
           for op in ops]
    theirs = py_trace(cfg, ops)
    assert_same(c_trace(slib, cfg, op_array(ops)), theirs, ops)
    assert (theirs[:, 0] == RC_MATH).sum() > 20


def test_the_math_errors_are_where_python_raises(slib):
    cfg = FilterConfig(dt=0.1, position_std_rel=0.01, kind=SINGER)
    ops = [(RESTART,), (START, 3.0, 1e200),                   # restart, then the overflow
           (START, 3.0, 10.0), (PREDICT, 0, 0, *THETA_TRUE, 1e-4, -1.0),   # bad step
           (PREDICT, 0, 0, *THETA_TRUE, 1e-4, 0.1), (UPDATE_SPEED, 3.0, -1.0),  # sqrt(-1)
           (GATE, 3.0, 10.0), (UPDATE, 3.0, 1e200),            # the distance's std ** 2
           (GATE, 1e3, 10.0), (UPDATE, 1e3, 1e200),            # the distance alone
           *[(GATE, 3.0, 1e6)] * 50, (UPDATE, 3.0, 1e200)]     # reacquired: the start overflows
    theirs = py_trace(cfg, ops)
    assert list(theirs[:, 0]) == [RC_OK, RC_MATH, RC_OK, RC_MATH, RC_OK, RC_MATH, RC_OK, RC_MATH,
                                  RC_OK, RC_MATH, *[RC_OK] * 50, RC_MATH]
    assert_same(c_trace(slib, cfg, op_array(ops)), theirs, ops)
    tiny = FilterConfig(dt=0.1, speed_std=1e-170, position_std=1e-170, kind=SINGER)
    ops = [(GATE, 0.0, 0.0), (UPDATE, 0.0, 0.0), (GATE, 1.0, 0.0), (UPDATE, 1.0, 0.0),
           (GATE, 0.0, 5.0), (UPDATE, 0.0, 5.0), (UPDATE_SPEED, 0.0, 0.0)]  # S = 0, det = 0
    theirs = py_trace(tiny, ops)
    assert list(theirs[:, 0]) == [RC_OK, RC_MATH] * 3 + [RC_MATH]
    assert_same(c_trace(slib, tiny, op_array(ops)), theirs, ops)


def test_the_singer_path_calls_no_blas(monkeypatch):
    """MotionFilter kind 4 runs without numpy's linear algebra (what C cannot reproduce)."""
    def refuse(*args, **kwargs):
        raise AssertionError("numpy.linalg on the Singer path")
    monkeypatch.setattr(np.linalg, "solve", refuse)
    monkeypatch.setattr(np.linalg, "inv", refuse)
    cfg = FilterConfig(dt=0.1, kind=SINGER)
    py_trace(cfg, station_runs(5, cfg, n=300))


def test_one_ulp_of_one_input_shows_in_the_comparison(slib):
    cfg = FilterConfig(dt=0.1, kind=SINGER, position_std_rel=0.01)
    ops = station_runs(3, cfg, n=800, faults=False)
    theirs = py_trace(cfg, ops)
    a = op_array(ops)
    assert first_difference(c_trace(slib, cfg, a), theirs) is None
    updates = [i for i, op in enumerate(ops) if op[0] == UPDATE and ops[i - 1][0] == GATE]
    for i in updates[100:600:50]:
        bumped = a.copy()
        bumped[i, 1] = math.nextafter(bumped[i, 1], math.inf)
        diff = first_difference(c_trace(slib, cfg, bumped), theirs)
        assert diff is not None and diff[0] == i
    predicts = [i for i, op in enumerate(ops) if op[0] == PREDICT]
    bumped = a.copy()
    bumped[predicts[200], 8] = math.nextafter(bumped[predicts[200], 8], math.inf)
    diff = first_difference(c_trace(slib, cfg, bumped), theirs)
    assert diff is not None and diff[0] == predicts[200]


def test_the_singer_filter_runs_clean_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    exe = tmp_path / "singer_run"
    build(exe, ["-O1", "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                "-DSINGER_SHIM_MAIN"])
    rng = np.random.default_rng(9)
    cfg_a = FilterConfig(dt=0.1, position_std_rel=0.01, kind=SINGER)
    cfg_b = FilterConfig(dt=0.1, position_std_rel=0.5, kind=SINGER, singer_tau=0.5)
    ops_b = [(*op[:8], float(rng.choice([0.1, -1.0, math.nan, 0.0, 400.0])))
             if op[0] == PREDICT else op for op in random_calls(rng, 1500)]
    for i, (cfg, ops) in enumerate([(cfg_a, station_runs(11, cfg_a, n=2000)), (cfg_b, ops_b)]):
        data = np.concatenate([np.array(config_values(cfg)), op_array(ops).ravel()])
        src, dst = tmp_path / f"case{i}.bin", tmp_path / f"case{i}.out"
        data.astype("<f8").tofile(src)
        proc = subprocess.run([str(exe), str(src), str(dst)], capture_output=True, timeout=120,
                              env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
        assert proc.returncode == 0, proc.stderr.decode(errors="replace")
        assert proc.stderr == b""
        ours = np.fromfile(dst, dtype="<f8").reshape(-1, NOUT)
        assert_same(ours, py_trace(cfg, ops), ops)


# ---------------------------------------------------------------- the chains

LIBRARY = ROOT / "scenarios" / "library"


@pytest.mark.parametrize("scenario,overrides", [
    ("steep_grades", {"filter.kind": 4}),
    ("station_day", {"filter.kind": 4}),
    ("station_day", {"filter.kind": 4, "filter.singer_tau": 4.0, "filter.singer_p0": 0.5,
                     "filter.singer_w_max_plus": 1.0, "sensor.position_std_rel": 0.01}),
], ids=["steep_grades", "station_day", "station_day_other_settings_and_drift"])
def test_chain_with_the_singer_filter_bit_identical(scenario, overrides):
    assert assert_identical(LIBRARY / f"{scenario}.toml", overrides, max_steps=4000) > 100


def test_open_chain_runs_the_singer_filter_in_c():
    assert open_chain(ChainConfig(filter=FilterConfig(kind=SINGER)), GradeProfile.level()).engine == "c"


@pytest.mark.parametrize("faulty,rel", [(False, 0.0), (True, 0.0), (True, 0.01)])
def test_estimator_chain_with_the_singer_filter_through_faults_and_stops(faulty, rel):
    rows = measurements(1500.0, seed=4, stops=4)
    if faulty:
        rows = with_faults(rows, seed=9)
    args = (IdentifierConfig(mass_initial=30.0),
            FilterConfig(kind=SINGER, position_std_rel=rel, singer_tau=6.0),
            StationConfig(dwell=20.0), GradeProfile.level())
    py, c = EstimatorChain(*args), CompiledEstimatorChain(*args)
    out_py, out_c = replay(py, rows), replay(c, rows)
    assert out_py[-1]["est.station_stops"] >= (2 if faulty else 3)
    if faulty:
        assert out_py[-1]["filter.rejected"] > 40
        assert py.estimator.filter.reacquired >= 1
    for k, (a, b) in enumerate(zip(out_py, out_c)):
        assert same(a, b), f"row {k}: {[(n, a[n], b[n]) for n in a if not same(a[n], b[n])][:4]}"


def test_estimator_chain_track_speeds_use_the_singer_acceleration():
    rows = measurements(400.0, seed=6, stops=1)
    track = TrackSensorConfig(spacing=200.0, base=5.0, resolution=1e-3, jitter=1e-4)
    args = (IdentifierConfig(), FilterConfig(kind=SINGER), StationConfig(), GradeProfile.level(),
            None, track)
    py, c = EstimatorChain(*args), CompiledEstimatorChain(*args)
    rng = random.Random(2)
    accelerations = []
    for k, r in enumerate(rows):
        extra = ()
        if k % 50 == 0 and r[4] > 1.0:
            extra = (r[4] + rng.gauss(0.0, 0.05), r[0] - rng.uniform(0.0, 0.3))
            accelerations.append(py.estimator.filter.acceleration)
        py.do_step(*r, *extra)
        c.do_step(*r, *extra)
        assert same(py.outputs(), c.outputs()), f"row {k}"
    assert py.estimator.track_speeds > 5
    assert max(abs(a) for a in accelerations) > 0.05       # the carried speeds moved with it
