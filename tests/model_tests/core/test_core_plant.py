"""The C true car (models/core/plant.c) against models.plant.dynamics.CarPlant, bit for bit.

The Python plant runs its own code (its optional compiled advance is switched off), the C plant
is driven through tests/core_cases/plant_shim.c with the same calls: communication points on
the 0.1 s sample grid, odd 0.037 s steps, steps longer than the solver grid, t_end exactly on
the grid and below the time tolerance; traction/coast/brake phases with station stops, dwell
and departures; wind +-20 m/s; the mass changed between calls (the chain's payload); the
chain's impulse reset; a grade profile with a steep downhill (a car released there rolls away)
and a steep climb (a coasting car stops there and stays). After every call the whole state is
compared by its bits (17 fields, see shim_read).
"""
from __future__ import annotations

import dataclasses
import math
import random
import shutil
import struct
import subprocess
import ctypes
from pathlib import Path

import pytest

from models.plant.dynamics import BRAKING, COASTING, STANDSTILL, TRACTION, CarPlant, VehicleParams
from models.plant.noise import noise_streams
from models.plant.track import GradeProfile

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "plant_shim.c"
SOURCES = [CORE / "plant.c", CORE / "track.c", CORE / "noise.c", CORE / "repr.c", SHIM]
CFLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic",
          "-fPIC"]
STREAMS = ("process", "speed_sensor", "position_sensor", "track_sensor")   # models/chain.py's
NFIELDS = 17
FIELDS = ("speed", "position", "acceleration", "traction_force", "brake_force", "grade", "mode",
          "still_time", "stops", "time", "grid_index", "traction_impulse", "brake_impulse", "h",
          "noise_std", "station_dwell", "mass")
VEH_FIELDS = tuple(f.name for f in dataclasses.fields(VehicleParams))
PROFILE = ((0.0, 300.0, 700.0, 1200.0, 1800.0, 2500.0, 3200.0),
           (0.0, 12.0, -35.0, 25.0, -8.0, 45.0, -2.0))
Dbl = ctypes.c_double


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    so = tmp_path_factory.mktemp("core") / "libplant.so"
    subprocess.run([gcc, *CFLAGS, "-shared", f"-I{CORE}", *map(str, SOURCES), "-o", str(so), "-lm"],
                   check=True, capture_output=True, text=True)
    dll = ctypes.CDLL(str(so))
    dll.shim_new.restype = ctypes.c_void_p
    dll.shim_new.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_long,
                             Dbl, Dbl, Dbl, ctypes.c_uint64]
    dll.shim_free.argtypes = [ctypes.c_void_p]
    dll.shim_validate.restype = ctypes.c_int
    dll.shim_validate.argtypes = [ctypes.c_void_p, Dbl, Dbl, ctypes.c_char_p, ctypes.c_long]
    dll.shim_set_mass.argtypes = [ctypes.c_void_p, Dbl]
    dll.shim_set_state.argtypes = [ctypes.c_void_p, Dbl, Dbl, Dbl, ctypes.c_long]
    dll.shim_set_impulses.argtypes = [ctypes.c_void_p, Dbl, Dbl]
    dll.shim_refresh.argtypes = [ctypes.c_void_p, Dbl, Dbl, Dbl]
    dll.shim_advance.argtypes = [ctypes.c_void_p, Dbl, Dbl, Dbl, Dbl]
    dll.shim_read.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    return dll


def darray(values):
    return (Dbl * len(values))(*values)


def py_fields(pl: CarPlant) -> tuple:
    s = pl.state
    return (s.speed, s.position, s.acceleration, s.traction_force, s.brake_force, s.grade, s.mode,
            s.still_time, s.stops, pl.time, pl._grid_index, pl.traction_impulse, pl.brake_impulse,
            pl.h, pl.noise_std, pl.station_dwell, pl.p.mass)


