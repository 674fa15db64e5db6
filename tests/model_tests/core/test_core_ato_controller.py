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
- the shim as a program under -fsanitize=address,undefined replaying a scenario: the same
  commands, no report;
- a one-ulp mutation of a controller expression makes the replay fail.
"""
from __future__ import annotations

import ctypes
import dataclasses
import math
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
from models.ato.interface import ALL_INPUTS, AtoTuning
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ato_controller_shim.c"
SOURCES = [CORE / f for f in ("ato_controller.c", "ato_supervision.c", "ato_tuning.c",
                              "ato_span.c", "ato_motion.c", "ato_stopping.c", "ato_planner.c",
                              "repr.c")]
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
        """(traction, brake, mode, planned_speed, ep_stage, finished, n_events)"""
        out = (ctypes.c_double * 7)()
        self.lib.shim_demands(self.h, t, arr(inputs), out)
        return (out[0], out[1], int(out[2]), out[3], int(out[4]), bool(out[5]), int(out[6]))

    def event(self, k: int) -> tuple[float, str]:
        t, text = ctypes.c_double(), ctypes.create_string_buffer(TEXT)
        assert self.lib.shim_event(self.h, k, ctypes.byref(t), text) >= 0, f"event {k} left the ring"
        return t.value, text.value.decode()

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
                                         "events": self.events})
        run["calls"].append((t, inputs, (cmd.traction, cmd.brake, int(cmd.mode),
                                         cmd.planned_speed, int(cmd.ep_stage)),
                             self.finished, len(self.events)))
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
    for k, (t, inputs, want, finished, n_events) in enumerate(run["calls"]):
        got = c.demands(t, inputs)
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
            break
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
