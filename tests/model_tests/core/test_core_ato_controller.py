"""The C ATO controller (models/core/ato_controller.c) against models/ato/controller.py's
AtoController, bit for bit and word for word (issue 30).

Driven through tests/core_cases/ato_controller_shim.c:

- every library ATO scenario (scenarios/library/ato_*.toml; ato_line's three spans each by its own
  controller, models/ato/line.py staying in Python) in the Python closed loop (harness
  run_on_chain), every demands() call recorded with what the controller saw; a C controller per
  span replays the calls: each command's traction, brake, planned speed (bits), mode, EP stage and
  the finished flag equal at every step, and the event log (t by its bits, the text exactly);
- the same scenarios in a closed loop driven by the C controllers themselves: the run's every
  output and input equal to the Python loop's, bit for bit;
- faults injected into what the controllers read (NaN inputs, est.* garbage that the supervisor
  refuses, est.* far off but sane, est.status flickering): the same replay;
- the construction refusals (the grid cap, an infeasible or too long schedule, an early initial
  plan, the EP stage, a climb the car cannot make, a limit the margin leaves nothing of, bad
  tuning) word for word;
- models/ato/line.py's LineController as ato_line.c: ato_line replayed (also with faults), the
  closed loop driven by the C line, its refusals;
- the shim as a program under -fsanitize=address,undefined replaying scenarios (a settling stop,
  faults, the line): the same commands, no report;
- a one-ulp mutation of a controller or line expression makes the replay fail.
"""
from __future__ import annotations

import ctypes
import dataclasses
import logging
import math
import random
import shutil
import struct
import subprocess
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from harness.run.driver import run_on_chain
from harness.run.scenario import load_scenario
from models.ato.controller import AtoController
from models.ato.interface import ALL_INPUTS, AtoCommand, AtoTuning
from models.ato.line import STATION_STOPS, LineController, LineSpan, LineStep
from models.ato.planner import fastest_run
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_controller_shim.c"
SOURCES = [CORE / f for f in ("ato_controller.c", "ato_line.c", "ato_supervision.c", "ato_tuning.c",
                              "ato_span.c", "track.c", "ato_motion.c", "ato_stopping.c",
                              "ato_planner.c", "repr.c", "rc_bytes.c")]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
         "-fPIC"]
SANITIZE = ["-g", "-O1", "-fsanitize=address,undefined", "-fno-sanitize-recover=all"]
ONE_ULP = "(1.0 + 2.220446049250313e-16)"
ATO_SCENARIOS = ("ato_nominal", "ato_A0_plus50", "ato_headwind", "ato_line", "ato_mass_plus20",
                 "ato_speed_noise", "ato_wet_rail")
TEXT = 512
CAR_FIELDS = [f.name for f in dataclasses.fields(CarTraction) if f.init]
TUNING_FIELDS = [f.name for f in dataclasses.fields(AtoTuning)]


# ------------------------------------------------------------------ the C side