class Twin:
    """A Python CarPlant and a C plant built alike; every call goes to both and is recorded."""

    def __init__(self, lib, veh: dict, profile, *, step, noise_psd, dwell, seed):
        self.lib = lib
        params = VehicleParams(**veh)
        stream = noise_streams(seed, STREAMS)["process"]
        self.draws = 0

        def normal():
            self.draws += 1
            return stream()
        self.py = CarPlant(params, GradeProfile(*profile), step=step, noise_psd=noise_psd,
                           station_dwell=dwell, normal_draws=normal)
        d, g = profile
        vals = [veh_value(veh, f) for f in VEH_FIELDS]
        self.header = vals + [step, noise_psd, dwell, float(seed), float(len(d)), *d, *g]
        self.c = lib.shim_new(darray(vals), darray(d), darray(g), len(d), step, noise_psd, dwell, seed)
        assert self.c
        self.buf = (Dbl * NFIELDS)()
        self.records: list[tuple] = []        # the calls, for the sanitizer replay
        self.states: list[bytes] = []         # Python's state after each call
        self.mismatch = None                  # (call index, field names) of the first difference
        self.check("init")

    def close(self):
        self.lib.shim_free(self.c)
        self.c = None

    def check(self, what):
        self.lib.shim_read(self.c, self.buf)
        ours = bytes(self.buf)
        theirs = struct.pack(f"<{NFIELDS}d", *map(float, py_fields(self.py)))
        self.states.append(theirs)
        if ours != theirs and self.mismatch is None:
            a = struct.unpack(f"<{NFIELDS}d", ours)
            b = struct.unpack(f"<{NFIELDS}d", theirs)
            diff = [f"{n}: C {x!r} Python {y!r}" for n, x, y in zip(FIELDS, a, b)
                    if struct.pack("<d", x) != struct.pack("<d", y)]
            self.mismatch = (len(self.states) - 1, what, diff)

    def advance(self, t_end, td, bd, wind, mass, c_mass=None):
        self.py.p.mass = mass
        self.py.advance(t_end, td, bd, wind)
        m = mass if c_mass is None else c_mass
        self.lib.shim_set_mass(self.c, m)
        self.lib.shim_advance(self.c, t_end, td, bd, wind)
        self.records.append((0.0, m, t_end, td, bd, wind, 0.0, 0.0))
        self.check(("advance", t_end, td, bd, wind, mass))

    def set_and_refresh(self, speed, position, still_time, stops, td, bd, wind):
        s = self.py.state
        s.speed, s.position, s.still_time, s.stops = speed, position, still_time, stops
        self.py.refresh_outputs(td, bd, wind)
        self.lib.shim_set_state(self.c, speed, position, still_time, stops)
        self.lib.shim_refresh(self.c, td, bd, wind)
        self.records.append((1.0, speed, position, still_time, float(stops), td, bd, wind))
        self.check(("refresh", speed, position, td, bd, wind))

    def reset_impulses(self):
        self.py.traction_impulse = self.py.brake_impulse = 0.0
        self.lib.shim_set_impulses(self.c, 0.0, 0.0)
        self.records.append((2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        self.check("reset impulses")


def veh_value(veh, name):
    return float(veh.get(name, getattr(VehicleParams, name)))


def drive(twin: Twin, rng: random.Random, calls: int, base_mass: float, perturb=None) -> dict:
    """A service run: legs of traction, coasting, braking to a stop and a dwell, with random
    communication points, wind changes, payload changes and random phase jumps. ``perturb``
    (call index, field) puts one input of the C plant's one ulp up from that call on."""
    py = twin.py
    seen = {"modes": set(), "winds": set(), "rolls": 0, "long_steps": 0, "on_grid": 0,
            "odd": 0, "tiny": 0, "mass_changes": 0}
    phase, phase_end, leg = "run", 0.0, rng.uniform(200.0, 900.0)
    vmax, td, bd = rng.uniform(8.0, 30.0), rng.uniform(5e3, 60e3), 0.0
    wind, mass, ts = 0.0, base_mass, 0.1
    for k in range(calls):
        s, t = py.state, py.time
        # --- the controller
        if rng.random() < 0.002:                       # a random jump: any phase, any demand
            phase = rng.choice(["run", "coast", "brake", "dwell"])
            phase_end = t + rng.uniform(1.0, 30.0)
        if phase == "run":
            td, bd = td if td > 0 else rng.uniform(5e3, 60e3), 0.0
            if s.speed > vmax or s.position > leg:
                phase, phase_end, td = "coast", t + rng.uniform(2.0, 40.0), 0.0
        elif phase == "coast":
            td, bd = 0.0, 0.0
            if t > phase_end or s.position > leg + 200.0:
                phase, bd = "brake", rng.uniform(20e3, 60e3)
        elif phase == "brake":
            td, bd = 0.0, bd if bd > 0 else rng.uniform(20e3, 60e3)
            if s.speed <= 0.0:
                phase, phase_end = "dwell", t + rng.uniform(0.5, 2.0) * py.station_dwell + 0.2
        elif phase == "dwell":
            td, bd = 0.0, bd if bd > 0 else rng.uniform(1e3, 30e3)
            if t > phase_end:
                release = rng.random()
                if release < 0.35:                     # brake off, no traction: rolls if downhill
                    phase, phase_end, td, bd = "coast", t + rng.uniform(5.0, 60.0), 0.0, 0.0
                else:
                    phase, td, bd = "run", rng.uniform(5e3, 60e3), 0.0
                    leg, vmax = rng.uniform(200.0, 900.0) * rng.choice([1, 1, 3]), rng.uniform(8.0, 30.0)
        if rng.random() < 0.01:
            wind = rng.choice([-20.0, 20.0, 0.0, rng.uniform(-20.0, 20.0)])
            seen["winds"].add(math.copysign(1.0, wind) if wind else 0.0)
        if rng.random() < 0.005:
            mass = base_mass + rng.uniform(0.0, 15.0)
            seen["mass_changes"] += 1
        # --- the next communication point
        kind = rng.random()
        if kind < 0.55:                                # the sample grid
            j = math.floor(t / ts + 1e-6) + 1
            t_end = j * ts
        elif kind < 0.75:
            t_end = t + 0.037
            seen["odd"] += 1
        elif kind < 0.87:
            t_end = t + rng.uniform(0.1, 0.7)          # several grid steps in one call
            seen["long_steps"] += 1
        elif kind < 0.97:
            t_end = (py._grid_index + rng.randint(1, 4)) * py.h     # exactly on the grid
            seen["on_grid"] += 1
        else:
            t_end = t + rng.choice([0.0, 1e-10, 5e-10])            # within the tolerance
            seen["tiny"] += 1
        was_still = s.speed <= 0.0
        c_td, c_wind, c_mass = td, wind, mass
        if perturb is not None and k >= perturb[0]:
            if perturb[1] == "wind":
                c_wind = math.nextafter(wind, math.inf)
            elif perturb[1] == "traction":
                c_td = math.nextafter(td, math.inf)
            elif perturb[1] == "mass":
                c_mass = math.nextafter(mass, math.inf)
        if (c_wind, c_td) != (wind, td):              # the C plant alone gets the other input
            twin.py.p.mass = mass
            twin.py.advance(t_end, td, bd, wind)
            twin.lib.shim_set_mass(twin.c, c_mass)
            twin.lib.shim_advance(twin.c, t_end, c_td, bd, c_wind)
            twin.records.append((0.0, c_mass, t_end, c_td, bd, c_wind, 0.0, 0.0))
            twin.check("perturbed")
        else:
            twin.advance(t_end, td, bd, wind, mass, c_mass=c_mass)
        seen["modes"].add(py.state.mode)
        if was_still and py.state.speed > 0.0 and td == 0.0:
            seen["rolls"] += 1                         # rolled away (downhill, or the wind)
        if abs(py.time / ts - round(py.time / ts)) < 1e-6 and rng.random() < 0.5:
            twin.reset_impulses()                      # the chain does it after each sample
        if twin.mismatch is not None and perturb is None:
            break
    seen["stops"] = py.state.stops
    return seen


SCENARIOS = [
    # vehicle, step, noise_psd, dwell, seed, initial (speed, position), calls
    (dict(mass=30.0), 0.05, 1e-4, 5.0, 1, (0.0, 0.0), 6000),
    (dict(mass=30.0, length=60.0, gamma=0.08), 0.1, 0.0, 10.0, 2, (12.0, 100.0), 5000),
    (dict(mass=28.0, length=60.0, adhesion_factor=0.5, adhesion_mass_fraction=0.6), 0.05, 1e-4,
     3.0, 7, (0.0, 0.0), 6000),
    (dict(mass=35.0, traction_power_max=250e3, brake_force_max=30e3), 0.1, 1e-4, 8.0, 11,
     (5.0, 1000.0), 5000),
]


@pytest.mark.parametrize("case", range(len(SCENARIOS)))
def test_the_c_plant_equals_the_python_plant_bit_for_bit(lib, case):
    veh, step, psd, dwell, seed, (v0, x0), calls = SCENARIOS[case]
    twin = Twin(lib, veh, PROFILE, step=step, noise_psd=psd, dwell=dwell, seed=seed)
    try:
        if v0 > 0.0 or x0 != 0.0:
            twin.set_and_refresh(v0, x0, 0.0, 0, 0.0, 0.0, 0.0)     # the chain's initial state
        seen = drive(twin, random.Random(200 + case), calls, veh["mass"])
        assert twin.mismatch is None, twin.mismatch
    finally:
        twin.close()
    n_adv = sum(1 for r in twin.records if r[0] == 0.0)
    assert n_adv == calls
    assert (twin.draws > 2000) if psd > 0 else (twin.draws == 0)     # the process noise ran
    # the run went where it should: every mode, station departures, both wind signs, payloads
    assert seen["modes"] == {STANDSTILL, TRACTION, COASTING, BRAKING}, seen
    assert seen["stops"] >= 3, seen
    assert seen["winds"] >= {-1.0, 1.0}, seen
    assert seen["rolls"] >= 1 and seen["mass_changes"] >= 5, seen
    assert min(seen["odd"], seen["long_steps"], seen["on_grid"], seen["tiny"]) >= 50, seen


def test_station_stops_rolling_away_and_a_stop_on_a_climb(lib):
    """A directed run on the profile (station dwell 4 s). Stopped on the -35 permille stretch for
    2 s (no station stop yet), the released car rolls away. Stopped there again for 6 s, the
    release is a departure: stops + 1 and the position restarts at 0, where the profile is level,
    so the car stays (Python's semantics: any stop of a dwell is a station). Then under traction
    to the +45 climb, coasting until the car stops there: no backward roll, no departure, until
    traction moves it off (a departure again)."""
    twin = Twin(lib, dict(mass=30.0, length=60.0), PROFILE, step=0.05, noise_psd=1e-4, dwell=4.0,
                seed=3)
    py, s = twin.py, twin.py.state
    clock = [0.0]

    def run(dt, td, bd, wind=0.0):
        clock[0] += dt
        twin.advance(clock[0], td, bd, wind, 30.0)

    def hold(seconds, td, bd, wind=0.0):
        for _ in range(round(seconds / 0.1)):
            run(0.1, td, bd, wind)

    try:
        while s.position < 900.0:                     # into the downhill, with a headwind
            run(0.1, 40e3 if s.speed < 15 else 0.0, 0.0, 20.0)
        while s.speed > 0.0:                          # stop on it, with a tailwind
            run(0.1, 0.0, 45e3, -20.0)
        hold(2.0, 0.0, 30e3)
        x = s.position
        run(0.037, 0.0, 0.0)                          # released: rolls away, no departure
        assert s.speed > 0.0 and s.position > x and s.stops == 0 and s.mode == COASTING
        hold(3.0, 0.0, 0.0)
        while s.speed > 0.0:
            run(0.1, 0.0, 45e3)
        hold(6.0, 0.0, 30e3)
        assert s.still_time >= 4.0 and s.mode == STANDSTILL and s.grade == -35.0
        run(0.1, 0.0, 0.0)                            # released after the dwell: a departure
        assert s.stops == 1 and s.position == 0.0 and s.speed == 0.0 and s.grade == 0.0
        while s.position < 1950.0:                    # on to the climb, odd steps
            run(0.037, 40e3 if s.speed < 12 else 0.0, 0.0)
        while s.speed > 0.0:
            run(0.1, 0.0, 0.0)
        assert s.mode == STANDSTILL and s.grade == 45.0
        x = s.position
        hold(10.0, 0.0, 0.0, -20.0)                   # stays: no roll back, no departure
        assert s.position == x and s.stops == 1 and s.still_time > 10.0
        run(0.25, 40e3, 0.0)                          # traction: departs (a station stop)
        assert s.stops == 2 and 0.0 < s.position < 1.0 and s.mode == TRACTION
        assert twin.mismatch is None, twin.mismatch
    finally:
        twin.close()


def test_refresh_outputs_after_the_state_is_set(lib):
    """What the chain does at start (state set, then refresh_outputs), over random states:
    at rest and moving, behind the profile's start, on every grade, every demand and wind."""
    rng = random.Random(5)
    twin = Twin(lib, dict(mass=30.0, length=60.0), PROFILE, step=0.05, noise_psd=1e-4, dwell=4.0,
                seed=3)
    try:
        for _ in range(3000):
            speed = rng.choice([0.0, rng.uniform(0.0, 40.0), rng.uniform(0.0, 0.01)])
            position = rng.choice([0.0, rng.uniform(-200.0, 4000.0), rng.choice(PROFILE[0])])
            td = rng.choice([0.0, rng.uniform(0.0, 80e3)])
            bd = rng.choice([0.0, 0.0, rng.uniform(0.0, 80e3)])
            wind = rng.choice([0.0, -20.0, 20.0, rng.uniform(-20.0, 20.0)])
            twin.set_and_refresh(speed, position, rng.uniform(0.0, 10.0), rng.randint(0, 9),
                                 td, bd, wind)
        assert twin.mismatch is None, twin.mismatch
    finally:
        twin.close()


@pytest.mark.parametrize("what", ["wind", "traction", "mass"])
def test_the_comparison_sees_one_ulp(lib, what):
    """One input of the C plant's one ulp off from call 300 on: the state comparison must catch
    it (so an exact comparison that passes means something)."""
    veh, step, psd, dwell, seed, _, _ = SCENARIOS[0]
    twin = Twin(lib, veh, PROFILE, step=step, noise_psd=psd, dwell=dwell, seed=seed)
    try:
        drive(twin, random.Random(100), 1500, veh["mass"], perturb=(300, what))
        assert twin.mismatch is not None
        index, _, diff = twin.mismatch
        assert index >= 300 and diff, twin.mismatch
    finally:
        twin.close()


BAD_CONFIGS = [
    (dict(mass=0.0), 0.05, 0.0),
    (dict(mass=math.nan), 0.05, 0.0),
    (dict(A1=-1e-5), 0.05, 0.0),
    (dict(length=-0.5), 0.05, 0.0),
    (dict(gamma=-1e-300), 0.05, 0.0),
    (dict(traction_power_max=-3e20), 0.05, 0.0),
    (dict(brake_force_max=math.inf), 0.05, 0.0),
    (dict(adhesion_mass_fraction=1.0000001), 0.05, 0.0),
    (dict(adhesion_factor=0.0), 0.05, 0.0),
    (dict(adhesion_factor=1.6, mass=-1.0), 0.05, 0.0),
    (dict(), 0.0, 0.0),
    (dict(), math.inf, 0.0),
    (dict(), -0.001, 0.0),
    (dict(), 0.05, -1e-4),
    (dict(), 0.05, math.nan),
    (dict(), 0.05, 123456789.5e10),
]


def test_validation_refuses_what_the_python_plant_refuses_with_its_message(lib):
    for veh, step, psd in BAD_CONFIGS + [(dict(length=60.0, gamma=0.1), 0.1, 1e-4)]:
        try:
            CarPlant(VehicleParams(**veh), GradeProfile(), step=step, noise_psd=psd,
                     station_dwell=0.0, normal_draws=None)
            expected = ""
        except ValueError as e:
            expected = str(e)
        msg = ctypes.create_string_buffer(256)
        status = lib.shim_validate(darray([veh_value(veh, f) for f in VEH_FIELDS]), step, psd, msg, 256)
        assert (status, msg.value.decode()) == ((2, expected) if expected else (0, "")), veh


def test_the_plant_runs_clean_under_address_and_undefined_behaviour_sanitizers(lib, tmp_path):
    """plant.c, track.c, noise.c and the shim as an executable under -fsanitize=address,undefined
    (any report aborts), replaying a recorded run; its states are still Python's, bit for bit."""
    gcc = shutil.which("gcc")
    assert gcc
    twin = Twin(lib, dict(mass=30.0, length=60.0), PROFILE, step=0.05, noise_psd=1e-4, dwell=5.0,
                seed=9)
    try:
        twin.set_and_refresh(3.0, 20.0, 0.0, 0, 10e3, 0.0, 5.0)
        drive(twin, random.Random(9), 3000, 30.0)
        assert twin.mismatch is None, twin.mismatch
    finally:
        twin.close()
    exe = tmp_path / "plant"
    subprocess.run([gcc, "-std=c99", "-O1", "-g", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                    "-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-DSHIM_MAIN",
                    f"-I{CORE}", *map(str, SOURCES), "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    stdin = struct.pack(f"<{len(twin.header)}d", *twin.header) + b"".join(
        struct.pack("<8d", *r) for r in twin.records)
    proc = subprocess.run([str(exe)], input=stdin, capture_output=True,
                          env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
    assert proc.returncode == 0 and not proc.stderr, proc.stderr.decode(errors="replace")
    assert proc.stdout == b"".join(twin.states[1:])
