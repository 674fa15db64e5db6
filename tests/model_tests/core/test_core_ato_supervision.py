"""The C input supervision of the ATO (models/core/ato_supervision.c) against the Python one
(models/ato/supervision.py's InputSupervisor and the front of models/ato/controller.py's
AtoController.demands: finiteness, the stated inputs' priors, the safe brake's latch), bit for
bit and word for word.

Driven through tests/core_cases/ato_supervision_shim.c (op records: init, check, note_command,
gate) and in Python alike; after every op the verdict (reason code, subject, text) and the whole
state (the time, the consistency window's anchor, travel and largest std, the response check's
push and dead inputs, the rest point, the latch) are compared by their bits, the texts exactly:

- the library's ATO scenarios in the Python closed loop (harness run_on_chain), every call the
  controllers saw, and ato_nominal / ato_line again with faults injected into what the
  controller reads (a flickering est.mass, NaN and inf inputs, a frozen position, a cut speed,
  time going backwards and jumping, the stated inputs missing): the C gate replays each call
  with the command's traction the Python controller gave, and must give its safe brakes,
  reasons, holds and releases;
- a catalogue at the supervisor: each check's bound exactly and one ulp beyond, the time
  thresholds (RESPONSE_TIME, CONSISTENCY_WINDOW) around their 1e-9 margins, the consistency
  tolerance at equality, the response check at rest and its dead inputs until they move;
- seeded random sequences of sane and insane (finite) values, time steps and commands;
- printf's conversions against Python's format specs (the messages' floats);
- the shim as a program under -fsanitize=address,undefined: every op, the same rows, no report;
- a one-ulp mutation of a supervision expression makes the comparison fail.
"""
from __future__ import annotations

import ctypes
import math
import random
import shutil
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest

from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario
from models.ato.controller import AtoController
from models.ato.interface import ALL_INPUTS, INPUTS, STATED_INPUTS
from models.ato.supervision import (CONSISTENCY_WINDOW, MASS_FACTOR, MAX_CALL_GAP, MAX_DISTANCE,
                                    MAX_SAMPLES, MAX_SPEED, NOISE_SIGMA, RECOVERY_TIME,
                                    RESPONSE_TIME, InputSupervisor)
from models.planning.span import CarTraction, Span

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_supervision_shim.c"
SOURCES = [CORE / "ato_supervision.c", CORE / "ato_tuning.c", CORE / "repr.c"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
         "-fPIC"]