def build(out: Path, extra: list[str], sources=SOURCES) -> None:
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    proc = subprocess.run([gcc, *FLAGS, *extra, f"-I{CORE}", *map(str, sources), str(SHIM), "-o",
                           str(out), "-lm"], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr


def load(path: Path):
    dll = ctypes.CDLL(str(path))
    vp, D = ctypes.c_void_p, ctypes.POINTER(ctypes.c_double)
    dll.shim_new.argtypes = [D, D, D, ctypes.c_int, D, D, ctypes.c_int, D, D,
                             ctypes.POINTER(ctypes.c_int), ctypes.c_char_p]
    dll.shim_new.restype = vp
    dll.shim_free.argtypes = [vp]
    dll.shim_demands.argtypes = [vp, ctypes.c_double, D, D]
    dll.shim_event.argtypes = [vp, ctypes.c_long, D, ctypes.c_char_p]
    dll.shim_event.restype = ctypes.c_int
    dll.shim_state.argtypes = [vp, D]
    dll.shim_line_new.argtypes = [ctypes.c_int, D, ctypes.c_int, D, D, ctypes.POINTER(ctypes.c_int),
                                  ctypes.c_char_p]
    dll.shim_line_new.restype = vp
    dll.shim_line_free.argtypes = [vp]
    dll.shim_line_demands.argtypes = [vp, ctypes.c_double, D, ctypes.c_double, D]
    dll.shim_line_departures.argtypes = [vp, D]
    dll.shim_line_event.argtypes = [vp, ctypes.c_int, ctypes.c_long, D, ctypes.c_char_p]
    dll.shim_line_event.restype = ctypes.c_int
    dll.shim_line_n_events.argtypes = [vp, ctypes.c_int]
    dll.shim_line_n_events.restype = ctypes.c_long
    assert dll.shim_sizes() == TEXT
    return dll


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    out = tmp_path_factory.mktemp("core") / "libato_controller.so"
    build(out, ["-shared"])
    return load(out)


def arr(values) -> ctypes.Array:
    values = [float(v) for v in values]
    return (ctypes.c_double * max(len(values), 1))(*values)


def header(span: Span, car: CarTraction, tuning: AtoTuning) -> list[float]:
    """The shim's construction arguments, flat (also the sanitizer program's file header)."""
    g = span.grade
    return ([span.length, span.schedule, span.stop, len(g.distances), *g.distances, *g.grades,
             len(span.limit_distances), *span.limit_distances, *span.limit_speeds]
            + [float(getattr(car, n)) for n in CAR_FIELDS]
            + [float(getattr(tuning, n)) for n in TUNING_FIELDS])


class CController:
    """One C controller; ``refusal``: (status, text) where the C construction refused."""

    def __init__(self, lib, span: Span, car: CarTraction, tuning, tuning_values=None):
        self.lib = lib
        values = tuning_values or [float(getattr(tuning, n)) for n in TUNING_FIELDS]
        status, msg = ctypes.c_int(), ctypes.create_string_buffer(TEXT)
        g = span.grade
        self.h = lib.shim_new(arr([span.length, span.schedule, span.stop]), arr(g.distances),
                              arr(g.grades), len(g.grades), arr(span.limit_distances),
                              arr(span.limit_speeds), len(span.limit_speeds),
                              arr(getattr(car, n) for n in CAR_FIELDS), arr(values),
                              ctypes.byref(status), msg)
        self.refusal = None if self.h else (status.value, msg.value.decode())
        self.n_events = 0

    def demands(self, t: float, inputs) -> tuple:
        """(traction, brake, mode, planned_speed, ep_stage, finished, n_events,
        predicted arrival, replans, using_estimates)"""
        out = (ctypes.c_double * 10)()
        self.lib.shim_demands(self.h, t, arr(inputs), out)
        return (out[0], out[1], int(out[2]), out[3], int(out[4]), bool(out[5]), int(out[6]),
                out[7], int(out[8]), bool(out[9]))

    def event(self, k: int) -> tuple[float, str]:
        return self.coded_event(k)[:2]

    def coded_event(self, k: int) -> tuple[float, str, int]:
        """(t, text, ato_event_code) of event k"""
        t, text = ctypes.c_double(), ctypes.create_string_buffer(TEXT)
        code = self.lib.shim_event(self.h, k, ctypes.byref(t), text)
        assert code >= 0, f"event {k} left the ring"
        return t.value, text.value.decode(), code

    def state(self) -> list[float]:
        out = (ctypes.c_double * 8)()
        self.lib.shim_state(self.h, out)
        return list(out)

    def __del__(self):
        if getattr(self, "h", None):
            self.lib.shim_free(self.h)


def bits(x: float) -> bytes:
    return struct.pack("<d", float(x))


# ------------------------------------------------------------------ the Python side

def seen_inputs(outputs) -> list[float]:
    return [math.nan if outputs.get(n) is None else float(outputs.get(n)) for n in ALL_INPUTS]


def published(ctrl: AtoController) -> tuple:
    """What the FMU publishes from the controller besides the command (fmu_src/ato_controller.py
    _publish): ato.predicted_arrival, ato.replans, ato.using_estimates"""
    return float(ctrl.plan.arrival), int(ctrl.replans), bool(ctrl.using_estimates)


def record(name: str, faults=None) -> list[dict]:
    """The scenario in the Python closed loop; per controller (span order): its span, car, tuning,
    calls [(t, inputs, command tuple, finished, number of events)] and events."""
    runs: dict[int, dict] = {}
    demands = AtoController.demands

    def rec(self, t, outputs):
        seen = {n: outputs.get(n) for n in ALL_INPUTS}
        if faults is not None:
            t, seen = faults(t, seen)
        inputs = [math.nan if v is None else float(v) for v in seen.values()]
        cmd = demands(self, t, {n: v for n, v in seen.items() if v is not None})
        run = runs.setdefault(id(self), {"span": self.span, "car": self.car,
                                         "tuning": self.tuning, "calls": [],
                                         "events": self.events, "ctrl": self})
        run["calls"].append((t, inputs, (cmd.traction, cmd.brake, int(cmd.mode),
                                         cmd.planned_speed, int(cmd.ep_stage)),
                             self.finished, len(self.events), published(self)))
        return cmd

    AtoController.demands = rec
    try:
        run_on_chain(load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml"))
    finally:
        AtoController.demands = demands
    return list(runs.values())


def replay_differences(lib, run: dict, limit: int = 5) -> list[str]:
    """Where the C controller's replay of a recorded run differs from Python's (step, field)."""
    c = CController(lib, run["span"], run["car"], run["tuning"])
    assert c.refusal is None, c.refusal
    out, seen = [], 0
    events = run["events"]
    for k, (t, inputs, want, finished, n_events, *extra) in enumerate(run["calls"]):
        got = c.demands(t, inputs)
        if extra and (bits(got[7]), got[8], got[9]) != (bits(extra[0][0]), *extra[0][1:]):
            out.append(f"step {k}: published C {got[7:]}, Python {extra[0]}")
        for j, field in enumerate(("traction", "brake", "mode", "planned_speed", "ep_stage")):
            if bits(got[j]) != bits(want[j]):
                out.append(f"step {k} (t = {t}): {field} C {got[j]!r}, Python {want[j]!r}")
        if got[5] != finished:
            out.append(f"step {k}: finished C {got[5]}, Python {finished}")
        if got[6] != n_events:
            out.append(f"step {k}: {got[6]} events in C, {n_events} in Python "
                       f"(Python's new: {events[seen:n_events]})")
        for e in range(seen, min(got[6], n_events)):
            te, text = c.event(e)
            if bits(te) != bits(events[e][0]) or text != events[e][1]:
                out.append(f"step {k}: event {e} C {(te, text)!r}, Python {events[e]!r}")
        seen = n_events
        if len(out) >= limit:
            return out
    ctrl = run.get("ctrl")
    if ctrl is not None:                   # the state the run ends in
        phases = ("run", "brake", "ep", "settle", "hold")
        want = [phases.index(ctrl.phase), ctrl.replans, ctrl.aim_offset, ctrl._gate,
                *ctrl.weights, ctrl.using_estimates, ctrl.relay.stop]
        got = c.state()
        for j, field in enumerate(("phase", "replans", "aim_offset", "gate", "w_m", "w_r",
                                   "using_estimates", "relay.stop")):
            if bits(got[j]) != bits(float(want[j])):
                out.append(f"at the end: {field} C {got[j]!r}, Python {want[j]!r}")
    return out


# ------------------------------------------------------------------ replays

@pytest.fixture(scope="module")
def recorded():
    return {name: record(name) for name in ATO_SCENARIOS}


@pytest.mark.parametrize("name", ATO_SCENARIOS)
def test_the_c_controller_replays_the_python_closed_loop_bit_for_bit(lib, recorded, name):
    runs = recorded[name]
    assert len(runs) == (3 if name == "ato_line" else 1)
    for k, run in enumerate(runs):
        assert run["calls"][-1][3], f"{name} span {k}: the Python controller never finished"
        assert replay_differences(lib, run) == [], f"{name} span {k}"


def test_the_replays_cover_every_phase_and_event_kind(recorded):
    """What the replays above compared: every mode but SAFE and SETTLE's, re-plans, events."""
    modes, texts, steps = set(), [], 0
    for runs in recorded.values():
        for run in runs:
            steps += len(run["calls"])
            modes |= {call[2][2] for call in run["calls"]}
            texts += [e for _, e in run["events"]]
    assert steps > 10_000
    assert {0, 1, 2, 3, 4, 7, 8} <= modes, modes       # TG, C, VB, SR, RK, EP, HOLD
    assert any("est.* usable" in e for e in texts)
    assert any(e.startswith("stopped") for e in texts)


# ------------------------------------------------------------------ variants: beyond the library

def _faults(t, seen):
    """NaN, est.* garbage the supervisor refuses, est.status flickering, est.A0 far off but sane,
    a stated input missing, a speed std jump (ST), each in its own window"""
    seen = dict(seen)
    if 30.0 <= t < 30.35:
        seen["filter.speed"] = math.nan
    if 50.0 <= t < 50.5:
        seen["est.mass"] = 1000.0
    if 60.0 <= t < 62.0:
        seen["est.status"] = 0.0
    if 70.0 <= t < 75.0:
        seen["est.A0"] = 30.0
    if 80.0 <= t < 82.0:
        seen["est.mass_std"] = None
    if 100.0 <= t < 100.3:
        seen["filter.speed_std"] = 1.0
    return t, seen


def _overspeed(t, seen):
    """filter.speed 6 m/s too high for 0.3 s at full speed: the supervisor's full brake"""
    seen = dict(seen)
    if 40.0 <= t < 40.3:
        seen["filter.speed"] = seen["filter.speed"] + 6.0
    return t, seen


def _inf_time_and_input(t, seen):
    """t and est.A1 not finite once each; est.samples running backwards (refused)"""
    seen = dict(seen)
    if 20.0 <= t < 20.05:
        t = math.inf
    if 25.0 <= t < 25.05:
        seen["est.A1"] = -math.inf
    if 35.0 <= t < 35.5:
        seen["est.samples"] = -5.0
    return t, seen


# (id, scenario, span change, tuning change, faults)
VARIANTS = (
    ("settle", "ato_speed_noise", None, lambda tn: replace(tn, settle_std=0.0), None),
    ("settle_line", "ato_line", None, lambda tn: replace(tn, settle_std=0.0, settle_time=2.0),
     None),
    ("late", "ato_mass_plus20", lambda s, c, tn: s.with_schedule(fastest_run(s, c, tn) + 0.3),
     None, None),
    ("faults", "ato_nominal", None, None, _faults),
    ("faults_noise", "ato_speed_noise", None, None, _faults),
    ("overspeed", "ato_nominal", None, None, _overspeed),
    ("not_finite", "ato_headwind", None, None, _inf_time_and_input),
    ("fixed_plan", "ato_A0_plus50", None, lambda tn: replace(tn, replan=False,
                                                              use_estimates=False), None),
)


def record_variant(name, span_of=None, tuning_of=None, faults=None) -> list[dict]:
    init = AtoController.__init__

    def new_init(self, span, car, tuning=None):
        tuning = AtoTuning() if tuning is None else tuning
        tuning = tuning_of(tuning) if tuning_of else tuning
        init(self, span_of(span, car, tuning) if span_of else span, car, tuning)

    AtoController.__init__ = new_init
    try:
        return record(name, faults)
    finally:
        AtoController.__init__ = init


@pytest.fixture(scope="module")
def variants():
    return {v[0]: record_variant(*v[1:]) for v in VARIANTS}


@pytest.mark.parametrize("variant", [v[0] for v in VARIANTS])
def test_the_c_controller_replays_settling_late_plans_and_faults_bit_for_bit(lib, variants,
                                                                            variant):
    for k, run in enumerate(variants[variant]):
        assert run["calls"][-1][3], f"{variant} span {k}: the Python controller never finished"
        assert replay_differences(lib, run) == [], f"{variant} span {k}"


def test_the_variants_reach_settle_creep_safe_overspeed_and_their_events(variants):
    modes = {call[2][2] for runs in variants.values() for run in runs for call in run["calls"]}
    assert {5, 9, 10, 11, 12} <= modes, modes            # ST, SAFE, OVERSPEED, CREEP, SETTLE
    texts = " | ".join(e for runs in variants.values() for run in runs for _, e in run["events"])
    for words in ("is not finite: safe brake", "is not a finite number", "of car.mass =",
                  "the safe brake is held", "the safe brake is released",
                  "estimates not usable (est.status = 0)", "stated sigmas from the configured",
                  "above the supervision curve", "standing", "settled:", "re-plan status late"):
        assert words in texts, words


# ------------------------------------------------------------------ seeded perturbations, open loop

def random_tuning(rng: random.Random) -> AtoTuning:
    """AtoTuning with a few settings drawn (within AtoTuning's bounds: redrawn until valid)"""
    while True:
        kw = {"settle_std": rng.choice([0.0, 0.05, 0.3]),
              "aim_sigma": rng.uniform(0.0, 3.0), "k_sigma": rng.uniform(1.0, 4.0),
              "gap_sigma": rng.uniform(0.0, 2.0), "replan_period": rng.choice([0.5, 1.0, 2.0, 5.0]),
              "time_reserve": rng.uniform(0.0, 0.05), "est_gate": rng.uniform(1.0, 6.0),
              "approach_gain": rng.uniform(0.2, 2.0), "min_samples": rng.choice([1, 50, 100]),
              "brake_integral_gain": rng.uniform(0.0, 1.0), "ep_stages": rng.randint(2, 8),
              "settle_time": rng.choice([0.0, 2.0, 5.0])}
        try:
            return AtoTuning(**kw)
        except ValueError:
            continue


def perturbed(rng: random.Random, calls) -> list[tuple[float, list[float]]]:
    """A recorded run's calls with seeded noise on what the controller reads: speeds and
    positions off, the stds scaled, est.* wandering, est.status flickering, a rare NaN"""
    out, drift, mass = [], 0.0, 0.0
    names = list(ALL_INPUTS)
    for t, inputs, *_ in calls:
        x = list(inputs)
        drift += rng.gauss(0.0, 0.02)
        mass += rng.gauss(0.0, 0.3)
        x[0] = x[0] * (1.0 + rng.gauss(0.0, 0.01)) + rng.gauss(0.0, 0.03)
        x[1] = x[1] + drift
        x[2] = x[2] * rng.uniform(0.5, 3.0)
        x[9] = x[9] * rng.uniform(0.5, 3.0)
        x[3] = x[3] + mass
        for j in (4, 5, 6):
            x[j] = x[j] * (1.0 + rng.gauss(0.0, 0.05))
        if rng.random() < 0.01:
            x[7] = float(rng.choice([0, 3]))
        if rng.random() < 0.003:
            x[rng.randrange(len(x))] = math.nan
        if rng.random() < 0.02:
            x[names.index("est.mass_std")] = math.nan
        out.append((t, x))
    return out


SEEDS = range(8)


@pytest.mark.parametrize("seed", SEEDS)
def test_seeded_perturbed_inputs_and_tunings_open_loop_are_python_s(lib, recorded, seed):
    """The Python and the C controller fed the same perturbed inputs (no loop: the car does not
    answer), with a drawn tuning: every command and event equal."""
    rng = random.Random(seed)
    name = ATO_SCENARIOS[seed % len(ATO_SCENARIOS)]
    base = recorded[name][0]
    tuning = random_tuning(rng)
    calls = perturbed(rng, base["calls"])
    py = AtoController(base["span"], base["car"], tuning)
    run = {"span": base["span"], "car": base["car"], "tuning": tuning, "events": py.events,
           "calls": [], "ctrl": py}
    for t, x in calls:
        cmd = py.demands(t, dict(zip(ALL_INPUTS, x)))
        run["calls"].append((t, x, (cmd.traction, cmd.brake, int(cmd.mode), cmd.planned_speed,
                                    int(cmd.ep_stage)), py.finished, len(py.events),
                             published(py)))
    assert replay_differences(lib, run) == [], f"seed {seed} ({name}, {tuning})"
    assert any(call[2][2] == 9 for call in run["calls"])          # the NaNs were met


def test_failing_re_plans_keep_the_last_plan_as_python_does(lib, recorded):
    """A 120 permille climb and est.mass three times the configured (heavier_mass takes it, to
    mass_band, even before est.* get weight): the re-plans fail (the car would stall), the last
    plan is kept and the failure is one episode (recorded and logged once), open loop on
    ato_nominal's inputs."""
    base = recorded["ato_nominal"][0]
    car = base["car"]
    span = Span(2200.0, 200.0, stop=2150.0,
                grade=GradeProfile((0.0, 1200.0, 1700.0), (0.0, 120.0, 0.0)))
    py = AtoController(span, car)
    run = {"span": span, "car": car, "tuning": py.tuning, "events": py.events, "calls": [],
           "ctrl": py}
    for t, inputs, *_ in base["calls"]:
        x = list(inputs)
        x[ALL_INPUTS.index("est.mass")] = 3.0 * car.mass
        x[ALL_INPUTS.index("est.mass_std")] = 0.01
        cmd = py.demands(t, dict(zip(ALL_INPUTS, x)))
        run["calls"].append((t, x, (cmd.traction, cmd.brake, int(cmd.mode), cmd.planned_speed,
                                    int(cmd.ep_stage)), py.finished, len(py.events),
                             published(py)))
    failed = [e for _, e in py.events if e.startswith("re-plan failed (no holding speed")]
    assert len(failed) == 1                   # one episode: recorded and logged once
    assert any(e.startswith("re-plan status early") for _, e in py.events)
    assert replay_differences(lib, run) == []


@pytest.mark.parametrize("use_estimates", [True, False])
def test_re_plan_events_carry_the_call_time_and_use_estimates_off_plans_the_configured_car(
        lib, recorded, use_estimates):
    """The climb above with the calls 100 s later (a span departing at t = 100 s, as a line's
    second span does): the re-plan events carry the call's time, not the time since departure
    (they once did); with ato.use_estimates off the configured car alone is planned, so
    est.mass three times heavier fails no re-plan (heavier_mass once took it anyway). C alike."""
    from dataclasses import replace as replaced
    base = recorded["ato_nominal"][0]
    car = base["car"]
    span = Span(2200.0, 200.0, stop=2150.0,
                grade=GradeProfile((0.0, 1200.0, 1700.0), (0.0, 120.0, 0.0)))
    py = AtoController(span, car, replaced(AtoTuning(), use_estimates=use_estimates))
    run = {"span": span, "car": car, "tuning": py.tuning, "events": py.events, "calls": [],
           "ctrl": py}
    for t, inputs, *_ in base["calls"]:
        x = list(inputs)
        x[ALL_INPUTS.index("est.mass")] = 3.0 * car.mass
        x[ALL_INPUTS.index("est.mass_std")] = 0.01
        cmd = py.demands(100.0 + t, dict(zip(ALL_INPUTS, x)))
        run["calls"].append((100.0 + t, x, (cmd.traction, cmd.brake, int(cmd.mode),
                                            cmd.planned_speed, int(cmd.ep_stage)),
                             py.finished, len(py.events), published(py)))
    failed = [t for t, e in py.events if e.startswith("re-plan failed")]
    assert len(failed) == (1 if use_estimates else 0)
    assert all(t >= 100.0 for t, _ in py.events), py.events
    assert replay_differences(lib, run) == []


# ------------------------------------------------------------------ the closed loop on C

# ato_controller.h's ato_event_code of the events AtoController._log records (once per episode)
# and logs: INPUT, RECOVERY, ESTIMATES, REPLAN_FAILED, OVERSPEED, INTERNAL
LOGGED_EVENTS = (0, 1, 3, 5, 10, 11)
CONTROLLER_LOG = logging.getLogger("models.ato.controller")


def run_with_c_controllers(lib, name: str):
    """The scenario on the models chain with every AtoController's demands made by a C
    controller (models/ato/line.py still sequences the spans)."""
    demands, ctrls = AtoController.demands, {}

    def c_demands(self, t, outputs):
        if id(self) not in ctrls:
            ctrls[id(self)] = (self, CController(lib, self.span, self.car, self.tuning))
        c = ctrls[id(self)][1]
        got = c.demands(t, seen_inputs(outputs))
        for k in range(len(self.events), got[6]):
            te, text, code = c.coded_event(k)
            self.events.append((te, text))
            if code in LOGGED_EVENTS:           # AtoController._log's: also logged
                CONTROLLER_LOG.warning("ATO at t = %.2f s: %s", te, text)
        if got[5]:
            self.phase = "hold"                  # AtoController.finished
        return AtoCommand(got[0], got[1], got[2], got[3], got[4])

    AtoController.demands = c_demands
    try:
        return run_on_chain(load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml")), ctrls
    finally:
        AtoController.demands = demands


@pytest.mark.parametrize("name", ATO_SCENARIOS)
def test_the_closed_loop_driven_by_the_c_controller_is_the_python_one(lib, name):
    want = run_on_chain(load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml"))
    got, ctrls = run_with_c_controllers(lib, name)
    assert len(ctrls) == (3 if name == "ato_line" else 1)
    assert got.time.tobytes() == want.time.tobytes()
    assert set(got.signals) == set(want.signals)
    for key in want.signals:
        assert got.signals[key].tobytes() == want.signals[key].tobytes(), key
    for key in want.inputs:
        assert got.inputs[key].tobytes() == want.inputs[key].tobytes(), key
    assert got.driver_log == want.driver_log


# ------------------------------------------------------------------ construction refusals

def _python_refusal(make) -> str:
    with pytest.raises(ValueError) as e:
        make()
    return str(e.value)


BASE_SPAN = Span(2200.0, 135.0, stop=2150.0)
BASE_CAR = CarTraction()
REFUSALS = (
    ("grid_cap", BASE_SPAN, BASE_CAR, {"grid_step": 1e-3}),
    ("grid_cap_long", Span(200_000.0, 9000.0, stop=199_000.0), BASE_CAR, {}),
    ("infeasible", BASE_SPAN.with_schedule(60.0), BASE_CAR, {}),
    ("too_long_huge", BASE_SPAN.with_schedule(1e20), BASE_CAR, {}),
    ("too_long", BASE_SPAN.with_schedule(4000.0), BASE_CAR, {}),
    ("climb", Span(2200.0, 300.0, stop=2150.0,
                   grade=GradeProfile((0.0, 500.0, 1400.0), (0.0, 150.0, 0.0))), BASE_CAR, {}),
    ("margin", Span(2200.0, 600.0, stop=2150.0, limit_distances=(0.0, 800.0),
                    limit_speeds=(20.0, 2.5)), BASE_CAR, {}),
    ("ep_stage", BASE_SPAN, replace(BASE_CAR, mech_force_max=20_000.0), {"a_ep": 1.2}),
    ("short_stop", Span(60.0, 60.0, stop=3.0), BASE_CAR, {}),
    ("grid_cap_shared_breaks", Span(2200.0, 135.0, stop=2150.0,
                                    grade=GradeProfile((0.0, 500.0, 1000.0), (0.0, 5.0, -5.0)),
                                    limit_distances=(0.0, 500.0, 1000.0 + BASE_CAR.length),
                                    limit_speeds=(20.0, 15.0, 20.0)), BASE_CAR,
     {"grid_step": 0.215}),
    ("low_limit_zone", Span(2200.0, 300.0, stop=2150.0, limit_distances=(0.0, 1000.0),
                            limit_speeds=(20.0, 2.2)), BASE_CAR, {"limit_margin": 0.0}),
)


@pytest.mark.parametrize("case, span, car, kw", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_construction_refusals_are_python_s_word_for_word(lib, case, span, car, kw):
    tuning = AtoTuning(**kw)
    want = _python_refusal(lambda: AtoController(span, car, tuning))
    c = CController(lib, span, car, tuning)
    assert c.refusal is not None, f"{case}: C accepted what Python refuses: {want}"
    assert c.refusal[1] == want


def test_an_early_initial_plan_is_refused_word_for_word(lib):
    """A schedule below the slowest run's bound that the planner still cannot fill ("early")."""
    t_min = fastest_run(BASE_SPAN, BASE_CAR)
    t_slowest = t_min + BASE_SPAN.stop / 1.0
    found = 0
    for schedule in np.linspace(t_slowest - 200.0, t_slowest, 41):
        span = BASE_SPAN.with_schedule(float(schedule))
        try:
            AtoController(span, BASE_CAR)
            continue
        except ValueError as e:
            want = str(e)
        found += "still arrives after" in want
        c = CController(lib, span, BASE_CAR, AtoTuning())
        assert c.refusal is not None and c.refusal[1] == want
    assert found > 0


BAD_TUNING = (("ep_stages", 0), ("grid_step", -1.0), ("safe_brake", 0.0), ("mass_band", 7.0),
              ("k_sigma", math.nan))


@pytest.mark.parametrize("field, value", BAD_TUNING)
def test_bad_tuning_is_refused_as_ato_tuning_refuses_it(lib, field, value):
    want = _python_refusal(lambda: AtoTuning(**{field: value}))
    values = [float(getattr(AtoTuning(), n)) for n in TUNING_FIELDS]
    values[TUNING_FIELDS.index(field)] = float(value)
    c = CController(lib, BASE_SPAN, BASE_CAR, None, tuning_values=values)
    assert c.refusal is not None and c.refusal[1] == want


# ------------------------------------------------------------------ the line (models/ato/line.py)

def line_flat(spans) -> list[float]:
    """shim_line_new's spans, flat"""
    flat = []
    for ls in spans:
        sp, g = ls.span, ls.span.grade
        flat += [sp.length, sp.schedule, sp.stop, len(g.distances), *g.distances, *g.grades,
                 len(sp.limit_distances), *sp.limit_distances, *sp.limit_speeds,
                 ls.dwell_s, ls.boarding_t]
    return flat


class CLine:
    """One C LineController; ``refusal``: (status, text) where the C construction refused."""

    def __init__(self, lib, spans, car: CarTraction, tuning: AtoTuning | None, tuning_values=None):
        self.lib, self.n = lib, len(spans)
        tuning = AtoTuning() if tuning is None else tuning
        values = tuning_values or [float(getattr(tuning, n)) for n in TUNING_FIELDS]
        flat = line_flat(spans)
        status, msg = ctypes.c_int(), ctypes.create_string_buffer(TEXT)
        self.h = lib.shim_line_new(len(spans), arr(flat), len(flat),
                                   arr(getattr(car, n) for n in CAR_FIELDS), arr(values),
                                   ctypes.byref(status), msg)
        self.refusal = None if self.h else (status.value, msg.value.decode())

    def demands(self, t: float, inputs, stops: float) -> tuple:
        """(t, span, traction, brake, mode, planned_speed, ep_stage, dwell, payload_change,
        finished, number of departures)"""
        out = (ctypes.c_double * 11)()
        self.lib.shim_line_demands(self.h, t, arr(inputs), stops, out)
        return tuple(out)

    def departures(self, n: int) -> list[float]:
        out = (ctypes.c_double * max(n, 1))()
        self.lib.shim_line_departures(self.h, out)
        return list(out)[:n]

    def events(self, i: int) -> list[tuple[float, str, int]]:
        out = []
        for k in range(self.lib.shim_line_n_events(self.h, i)):
            t, text = ctypes.c_double(), ctypes.create_string_buffer(TEXT)
            code = self.lib.shim_line_event(self.h, i, k, ctypes.byref(t), text)
            assert code >= 0, f"span {i} event {k} left the ring"
            out.append((t.value, text.value.decode(), code))
        return out

    def __del__(self):
        if getattr(self, "h", None):
            self.lib.shim_line_free(self.h)


def line_inputs(outputs) -> tuple[list[float], float]:
    stops = outputs.get(STATION_STOPS)
    return seen_inputs(outputs), math.nan if stops is None else float(stops)


def record_line(name: str, faults=None) -> dict:
    """The scenario's LineController in the Python closed loop: its spans, car, tuning, calls
    [(t, inputs, station_stops, LineStep as the shim's tuple, finished, departures)], and the
    controllers' events."""
    demands, run = LineController.demands, {}

    def rec(self, t, outputs):
        if faults is not None:
            t, outputs = faults(t, dict(outputs))
            outputs = {n: v for n, v in outputs.items() if v is not None}
        inputs, stops = line_inputs(outputs)
        st = demands(self, t, outputs)
        c = st.command
        run.setdefault("line", self)
        run.setdefault("calls", []).append(
            (t, inputs, stops, (st.t, st.span, c.traction, c.brake, c.mode, c.planned_speed,
                                c.ep_stage, st.dwell, st.payload_change),
             self.finished, len(self.departures)))
        return st

    LineController.demands = rec
    try:
        run_on_chain(load_scenario(ROOT / "scenarios" / "library" / f"{name}.toml"))
    finally:
        LineController.demands = demands
    return run


def _line_faults(t, outputs):
    """after the second span's departure (165.3 s): est.station_stops missing (the shift stays
    longer), a NaN filter.speed (the safe brake and its release)"""
    if 160.0 <= t < 180.0:
        outputs[STATION_STOPS] = None
    if 170.0 <= t < 170.3:
        outputs["filter.speed"] = math.nan
    return t, outputs


def _line_nan_offset(t, outputs):
    """filter.position NaN at the second span's departure (165.3 s): the line holds the car at
    the station until the position is back (it once took the NaN as the shift, held the safe
    brake for ever and never finished)"""
    if 165.0 <= t < 165.5:
        outputs["filter.position"] = math.nan
    return t, outputs


LINE_RUNS = ((None, True, False), (_line_faults, True, True), (_line_nan_offset, True, False))
"""(faults, the line finishes, a safe brake is met: the NaN position comes while standing)"""


@pytest.mark.parametrize("faults, finishes, safe_brake", LINE_RUNS,
                         ids=["ato_line", "ato_line_faults", "ato_line_nan_offset"])
def test_the_c_line_replays_the_python_line_bit_for_bit(lib, faults, finishes, safe_brake):
    run = record_line("ato_line", faults)
    line = run["line"]
    c = CLine(lib, line.spans, line.controllers[0].car, line.controllers[0].tuning)
    assert c.refusal is None, c.refusal
    for k, (t, inputs, stops, want, finished, n_dep) in enumerate(run["calls"]):
        got = c.demands(t, inputs, stops)
        assert [bits(x) for x in got[:9]] == [bits(x) for x in want], f"step {k} (t = {t})"
        assert (bool(got[9]), int(got[10])) == (finished, n_dep), f"step {k}"
    assert line.finished == finishes
    n = len(line.departures)
    assert n == (3 if finishes else 2)
    assert [bits(x) for x in c.departures(n)] == [bits(x) for x in line.departures]
    for i, ctrl in enumerate(line.controllers):
        assert [(bits(t), e) for t, e, _ in c.events(i)] == [(bits(t), e) for t, e in ctrl.events]
    texts = [e for ctrl in line.controllers for _, e in ctrl.events]
    assert safe_brake == any("safe brake" in e for e in texts)
    assert any(call[3][7] for call in run["calls"])                  # a dwell was replayed
    assert sum(call[3][8] != 0.0 for call in run["calls"]) >= 1       # ... with its boarding


def test_the_closed_loop_driven_by_the_c_line_is_the_python_one(lib):
    demands, lines = LineController.demands, {}

    def c_demands(self, t, outputs):
        if id(self) not in lines:
            lines[id(self)] = (self, CLine(lib, self.spans, self.controllers[0].car,
                                           self.controllers[0].tuning))
        c = lines[id(self)][1]
        inputs, stops = line_inputs(outputs)
        got = c.demands(t, inputs, stops)
        self.k = int(got[1])
        for i, ctrl in enumerate(self.controllers):
            for te, text, code in c.events(i)[len(ctrl.events):]:
                ctrl.events.append((te, text))
                if code in LOGGED_EVENTS:
                    CONTROLLER_LOG.warning("ATO at t = %.2f s: %s", te, text)
        self.finished = bool(got[9])
        self.departures[:] = c.departures(int(got[10]))
        return LineStep(got[0], int(got[1]), AtoCommand(got[2], got[3], int(got[4]), got[5],
                                                        int(got[6])),
                        dwell=bool(got[7]), payload_change=got[8])

    scenario = ROOT / "scenarios" / "library" / "ato_line.toml"
    want = run_on_chain(load_scenario(scenario))
    LineController.demands = c_demands
    try:
        got = run_on_chain(load_scenario(scenario))
    finally:
        LineController.demands = demands
    assert len(lines) == 1
    for key in want.signals:
        assert got.signals[key].tobytes() == want.signals[key].tobytes(), key
    for key in want.inputs:
        assert got.inputs[key].tobytes() == want.inputs[key].tobytes(), key
    assert got.driver_log == want.driver_log
    assert [(s.span, s.dwell, s.payload_change) for s in got.driver_steps] == \
        [(s.span, s.dwell, s.payload_change) for s in want.driver_steps]


LINE_REFUSALS = (
    ("no_span", []),
    ("dwell_nan", [LineSpan(BASE_SPAN), LineSpan(BASE_SPAN, dwell_s=math.nan)]),
    ("boarding_inf", [LineSpan(BASE_SPAN, boarding_t=math.inf)]),
    ("dwell_zero", [LineSpan(BASE_SPAN), LineSpan(BASE_SPAN, dwell_s=0.0)]),
    ("second_infeasible", [LineSpan(BASE_SPAN), LineSpan(BASE_SPAN.with_schedule(60.0),
                                                         dwell_s=20.0)]),
    ("third_grid", [LineSpan(BASE_SPAN), LineSpan(BASE_SPAN, dwell_s=20.0),
                    LineSpan(Span(200_000.0, 9000.0, stop=199_000.0), dwell_s=5.0)]),
)


@pytest.mark.parametrize("case, spans", LINE_REFUSALS, ids=[r[0] for r in LINE_REFUSALS])
def test_line_refusals_are_python_s_word_for_word(lib, case, spans):
    want = _python_refusal(lambda: LineController(spans, BASE_CAR))
    c = CLine(lib, spans, BASE_CAR, None)
    assert c.refusal is not None and c.refusal[1] == want


# ------------------------------------------------------------------ sanitizers, mutation

@pytest.fixture(scope="module")
def sanitized(tmp_path_factory):
    exe = tmp_path_factory.mktemp("sanitized") / "ato_controller_shim"
    build(exe, SANITIZE + ["-DSHIM_MAIN"])
    return exe


def run_sanitized(exe: Path, mode: str, data: list[float], tmp_path: Path) -> list[list[str]]:
    path = tmp_path / f"{mode}.bin"
    path.write_bytes(np.asarray(data, dtype="<f8").tobytes())
    proc = subprocess.run([str(exe), mode, str(path)], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "runtime error" not in proc.stderr and "Sanitizer" not in proc.stderr, proc.stderr
    return [line.split() for line in proc.stdout.splitlines()]


@pytest.mark.parametrize("variant", ["settle", "faults_noise"])
def test_the_controller_runs_clean_under_the_sanitizers(sanitized, tmp_path, variants, variant):
    run = variants[variant][0]
    data = header(run["span"], run["car"], run["tuning"])
    for t, inputs, *_ in run["calls"]:
        data += [t, *inputs]
    rows = run_sanitized(sanitized, "span", data, tmp_path)
    assert len(rows) == len(run["calls"])
    for f, (_, _, want, finished, n_events, _) in zip(rows, run["calls"]):
        assert (float.fromhex(f[0]), float.fromhex(f[1]), int(f[2]), float.fromhex(f[3]),
                int(f[4])) == want
        assert (bool(int(f[5])), int(f[6])) == (finished, n_events)


def test_the_line_runs_clean_under_the_sanitizers(sanitized, tmp_path):
    run = record_line("ato_line", _line_faults)
    line = run["line"]
    flat = line_flat(line.spans)
    car, tuning = line.controllers[0].car, line.controllers[0].tuning
    data = ([len(line.spans), len(flat), *flat] + [float(getattr(car, n)) for n in CAR_FIELDS]
            + [float(getattr(tuning, n)) for n in TUNING_FIELDS])
    for t, inputs, stops, *_ in run["calls"]:
        data += [t, *inputs, stops]
    rows = run_sanitized(sanitized, "line", data, tmp_path)
    assert len(rows) == len(run["calls"])
    for f, (_, _, _, want, finished, n_dep) in zip(rows, run["calls"]):
        got = [float.fromhex(x) for x in f]
        assert [bits(x) for x in got[:9]] == [bits(x) for x in want]
        assert (bool(got[9]), int(got[10])) == (finished, n_dep)


MUTATIONS = (
    ("double f = rc_min(f_ceil + car->m_in * c->brake_int, 0.0);",
     f"double f = rc_min(f_ceil * {ONE_ULP} + car->m_in * c->brake_int, 0.0);"),
    ("double a_u = 0.5 * dq;", f"double a_u = 0.5 * dq * {ONE_ULP};"),
)


@pytest.mark.parametrize("original, mutated", MUTATIONS)
def test_a_one_ulp_mutation_of_the_controller_is_caught(tmp_path, recorded, original, mutated):
    source = (CORE / "ato_controller.c").read_text()
    assert source.count(original) == 1
    mutant = tmp_path / "ato_controller.c"
    mutant.write_text(source.replace(original, mutated))
    out = tmp_path / "libmutant.so"
    build(out, ["-shared"], [mutant] + SOURCES[1:])
    dll = load(out)
    assert replay_differences(dll, recorded["ato_nominal"][0]) != []


def test_a_one_ulp_mutation_of_the_line_is_caught(tmp_path):
    original = "view[ATO_IN_POSITION] = inputs[ATO_IN_POSITION] - line->offset;"
    source = (CORE / "ato_line.c").read_text()
    assert source.count(original) == 1
    mutant = tmp_path / "ato_line.c"
    mutant.write_text(source.replace(original, original.replace(
        "inputs[ATO_IN_POSITION] -", f"inputs[ATO_IN_POSITION] * {ONE_ULP} -")))
    out = tmp_path / "libmutant.so"
    build(out, ["-shared"], [SOURCES[0], mutant] + SOURCES[2:])
    dll = load(out)
    run = record_line("ato_line")
    line = run["line"]
    c = CLine(dll, line.spans, line.controllers[0].car, line.controllers[0].tuning)
    differs = False
    for t, inputs, stops, want, *_ in run["calls"]:
        got = c.demands(t, inputs, stops)
        differs = differs or [bits(x) for x in got[:9]] != [bits(x) for x in want]
    assert differs