SANITIZE = ["-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
ONE_ULP = "(1.0 + 2.220446049250313e-16)"
ATO_SCENARIOS = ("ato_nominal", "ato_A0_plus50", "ato_headwind", "ato_line", "ato_mass_plus20",
                 "ato_speed_noise", "ato_wet_rail")
INIT, CHECK, NOTE, GATE = 0, 1, 2, 3
N_ALL = len(ALL_INPUTS)
OP_SIZE = 2 + N_ALL
STATE = ("has_t_last", "t_last", "has_anchor", "anchor_t", "anchor_s", "anchor_psd", "travel",
         "v_last", "t_prev", "sd_max", "pushing", "pushing_t", "pushing_s", "dead", "dead_s",
         "at_rest", "at_rest_t", "at_rest_s", "latched", "has_sane_since", "sane_since")
ROW_SIZE = 3 + len(STATE) + N_ALL
SUBJECT_NONE, SUBJECT_TIME, SUBJECT_CONSISTENCY, SUBJECT_RECOVERY = -1, 100, 101, 102
GATE_RUN, GATE_RUN_RELEASED, GATE_SAFE = 0, 1, 2
# ato_supervision.h's ato_reason, each told by words of its Python message
REASONS = (("does not continue", 1), ("after the previous call", 2),
           ("a standard deviation is never negative", 3), ("a filter is exact only", 4),
           ("(not physics)", 5), ("does not run backwards", 6), ("no rail car is that fast", 7),
           ("behind the departure station", 8), ("no line is that long", 9),
           ("of car.mass =", 10), ("no resistance is that large", 11),
           ("not one of the estimator's codes", 12), ("a count of samples", 13),
           ("disagree", 14), ("not connected?", 15), ("is not a finite number", 16),
           ("is not finite: safe brake", 17), ("the safe brake is held", 18))
MASS = 30.0


def reason_code(text: str) -> int:
    for words, code in REASONS:
        if words in text:
            return code
    raise AssertionError(f"no reason code for {text!r}")


# ------------------------------------------------------------------ the C side

def build(out: Path, extra: list[str], sources=SOURCES) -> None:
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    proc = subprocess.run([gcc, *FLAGS, *extra, f"-I{CORE}", *map(str, sources), str(SHIM), "-o",
                           str(out), "-lm"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


def load(path: Path):
    dll = ctypes.CDLL(str(path))
    dll.shim_apply.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long, ctypes.c_void_p,
                               ctypes.c_void_p]
    dll.shim_apply.restype = ctypes.c_int
    dll.shim_subject_name.argtypes = [ctypes.c_int]
    dll.shim_subject_name.restype = ctypes.c_char_p
    sizes = [ctypes.c_int() for _ in range(4)]
    dll.shim_sizes(*map(ctypes.byref, sizes))
    dll.sizes = [s.value for s in sizes]
    return dll


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    out = tmp_path_factory.mktemp("core") / "libato_supervision.so"
    build(out, ["-shared"])
    dll = load(out)
    assert dll.sizes[:3] == [OP_SIZE, ROW_SIZE, 512]
    return dll


def c_apply(dll, ops: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """Rows (ROW_SIZE doubles per op) and texts of the ops through one C supervisor."""
    ops = np.ascontiguousarray(ops, dtype="<f8")
    n = len(ops)
    rows = np.zeros((n, ROW_SIZE))
    texts = ctypes.create_string_buffer(512 * n)
    sup = ctypes.create_string_buffer(dll.sizes[3])
    assert dll.shim_apply(sup, ops.ctypes.data, n, rows.ctypes.data, texts) == 0
    raw = texts.raw
    return rows, [raw[k * 512:(k + 1) * 512].split(b"\0", 1)[0].decode() for k in range(n)]


def subject_of(dll, name: str | None) -> int:
    if name is None:
        return SUBJECT_NONE
    if name in ALL_INPUTS:
        return ALL_INPUTS.index(name)
    code = {"t": SUBJECT_TIME, "filter.speed vs filter.position": SUBJECT_CONSISTENCY,
            "recovery": SUBJECT_RECOVERY}[name]
    assert dll.shim_subject_name(code).decode() == name
    return code


# ------------------------------------------------------------------ the Python side

def op(kind: int, t: float = 0.0, values=()) -> list[float]:
    row = [float(kind), float(t)] + [float(v) for v in values]
    return row + [0.0] * (OP_SIZE - len(row))


def py_state(sup: InputSupervisor, ctrl: AtoController | None = None) -> dict:
    """InputSupervisor's state (and the controller's latch) by the shim's STATE names; None
    where the C value is not meaningful (the flag before it says so)."""
    a, p, d, r = sup._anchor, sup._pushing, sup._dead, sup._at_rest
    latched = bool(ctrl._latched) if ctrl else False
    since = ctrl._sane_since if ctrl else None
    return {"has_t_last": sup.t_last is not None, "t_last": sup.t_last,
            "has_anchor": a is not None, "anchor_t": a and a[0], "anchor_s": a and a[1],
            "anchor_psd": a and a[2], "travel": sup._travel, "v_last": sup._v_last,
            "t_prev": getattr(sup, "_t_prev", None), "sd_max": sup._sd_max,
            "pushing": p is not None, "pushing_t": p and p[0], "pushing_s": p and p[1],
            "dead": d is not None, "dead_s": d and d[1], "at_rest": r is not None,
            "at_rest_t": r and r[0], "at_rest_s": r and r[1], "latched": latched,
            "has_sane_since": since is not None, "sane_since": since}


FLAG_OF = {"t_last": "has_t_last", "anchor_t": "has_anchor", "anchor_s": "has_anchor",
           "anchor_psd": "has_anchor", "pushing_t": "pushing", "pushing_s": "pushing",
           "dead_s": "dead", "at_rest_t": "at_rest", "at_rest_s": "at_rest",
           "sane_since": "has_sane_since"}


def bits(x: float) -> bytes:
    return struct.pack("<d", float(x))


def state_differences(expected: dict, row: np.ndarray) -> list[str]:
    out = []
    for j, name in enumerate(STATE):
        got, want = row[3 + j], expected[name]
        flag = FLAG_OF.get(name)
        if flag is not None and not expected[flag]:
            continue
        if want is None:
            continue
        if isinstance(want, bool):
            if got != float(want):
                out.append(f"{name}: C {got}, Python {want}")
        elif bits(got) != bits(want):
            out.append(f"{name}: C {got!r}, Python {want!r}")
    return out


class Expected:
    """One op's Python outcome: result code, subject name, reason code, text, state, values."""

    def __init__(self, code, name, reason, text, state, values=None):
        self.code, self.name, self.reason, self.text = code, name, reason, text
        self.state, self.values = state, values


def py_apply(ops: list[list[float]]) -> list[Expected]:
    """The supervisor-level ops (INIT, CHECK, NOTE) on InputSupervisor."""
    out, sup = [], None
    for o in ops:
        kind, t, v = int(o[0]), o[1], o[2:]
        if kind == INIT:
            sup = InputSupervisor(v[0])
            out.append(Expected(0, None, 0, "", py_state(sup)))
        elif kind == CHECK:
            got = sup.check(t, list(v[:len(INPUTS)]))
            name, text = got if got is not None else (None, "")
            code = reason_code(text) if got is not None else 0
            out.append(Expected(code, name, code, text, py_state(sup)))
        elif kind == NOTE:
            sup.note_command(v[0])
            out.append(Expected(0, None, 0, "", py_state(sup)))
        else:
            raise AssertionError(kind)
    return out


def differences(dll, expected: list[Expected], rows, texts, limit=5) -> list[str]:
    """Every op where C and Python differ (the first ``limit``), and how."""
    out = []
    for k, (e, row, text) in enumerate(zip(expected, rows, texts)):
        why = []
        if (row[0], row[1], row[2]) != (e.code, subject_of(dll, e.name), e.reason):
            why.append(f"verdict C {tuple(row[:3])}, Python {(e.code, e.name, e.reason)}")
        if text != e.text:
            why.append(f"text\n    C      {text!r}\n    Python {e.text!r}")
        if e.state is not None:
            why += state_differences(e.state, row)
        if e.values is not None:
            got = row[3 + len(STATE):]
            if any(bits(a) != bits(b) for a, b in zip(got, e.values)):
                why.append(f"values C {list(got)}, Python {e.values}")
        if why:
            out.append(f"op {k}: " + "; ".join(why))
            if len(out) >= limit:
                break
    return out


def assert_same(dll, ops, expected=None) -> None:
    expected = expected if expected is not None else py_apply(ops)
    rows, texts = c_apply(dll, np.array(ops))
    diff = differences(dll, expected, rows, texts)
    assert not diff, "\n".join(diff)


# ------------------------------------------------------------------ the controller's calls

class Faults:
    """Faults injected into what a controller reads at time t [s]: a function of (t, k, the
    inputs by name) -> (t, inputs) the controller gets."""

    def __init__(self, rules):
        self.rules = rules
        self.k = 0
        self.frozen: dict = {}

    def __call__(self, t: float, inputs: dict) -> tuple[float, dict]:
        for rule in self.rules:
            t, inputs = rule(self, t, inputs)
        self.k += 1
        return t, inputs


def window(t0, t1, change):
    def rule(f, t, x):
        return (t, change(f, t, x)) if t0 <= t < t1 else (t, x)
    return rule


def set_to(name, value):
    return lambda f, t, x: {**x, name: value}


def flicker(name, value):
    """Every other call bad: the latch must hold through the good ones."""
    return lambda f, t, x: {**x, name: value} if f.k % 2 else x


def freeze(name):
    def change(f, t, x):
        f.frozen.setdefault(name, x[name])
        return {**x, name: f.frozen[name]}
    return change


def time_shift(t0, t1, dt):
    def rule(f, t, x):
        return (t + dt, x) if t0 <= t < t1 else (t, x)
    return rule


NOMINAL_FAULTS = [
    window(20.0, 22.0, flicker("est.mass", 0.0)),               # flicker, then 1 s to release
    window(30.0, 30.35, set_to("filter.speed", math.nan)),
    window(35.0, 35.25, set_to("est.A1", math.inf)),
    window(38.0, 38.15, set_to("filter.position_std", -math.inf)),
    window(40.0, 43.0, freeze("filter.position")),              # consistency
    window(50.0, 52.0, set_to("filter.speed", 0.0)),            # speed cut while moving
    time_shift(60.0, 60.05, -5.0),                              # time backwards once
    window(70.0, 70.35, set_to("est.status", 7.0)),
    window(72.0, 72.35, set_to("est.samples", -1.0)),
    window(74.0, 74.35, set_to("filter.speed_std", 1e300)),
    window(76.0, 78.0, set_to("est.mass_std", math.nan)),       # stated: the prior, no fault
    window(78.0, 80.0, set_to("est.cov_A0_A1", None)),          # missing stated input: the prior
    window(90.0, 90.45, set_to("est.A2", -10.000000000000002)),
    time_shift(120.0, 120.05, 30.0),     # a jump beyond MAX_CALL_GAP: the later calls go back
]
LINE_FAULTS = [
    window(5.0, 5.05, set_to("filter.speed", -1e9)),
    window(100.0, 101.0, flicker("filter.position", -1e9)),
    time_shift(200.0, 200.05, math.nan),                        # t not finite (span 2)
    window(300.0, 300.5, set_to("est.mass", 1e5)),
]


def record_calls(name: str, faults: Faults | None = None) -> list[list[dict]]:
    """Every call of every controller in the Python closed loop of library scenario ``name``
    (faults injected into what the controllers read): per controller a list of calls, each
    {t, inputs (ALL_INPUTS, NaN where missing), safes [(reason, key)], released (event or
    None), values (the check's x or None), traction (None when safe), state (after)}."""
    calls: dict[int, list[dict]] = {}
    demands, safe = AtoController.demands, AtoController._safe
    check = InputSupervisor.check
    current: list[dict] = []

    def rec_safe(self, t, reason, key):
        current[-1]["safes"].append((reason, key))
        return safe(self, t, reason, key)

    def rec_check(self, t, x):
        current[-1]["values"] = [float(v) for v in x]
        return check(self, t, x)

    def rec_demands(self, t, outputs):
        seen = {n: outputs.get(n) for n in ALL_INPUTS}
        if faults is not None:
            t, seen = faults(t, seen)
        call = {"t": t, "inputs": [math.nan if seen[n] is None else float(seen[n])
                                   for n in ALL_INPUTS],
                "safes": [], "values": None}
        current.append(call)
        n_events = len(self.events)
        cmd = demands(self, t, {n: v for n, v in seen.items() if v is not None})
        released = [e for _, e in self.events[n_events:] if "released" in e]
        call["released"] = released[0] if released else None
        call["traction"] = None if call["safes"] else cmd.traction
        call["mode"] = cmd.mode
        call["state"] = py_state(self.supervisor, self)
        calls.setdefault(id(self), [self.car.mass]).append(call)
        return cmd

    AtoController.demands, AtoController._safe = rec_demands, rec_safe
    InputSupervisor.check = rec_check
    try:
        run_on_chain(load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml"))
    finally:
        AtoController.demands, AtoController._safe = demands, safe
        InputSupervisor.check = check
    return list(calls.values())


def gate_ops(controller_calls: list) -> tuple[list[list[float]], list[Expected]]:
    """One controller's calls as GATE ops (and NOTE ops where it stepped) with Python's outcomes."""
    mass, calls = controller_calls[0], controller_calls[1:]
    ops = [op(INIT, 0.0, [mass])]
    expected = [Expected(0, None, 0, "", None)]
    for c in calls:
        ops.append(op(GATE, c["t"], c["inputs"]))
        state = c["state"]
        if c["safes"]:
            assert len(c["safes"]) == 1, c["safes"]
            reason, key = c["safes"][0]
            name = key[len("input:"):] if key.startswith("input:") else key
            # the state after the call: the C gate has done _safe's note_command(0) too
            expected.append(Expected(GATE_SAFE, name, reason_code(reason), reason, state))
        elif c["released"] is not None:
            expected.append(Expected(GATE_RUN_RELEASED, "recovery", 0, c["released"], None,
                                     c["values"]))
        else:
            expected.append(Expected(GATE_RUN, None, 0, "", None, c["values"]))
        if not c["safes"]:
            ops.append(op(NOTE, 0.0, [c["traction"]]))
            expected.append(Expected(0, None, 0, "", state))
    return ops, expected


@pytest.fixture(scope="module")
def library_calls() -> dict[str, list]:
    runs = {name: record_calls(name) for name in ATO_SCENARIOS}
    runs["ato_nominal+faults"] = record_calls("ato_nominal", Faults(NOMINAL_FAULTS))
    runs["ato_line+faults"] = record_calls("ato_line", Faults(LINE_FAULTS))
    return runs


@pytest.fixture(scope="module")
def library_ops(library_calls) -> dict[str, tuple[list, list]]:
    out = {}
    for name, controllers in library_calls.items():
        for k, calls in enumerate(controllers):
            out[f"{name}/{k}"] = gate_ops(calls)
    return out


def test_library_calls_cover_the_paths(library_calls):
    """The recorded calls meet what the comparison is for: sane running, every kind of safe
    brake, holds and releases (else the comparison below proves little)."""
    calls = [c for runs in library_calls.values() for ctrl in runs for c in ctrl[1:]]
    assert len(calls) > 12000
    reasons = {reason_code(c["safes"][0][0]) for c in calls if c["safes"]}
    assert reasons >= {1, 2, 6, 10, 12, 13, 5, 11, 14, 16, 17, 18}, sorted(reasons)
    assert sum(c["released"] is not None for c in calls) >= 10
    clean = [c for name in ATO_SCENARIOS for ctrl in library_calls[name] for c in ctrl[1:]]
    assert not any(c["safes"] for c in clean)        # the library itself runs sane
    assert any(c["state"]["pushing"] for c in clean)  # a traction command at rest (departure)


def test_the_c_gate_gives_the_controller_s_verdicts_on_the_library(lib, library_ops):
    for name, (ops, expected) in library_ops.items():
        rows, texts = c_apply(lib, np.array(ops))
        diff = differences(lib, expected, rows, texts)
        assert not diff, f"{name}:\n" + "\n".join(diff)


# ------------------------------------------------------------------ the catalogue

def sane(k: int, step: float = 0.1, v: float = 10.0, s0: float = 100.0, **changes) -> list[float]:
    """INPUTS of a car at v [m/s] from s0 [m], call k, with changes (by INPUTS name)."""
    x = {"filter.speed": v, "filter.position": s0 + v * k * step, "filter.speed_std": 0.05,
         "est.mass": MASS, "est.A0": 1.0, "est.A1": 0.03, "est.A2": 0.01, "est.status": 1.0,
         "est.samples": 50.0 + k, "filter.position_std": 0.1}
    x.update(changes)
    return [float(x[n]) for n in INPUTS]


def up(x: float) -> float:
    return math.nextafter(x, math.inf)


def down(x: float) -> float:
    return math.nextafter(x, -math.inf)


def single_value_cases() -> list[list[list[float]]]:
    """Three sane calls at rest, then one with a value at a bound or one ulp beyond it."""
    lo, hi = MASS / MASS_FACTOR, MASS * MASS_FACTOR
    rest = {"filter.speed": 0.0, "filter.position": 0.0}
    values = {
        "filter.speed": [-NOISE_SIGMA * 0.05, down(-NOISE_SIGMA * 0.05), MAX_SPEED, up(MAX_SPEED),
                         -0.0, 5e-324, -1e300],
        "filter.position": [-NOISE_SIGMA * 0.1, down(-NOISE_SIGMA * 0.1), MAX_DISTANCE,
                            up(MAX_DISTANCE), -0.0, -1.7976931348623157e308],
        "filter.speed_std": [0.0, -0.0, -5e-324, MAX_SPEED, up(MAX_SPEED), 1e300],
        "filter.position_std": [0.0, -0.0, -5e-324, MAX_DISTANCE, up(MAX_DISTANCE)],
        "est.mass": [lo, down(lo), hi, up(hi), 0.0, -0.0, -30.0, 3e4, 1.7976931348623157e308],
        "est.A0": [1000.0, up(1000.0), -1000.0, down(-1000.0), -1e300],
        "est.A1": [100.0, up(100.0), -100.0, down(-100.0)],
        "est.A2": [10.0, up(10.0), -10.0, down(-10.0), 123456.789],
        "est.status": [0.0, -0.0, 1.0, 2.0, 3.0, up(3.0), down(0.0), 0.5, 4.0, -1.0, 1e20],
        "est.samples": [0.0, -0.0, -5e-324, MAX_SAMPLES, up(MAX_SAMPLES), 2.5, 1e300, -1e308,
                        2 ** 31 - 1],
    }
    cases = []
    for name, vs in values.items():
        for v in vs:
            for at_rest in (True, False):
                base = rest if at_rest else {}
                ops = [op(INIT, 0.0, [MASS])]
                ops += [op(CHECK, k * 0.1, sane(k, **base)) for k in range(3)]
                ops.append(op(CHECK, 0.3, sane(3, **{**base, name: v})))
                ops.append(op(CHECK, 0.4, sane(4, **base)))
                cases.append(ops)
    # car masses whose bounds round: lo = mass / 10 and hi = mass x 10 inexact
    for mass in (0.3, 33.3, 1e-300, 7.0, 1.7976931348623157e307):
        for m in (mass / MASS_FACTOR, mass * MASS_FACTOR):
            for v in (m, up(m), down(m)):
                cases.append([op(INIT, 0.0, [mass]), op(CHECK, 0.0, sane(0, **{"est.mass": v}))])
    return cases


def time_cases() -> list[list[list[float]]]:
    cases = []
    for t0 in (0.0, 1.0, 123.456, 1e15, -50.0):
        for dt in (0.0, -0.0, 5e-324, -1e-9, -1.0, MAX_CALL_GAP, up(MAX_CALL_GAP),
                   down(MAX_CALL_GAP), 1e300, 0.1):
            t1 = t0 + dt
            for t2 in (up(t1), t1 + 0.1, t0 + 0.1):
                cases.append([op(INIT, 0.0, [MASS]), op(CHECK, t0, sane(0)),
                              op(CHECK, t1, sane(1)), op(CHECK, t2, sane(2)),
                              op(CHECK, up(t2), sane(3))])
    cases.append([op(INIT, 0.0, [MASS]), op(CHECK, 5.0, sane(0)), op(CHECK, 4.0, sane(1)),
                  op(CHECK, 3.0, sane(2)), op(CHECK, 5.0, sane(3)), op(CHECK, 5.1, sane(4))])
    return cases


def window_threshold_times(t0: float, span: float) -> list[float]:
    """Times around t0 + (span - 1e-9): where t - t0 >= span - 1e-9 switches, and a few ulps."""
    t = t0 + (span - 1e-9)
    out = [t]
    for _ in range(3):
        out = [down(out[0])] + out + [up(out[-1])]
    return out


def consistency_cases() -> list[list[list[float]]]:
    """The tolerance at equality (advance - travel == tol exactly: sane; one ulp more: not) for
    random stds and times, and the window's restart around CONSISTENCY_WINDOW - 1e-9."""
    rng = random.Random(30)
    cases = []
    for _ in range(300):
        psd0, psd, sd = rng.uniform(0.0, 2.0), rng.uniform(0.0, 2.0), rng.uniform(0.001, 1.0)
        dt = rng.choice([0.1, 0.2, 0.3, rng.uniform(0.01, 1.9)])
        t0 = rng.choice([0.0, rng.uniform(0, 1000)])
        t1 = t0 + dt
        tol = NOISE_SIGMA * (psd0 + psd + sd * (t1 - t0)) + 1.0
        s0 = rng.choice([0.0, 0.0, rng.uniform(0, 1000)])
        for s1 in (s0 + tol, up(s0 + tol), s0 - tol, down(s0 - tol)):
            x0 = sane(0, v=0.0, s0=s0, **{"filter.speed_std": sd, "filter.position_std": psd0})
            x1 = sane(0, v=0.0, s0=s1, **{"filter.speed_std": sd, "filter.position_std": psd})
            cases.append([op(INIT, 0.0, [MASS]), op(CHECK, t0, x0), op(CHECK, t1, x1)])
    for t0 in (0.0, 0.7, 1e6 + 0.3):
        for t in window_threshold_times(t0, CONSISTENCY_WINDOW):
            ops = [op(INIT, 0.0, [MASS]), op(CHECK, t0, sane(0, v=5.0))]
            ops.append(op(CHECK, t, sane(0, v=5.0, s0=100.0 + 5.0 * (t - t0))))
            ops.append(op(CHECK, t + 0.5, sane(0, v=5.0, s0=100.0 + 5.0 * (t + 0.5 - t0) + 3.0)))
            cases.append(ops)
    # a speed cut, a position frozen, a correction within the tolerance, over 40 calls
    for change in ({"filter.speed": 0.0}, {"filter.position": 102.0}, {}):
        ops = [op(INIT, 0.0, [MASS])]
        for k in range(40):
            x = sane(k, **(change if k >= 3 else {}))
            if not change:
                x[1] += 0.1 * k
            ops.append(op(CHECK, k * 0.1, x))
        cases.append(ops)
    return cases


def response_cases() -> list[list[list[float]]]:
    """Traction at rest: refused at RESPONSE_TIME (around its 1e-9 margin), held while the
    inputs do not move, released when they move; no traction, or the car responding: never."""
    rest = sane(0, v=0.0, s0=0.0, **{"filter.speed_std": 0.0, "filter.position_std": 0.0})
    cases = []
    for t0 in (0.0, 0.1, 12.3, 1e9):
        for t in window_threshold_times(t0, RESPONSE_TIME):
            ops = [op(INIT, 0.0, [MASS]), op(CHECK, t0, rest), op(NOTE, 0.0, [1000.0])]
            ops += [op(CHECK, t0 + 1.0, rest), op(NOTE, 0.0, [2000.0])]
            ops += [op(CHECK, t, rest), op(NOTE, 0.0, [2000.0])]
            ops += [op(CHECK, t + 0.1, rest), op(NOTE, 0.0, [0.0]), op(CHECK, t + 0.2, rest)]
            moved = list(rest)
            moved[1] = 0.01
            moved[2], moved[9] = 0.01, 0.01
            ops += [op(CHECK, t + 0.3, moved), op(CHECK, t + 0.4, rest)]
            cases.append(ops)
    for traction in (0.0, -1.0, 5e-324, 1e6):
        ops = [op(INIT, 0.0, [MASS])]
        for k in range(50):
            ops += [op(CHECK, k * 0.1, rest), op(NOTE, 0.0, [traction])]
        cases.append(ops)
    # the command before any check, after a refused call, with the car moving
    cases.append([op(INIT, 0.0, [MASS]), op(NOTE, 0.0, [1.0]), op(CHECK, 0.0, rest),
                  op(CHECK, 0.1, sane(1, **{"est.mass": -1.0})), op(NOTE, 0.0, [1.0]),
                  op(CHECK, 0.2, sane(2)), op(NOTE, 0.0, [1.0]), op(CHECK, 3.5, sane(3))])
    # a moved position ends a push: a push that starts again is timed from its new start
    ops = [op(INIT, 0.0, [MASS])]
    for k in range(80):
        x = list(rest)
        x[1] = 0.0 if k < 20 else 0.5
        ops += [op(CHECK, k * 0.1, x), op(NOTE, 0.0, [100.0])]
    cases.append(ops)
    return cases


def random_cases(n_cases: int = 60, n_ops: int = 300) -> list[list[list[float]]]:
    """Seeded random sequences: a car at rest, accelerating, cruising, braking, with random
    insane values, time steps (some backwards, some beyond the gap) and commands."""
    rng = random.Random(7)
    nasty = [0.0, -0.0, 5e-324, -5e-324, 1e-300, -1.0, 1.0, 3.0, 4.0, 1e9, up(1e9), 200.0,
             up(200.0), 1e7, up(1e7), -1e300, 1e300, 1.7976931348623157e308, 0.5, 0.1, 2.0]
    cases = []
    for _ in range(n_cases):
        mass = rng.choice([30.0, 24.0, 44.0, rng.uniform(1, 1000)])
        ops = [op(INIT, 0.0, [mass])]
        t, s, v = rng.choice([0.0, rng.uniform(0, 1e4)]), 0.0, 0.0
        for _ in range(n_ops):
            r = rng.random()
            dt = (0.1 if r < 0.7 else rng.choice([0.0, -0.1, 0.05, 1.0, 9.99, 10.0, 10.01, 30.0,
                                                  rng.uniform(0, 3)]))
            t += dt
            a = rng.choice([0.0, 0.0, 0.5, -0.5, 1.0])
            v = max(0.0, v + a * max(dt, 0.0))
            s += v * max(dt, 0.0)
            sd = 0.0 if v == 0.0 and rng.random() < 0.5 else rng.uniform(0.0, 0.3)
            x = [v, s + rng.gauss(0, 0.1), sd, mass * rng.uniform(0.8, 1.2), rng.gauss(1, 0.5),
                 rng.gauss(0.03, 0.02), rng.gauss(0.01, 0.005), float(rng.choice([0, 1, 2, 3])),
                 float(rng.randrange(0, 10000)), rng.uniform(0.0, 0.5)]
            if rng.random() < 0.1:
                x[rng.randrange(len(INPUTS))] = rng.choice(nasty)
            if rng.random() < 0.05:
                x[0] = 0.0
            ops.append(op(CHECK, t, x))
            if rng.random() < 0.8:
                ops.append(op(NOTE, 0.0, [rng.choice([0.0, 0.0, 1e4, -1.0, 5e-324])]))
        cases.append(ops)
    return cases


CATALOGUE = {"single_values": single_value_cases, "time": time_cases,
             "consistency": consistency_cases, "response": response_cases,
             "random": random_cases}


@pytest.mark.parametrize("family", CATALOGUE)
def test_the_c_supervisor_gives_python_s_verdicts_texts_and_state(lib, family):
    cases = CATALOGUE[family]()
    found = set()
    for ops in cases:
        expected = py_apply(ops)
        found |= {e.reason for e in expected}
        assert_same(lib, ops, expected)
    want = {"single_values": {0, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13},
            "time": {0, 1, 2}, "consistency": {0, 14}, "response": {0, 15},
            "random": {0, 1, 2, 10, 12, 13, 14}}[family]
    assert found >= want, f"{family}: reasons met {sorted(found)}"


class ControllerCalls:
    """A controller (models.ato.controller) fed crafted inputs, each call recorded as
    record_calls records them."""

    def __init__(self):
        self.car = CarTraction()
        self.ctrl = AtoController(Span(2200.0, 135.0, stop=2150.0), self.car)
        self.calls: list[dict] = []

    def __call__(self, t: float, inputs: dict) -> None:
        ctrl, safe, check = self.ctrl, AtoController._safe, InputSupervisor.check
        c = {"t": t, "inputs": [math.nan if inputs.get(n) is None else float(inputs[n])
                                for n in ALL_INPUTS], "safes": [], "values": None}

        def rec_safe(self_, t_, reason, key):
            c["safes"].append((reason, key))
            return safe(self_, t_, reason, key)

        def rec_check(self_, t_, x):
            c["values"] = [float(v) for v in x]
            return check(self_, t_, x)

        AtoController._safe, InputSupervisor.check = rec_safe, rec_check
        try:
            n_events = len(ctrl.events)
            cmd = ctrl.demands(t, {n: v for n, v in inputs.items() if v is not None})
        finally:
            AtoController._safe, InputSupervisor.check = safe, check
        rel = [e for _, e in ctrl.events[n_events:] if "released" in e]
        c["released"] = rel[0] if rel else None
        c["traction"] = None if c["safes"] else cmd.traction
        c["mode"] = cmd.mode
        c["state"] = py_state(ctrl.supervisor, ctrl)
        self.calls.append(c)

    def ops(self):
        return gate_ops([self.car.mass] + self.calls)


def rolling(t: float, **changes) -> dict:
    """ALL_INPUTS of a car rolling at 1 m/s (position = t), with changes (dots as __)."""
    x = dict(zip(ALL_INPUTS, [1.0, t, 0.05, 30.0, 1.0, 0.03, 0.01, 1.0, 500.0, 0.1]
                 + [p for _, p in STATED_INPUTS]))
    x.update({n.replace("__", "."): v for n, v in changes.items()})
    return x


def test_gate_catalogue_through_a_controller(lib):
    """Crafted calls through controllers: every INPUTS value and the time NaN, -NaN, +-inf; the
    stated inputs bad or absent (their prior); a fault then sane for less and more than
    RECOVERY_TIME; flicker; inputs that stay at rest under traction (dead until they move).
    The C gate replays each controller's calls."""
    bad = [math.nan, math.inf, -math.inf, -math.nan]
    moving = ControllerCalls()
    now = 0.0

    def call(dt=0.1, t=None, **changes):
        nonlocal now
        now += dt
        moving(now if t is None else t, rolling(now, **changes))

    for name in INPUTS:
        for b in bad:
            call(**{name.replace(".", "__"): b})
    for b in bad:
        call(t=b)                                     # time not finite
    for name, _ in STATED_INPUTS:
        for b in (*bad, None, -5.0, 1e300):
            call(**{name.replace(".", "__"): b})
    for hold in (0.5, 0.9, 0.95, 1.0, 1.05, 2.0):    # a fault, then sane for about `hold` s
        call(est__mass=-1.0)
        for _ in range(int(round(hold / 0.05)) + 3):
            call(0.05)
    for j in range(40):                               # flicker
        call(est__status=9.0 if j % 2 else 1.0)
    for _ in range(30):
        call()
    standing = ControllerCalls()                      # at rest under traction: not connected?
    rest = dict(rolling(0.0), **{"filter.speed": 0.0, "filter.position": 0.0,
                                 "filter.speed_std": 0.0, "filter.position_std": 0.0,
                                 "est.status": 0.0, "est.samples": 0.0})
    for k in range(60):
        standing(0.1 * k, rest)
    for k in range(60, 80):
        standing(0.1 * k, dict(rest, **{"filter.speed": 0.1, "filter.speed_std": 0.01,
                                        "filter.position": 0.01 * (k - 59),
                                        "filter.position_std": 0.01}))
    reasons, released = set(), 0
    for calls in (moving, standing):
        ops, expected = calls.ops()
        reasons |= {e.reason for e in expected}
        released += sum(e.code == GATE_RUN_RELEASED for e in expected)
        rows, texts = c_apply(lib, np.array(ops))
        diff = differences(lib, expected, rows, texts)
        assert not diff, "\n".join(diff)
    assert reasons >= {0, 10, 12, 15, 16, 17, 18}, sorted(reasons)
    assert released >= 5


# ------------------------------------------------------------------ formats and limits

def test_printf_writes_floats_as_python_s_format_specs(tmp_path):
    """The messages format floats by printf's %g, %.3g, %.4g, %.6g, %.3f, %.0f, %.0e: Python's
    :g, .3g, ... write the same characters (finite values, both correctly rounded)."""
    src = tmp_path / "fmt.c"
    src.write_text('#include <stdio.h>\n#include <stdlib.h>\n'
                   'int main(int c, char **v) { double x; char s[8];\n'
                   '  while (scanf("%7s %lf", s, &x) == 2) { char f[16]; snprintf(f, sizeof f, "%%%s\\n", s);'
                   ' printf(f, x); }\n  (void)c; (void)v; return 0; }\n')
    exe = tmp_path / "fmt"
    proc = subprocess.run([shutil.which("gcc"), "-std=c99", "-O2", str(src), "-o", str(exe)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    rng = random.Random(11)
    values = [0.0, -0.0, 5e-324, 1.7976931348623157e308, 0.5, 1.5, 2.5, 0.0005, 9.9995, 99.95,
              1e-5, 1e16, 123456.5, 2 ** 31 - 1, 1e9, -0.0004999]
    values += [rng.uniform(-1, 1) * 10 ** rng.randint(-12, 20) for _ in range(3000)]
    values += [struct.unpack("<d", struct.pack("<Q", rng.getrandbits(63)))[0] for _ in range(500)]
    values = [v for v in values if math.isfinite(v)]
    specs = ["g", ".3g", ".4g", ".6g", ".3f", ".0f", ".0e"]
    lines = [(s, v) for v in values for s in specs]
    out = subprocess.run([str(exe)], input="".join(f"{s} {v!r}\n" for s, v in lines),
                         capture_output=True, text=True).stdout.splitlines()
    assert len(out) == len(lines)
    bad = [(s, v, c, format(v, s)) for (s, v), c in zip(lines, out) if c != format(v, s)]
    assert not bad, bad[:5]


def test_the_longest_texts_fit(lib):
    """The longest messages reachable (a 309-digit est.samples, the largest reprs) fit in the
    512-character text with ": safe brake" after them."""
    huge = -1.7976931348623157e308
    ops = [op(INIT, 0.0, [MASS]), op(GATE, 0.0, [*sane(0, **{"est.samples": huge}),
                                                 *[p for _, p in STATED_INPUTS]])]
    rows, texts = c_apply(lib, np.array(ops))
    sup = InputSupervisor(MASS)
    want = sup.check(0.0, sane(0, **{"est.samples": huge}))[1] + ": safe brake"
    assert texts[1] == want and len(want) > 400


# ------------------------------------------------------------------ sanitizers and mutation

def all_ops(library_ops) -> list[tuple[str, list, list]]:
    cases = [(name, ops, exp) for name, (ops, exp) in library_ops.items()]
    for family, make in CATALOGUE.items():
        for k, ops in enumerate(make()):
            cases.append((f"{family}/{k}", ops, None))
    return cases


def test_the_shim_program_under_sanitizers(lib, library_ops, tmp_path):
    exe = tmp_path / "ato_supervision"
    build(exe, [*SANITIZE, "-DATO_SUPERVISION_MAIN"])
    ops = [o for _, case, _ in all_ops(library_ops) for o in case]
    path = tmp_path / "ops.in"
    np.array(ops, dtype="<f8").tofile(path)
    proc = subprocess.run([str(exe), str(path), str(tmp_path / "ops.out")], capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr[-3000:]
    raw = (tmp_path / "ops.out").read_bytes()
    n = len(ops)
    rows = np.frombuffer(raw[:8 * ROW_SIZE * n], dtype="<f8").reshape(n, ROW_SIZE)
    want_rows, want_texts = c_apply(lib, np.array(ops))
    assert rows.tobytes() == want_rows.tobytes()
    texts = raw[8 * ROW_SIZE * n:]
    got = [texts[k * 512:(k + 1) * 512].split(b"\0", 1)[0].decode() for k in range(n)]
    assert got == want_texts


MUTATIONS = {
    # the trapezoid of the speeds over the window
    "travel": ("s->travel += 0.5 * (s->v_last + v) * (t - s->t_prev);",
               f"s->travel += 0.5 * (s->v_last + v) * (t - s->t_prev) * {ONE_ULP};"),
    # the tolerance, re-associated
    "tolerance": ("(psd0 + psd + s->sd_max * (t - t0))", "(psd0 + (psd + s->sd_max * (t - t0)))"),
    # the backwards bound of filter.speed
    "backwards": ("if (v < -ATO_NOISE_SIGMA * sd) {", f"if (v < -ATO_NOISE_SIGMA * sd * {ONE_ULP}) {{"),
    # est.mass's lower bound
    "mass_low": ("double lo = s->mass / ATO_MASS_FACTOR,",
                 f"double lo = s->mass * {ONE_ULP} / ATO_MASS_FACTOR,"),
}


@pytest.mark.parametrize("mutation", MUTATIONS)
def test_a_one_ulp_mutation_fails_the_comparison(mutation, library_ops, tmp_path):
    target, replacement = MUTATIONS[mutation]
    text = (CORE / "ato_supervision.c").read_text()
    assert text.count(target) == 1, f"the mutation's target occurs {text.count(target)} times"
    mutated = tmp_path / "ato_supervision.c"
    mutated.write_text(text.replace(target, replacement))
    for h in CORE.glob("*.h"):
        shutil.copy(h, tmp_path / h.name)
    so = tmp_path / "libmutant.so"
    build(so, ["-shared"], [mutated, CORE / "ato_tuning.c", CORE / "repr.c"])
    dll = load(so)
    caught = []
    for name, ops, expected in all_ops(library_ops):
        expected = expected if expected is not None else py_apply(ops)
        rows, texts = c_apply(dll, np.array(ops))
        if differences(dll, expected, rows, texts, limit=1):
            caught.append(name)
    assert caught, f"{mutation}: every case still equals Python's"
