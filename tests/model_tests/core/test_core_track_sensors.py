"""Track sensors in the C chain (models/core/track_sensors.c, railcar.c) against the Python
reference (models/chain.py's _track_passages, _hermite_crossing, _track_reading, _pending_track,
the estimator's measure_track_speed, models/plant/track_sensors.py): bit for bit.

CompiledChain and RailCarChain run side by side with sensor pairs every 200 m and 50 m (base 5 m),
timer resolution 1 ms and 0 (exact), detection jitter 0 and 0.1 ms, through traction, cruise,
braking and station stops (the distance restarts: the pair's first passage is forgotten), at
host steps of 0.1 s and odd ones (0.037 s, 0.5 s); every output after every step must be equal,
sensor.track_speed and sensor.track_time included, and readings must have happened. The pure
functions are compared with Python's on random inputs; the comparison is shown to catch one ulp;
the chain runs clean under AddressSanitizer/UndefinedBehaviorSanitizer.
"""
from __future__ import annotations

import ctypes
import math
import random
import shutil
import struct
import subprocess
from pathlib import Path

import pytest

from models import compiled
from models.chain import ChainConfig, RailCarChain, TrackSensorConfig, _hermite_crossing
from models.compiled import OUTPUT_NAMES, CompiledChain, _config_values, open_chain
from models.plant.dynamics import VehicleParams
from models.estimation.online import StationConfig
from models.plant.track import GradeProfile
from models.plant.track_sensors import quantise_time, speed_from_times
from test_core_chain import ROOT, assert_identical, python_state, same

CORE = ROOT / "models" / "core"
GRADE = GradeProfile((0.0, 300.0, 800.0, 1500.0), (0.0, 12.0, -8.0, 4.0))
TRACKS = {
    "200m_1ms": TrackSensorConfig(spacing=200.0, base=5.0, resolution=1e-3, jitter=0.0),
    "200m_1ms_jitter": TrackSensorConfig(spacing=200.0, base=5.0, resolution=1e-3, jitter=1e-4),
    "50m_exact": TrackSensorConfig(spacing=50.0, base=5.0, resolution=0.0, jitter=0.0),
    "50m_exact_jitter": TrackSensorConfig(spacing=50.0, base=5.0, resolution=0.0, jitter=1e-4),
    "50m_1ms_jitter": TrackSensorConfig(spacing=50.0, base=5.0, resolution=1e-3, jitter=1e-4),
}
STEPS = {"0.1": (0.1,), "odd": (0.037, 0.5)}


def chain_config(track: TrackSensorConfig, seed: int) -> ChainConfig:
    return ChainConfig(track=track, seed=seed, station=StationConfig(dwell=8.0))


class Driver:
    """Closed loop on the car's truth: traction to a top speed, cruise, brake to a stop, stand
    (a station stop when longer than the dwell: the distance restarts at 0), again. Top speed,
    cruise and stand times drawn from a seeded rng."""

    def __init__(self, rng: random.Random):
        self.rng = rng
        self.phase, self.until = "traction", 0.0
        self.top = rng.uniform(8.0, 22.0)

    def demands(self, t: float, out: dict) -> tuple[float, float]:
        v = out["car.speed"]
        if self.phase == "traction":
            if v >= self.top:
                self.phase, self.until = "cruise", t + self.rng.uniform(15.0, 50.0)
            return 36e3, 0.0
        if self.phase == "cruise":
            if t >= self.until:
                self.phase = "brake"
            return (6e3 if v < self.top else 0.0), 0.0
        if self.phase == "brake":
            if v == 0.0:
                # mostly a station stop (longer than the dwell), sometimes a short halt
                self.phase, self.until = "stand", t + self.rng.choice((3.0, 10.0, 12.0, 15.0))
            return 0.0, self.rng.uniform(15e3, 40e3)
        if t >= self.until:
            self.phase, self.top = "traction", self.rng.uniform(8.0, 22.0)
        return 0.0, 20e3


def run_pair(track: TrackSensorConfig, steps: tuple, seed: int, seconds: float,
             start_time: float = 0.0) -> dict:
    """Both chains through one closed-loop run; every output compared after every step.
    Returns counts: track-speed changes, readings taken by the estimator, station restarts,
    restarts that dropped a first passage (Python's _track_t1 was set)."""
    cfg = chain_config(track, seed)
    py = RailCarChain(cfg, GRADE, start_time=start_time)
    c = CompiledChain(cfg, GRADE, start_time=start_time)
    assert c.engine == "c"
    counts = {"changes": 0, "restarts": 0, "dropped_t1": 0}
    passages = py._track_passages

    def spy(t0, x0, v0):                 # observes the Python chain, changes nothing
        if py.plant.state.position < x0:
            counts["restarts"] += 1
            counts["dropped_t1"] += py._track_t1 is not None
        passages(t0, x0, v0)
    py._track_passages = spy
    rng = random.Random(seed)
    driver = Driver(random.Random(seed + 1))
    a, b = py.outputs(), c.outputs()
    assert same(a, b)
    t, k = start_time, 0
    while t - start_time < seconds:
        h = rng.choice(steps)
        traction, brake = driver.demands(t - start_time, a)
        wind = rng.uniform(-3.0, 3.0)
        py.do_step(t, h, traction, brake, wind)
        c.do_step(t, h, traction, brake, wind)
        prev = a["sensor.track_speed"]
        a, b = py.outputs(), c.outputs()
        if not same(a, b):
            diff = [(n, a[n], b[n]) for n in a if not same(a[n], b[n])]
            raise AssertionError(f"step {k} (t = {t!r}, h = {h}): {diff[:4]}")
        counts["changes"] += a["sensor.track_speed"] != prev
        t += h
        k += 1
    assert same(python_state(py), c.state())
    counts["readings"] = py.estimator.track_speeds
    counts["stops"] = a["est.station_stops"]
    return counts


@pytest.mark.parametrize("steps", STEPS)
@pytest.mark.parametrize("name", TRACKS)
def test_track_sensors_bit_identical(name, steps):
    counts = run_pair(TRACKS[name], STEPS[steps], seed=11 + len(name), seconds=500.0)
    assert counts["changes"] > 10, counts
    assert counts["readings"] >= counts["changes"], counts
    assert counts["restarts"] >= 3, counts          # station stops: the distance restarted


def test_a_station_stop_between_the_sensors_of_a_pair_forgets_the_first_passage():
    """The car stops for a station between a pair's two sensors (first passed, second not): the
    restart at 0 drops _track_t1 in both chains; readings go on after it, identical."""
    total = {"dropped_t1": 0, "changes": 0}
    for seed in (104, 105):
        counts = run_pair(TRACKS["50m_1ms_jitter"], (0.1, 0.037), seed=seed, seconds=400.0)
        for key in total:
            total[key] += counts[key]
    assert total["dropped_t1"] >= 2 and total["changes"] > 30, total


def test_track_sensors_with_a_start_time():
    """The host starts at t = 1000 s: sensor.track_time is the host's time of the stamp."""
    counts = run_pair(TRACKS["50m_1ms_jitter"], (0.1, 0.5, 0.037), seed=5, seconds=300.0,
                      start_time=1000.0)
    assert counts["changes"] > 10, counts


def test_steep_grades_with_track_sensors_bit_identical():
    path = ROOT / "scenarios" / "library" / "steep_grades.toml"
    assert assert_identical(path, {"sensor.track_spacing": 200.0, "sensor.track_jitter": 1e-4}) > 100


def test_station_day_with_track_sensors_bit_identical():
    path = ROOT / "scenarios" / "library" / "station_day.toml"
    overrides = {"sensor.track_spacing": 50.0, "sensor.track_resolution": 0.0,
                 "sensor.track_jitter": 1e-4}
    assert assert_identical(path, overrides, max_steps=6000) > 100


def test_open_chain_runs_track_sensors_in_c():
    before = compiled.ENGINES["c"]
    chain = open_chain(chain_config(TRACKS["200m_1ms"], 1), GRADE)
    assert chain.engine == "c" and isinstance(chain, CompiledChain)
    assert compiled.ENGINES["c"] == before + 1
    assert compiled.not_covered(chain_config(TRACKS["50m_exact"], 1)) is None


def test_reset_repeats_the_track_readings():
    chain = CompiledChain(chain_config(TRACKS["50m_1ms_jitter"], 4), GRADE)

    def run():
        rows = [chain.outputs()]
        for k in range(1500):
            chain.do_step(k * 0.1, 0.1, 36e3 if k < 300 else 0.0, 0.0, 0.0)
            rows.append(chain.outputs())
        return rows
    first = run()
    chain.reset()
    again = run()
    assert same(first, again)
    assert len({r["sensor.track_speed"] for r in first}) > 10


def test_a_bad_track_configuration_reads_as_in_python():
    for track in (TrackSensorConfig(spacing=5.0, base=5.0), TrackSensorConfig(spacing=-1.0),
                  TrackSensorConfig(spacing=100.0, base=0.0), TrackSensorConfig(resolution=-1e-3),
                  TrackSensorConfig(jitter=math.inf), TrackSensorConfig(spacing=math.nan)):
        messages = []
        for kind in (RailCarChain, CompiledChain):
            with pytest.raises(ValueError) as e:
                kind(ChainConfig(track=track), GRADE)
            messages.append(str(e.value))
        assert messages[0] == messages[1]


# ---------------------------------------------------------------- the one-ulp check

def test_one_ulp_of_the_base_shows_in_the_track_speed():
    """The comparison can fail: the C chain with a base one ulp longer reads other speeds."""
    track = TRACKS["200m_1ms_jitter"]
    ulp = TrackSensorConfig(spacing=track.spacing, base=math.nextafter(track.base, 10.0),
                            resolution=track.resolution, jitter=track.jitter)
    py = RailCarChain(chain_config(track, 2), GRADE)
    c = CompiledChain(chain_config(ulp, 2), GRADE)
    differs = False
    for k in range(2000):
        py.do_step(k * 0.1, 0.1, 36e3 if k < 300 else 0.0, 0.0, 0.0)
        c.do_step(k * 0.1, 0.1, 36e3 if k < 300 else 0.0, 0.0, 0.0)
        a, b = py.outputs(), c.outputs()
        differs |= not same(a["sensor.track_speed"], b["sensor.track_speed"])
    assert differs
    assert not same(a, b)


# ---------------------------------------------------------------- the pure functions

@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    so = tmp_path_factory.mktemp("core") / "libtrack_sensors.so"
    subprocess.run([gcc, "-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                    "-pedantic", "-fPIC", "-shared", str(CORE / "track_sensors.c"), "-o", str(so),
                    "-lm"], check=True, capture_output=True, text=True)
    dll = ctypes.CDLL(str(so))
    d = ctypes.c_double
    for name, n in (("rc_track_speed_std", 4), ("rc_track_quantise", 2),
                    ("rc_track_speed_from_times", 6), ("rc_track_hermite_crossing", 7)):
        f = getattr(dll, name)
        f.argtypes = [d] * n
        f.restype = d
    return dll


def test_the_pure_functions_equal_python(lib):
    rng = random.Random(17)
    for _ in range(4000):
        res = rng.choice((0.0, 1e-3, 1e-4, rng.uniform(0.0, 0.01)))
        jit = rng.choice((0.0, 1e-4, rng.uniform(0.0, 1e-3)))
        base = rng.choice((5.0, rng.uniform(0.5, 20.0)))
        v = rng.uniform(0.0, 40.0)
        assert same(lib.rc_track_speed_std(v, base, res, jit),
                    TrackSensorConfig(spacing=0.0, base=base, resolution=res, jitter=jit).speed_std(v))
        t = rng.uniform(-10.0, 5000.0)
        assert same(lib.rc_track_quantise(t, res), float(quantise_time(t, res)))
        t1 = rng.uniform(0.0, 5000.0)
        t2 = t1 + rng.choice((rng.uniform(0.0, 2.0), rng.uniform(0.0, 2e-3), 0.0))
        j1, j2 = jit * rng.gauss(0.0, 1.0), jit * rng.gauss(0.0, 1.0)
        assert same(lib.rc_track_speed_from_times(t1, t2, base, res, j1, j2),
                    float(speed_from_times(t1, t2, base, res, 0.0, j1, j2)))
        h = rng.choice((0.1, 0.037, 0.5, rng.uniform(0.01, 2.0)))
        x0, v0, v1 = rng.uniform(0.0, 5000.0), rng.uniform(0.0, 30.0), rng.uniform(0.0, 30.0)
        x1 = x0 + 0.5 * (v0 + v1) * h
        d = rng.uniform(x0, x1) if x1 > x0 else x0
        args = (t1, x0, v0, t1 + h, x1, v1, d)
        assert same(lib.rc_track_hermite_crossing(*args), _hermite_crossing(*args))


# ---------------------------------------------------------------- sanitizers

def test_the_chain_with_track_sensors_runs_clean_under_sanitizers(tmp_path):
    """railcar.c, track_sensors.c and the rest of the core as an executable under
    -fsanitize=address,undefined (any report aborts) through a run with readings and station
    stops; its outputs are still the Python chain's, bit for bit."""
    gcc = shutil.which("gcc")
    assert gcc
    exe = tmp_path / "track_chain"
    sources = [ROOT / "tests" / "core_cases" / "track_sensors_shim.c", *sorted(CORE.glob("*.c"))]
    subprocess.run([gcc, "-std=c99", "-O1", "-g", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror",
                    "-pedantic", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                    f"-I{CORE}", *map(str, sources), "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    cfg = chain_config(TRACKS["50m_1ms_jitter"], 21)
    py = RailCarChain(cfg, GRADE)
    rows, outs = [], [py.outputs()]
    rng, driver, t = random.Random(21), Driver(random.Random(22)), 0.0
    while t < 250.0:
        h = rng.choice((0.1, 0.037, 0.5))
        traction, brake = driver.demands(t, outs[-1])
        rows.append((t, h, traction, brake, 0.0, 0.0))
        py.do_step(*rows[-1])
        outs.append(py.outputs())
        t += h
    values = _config_values(cfg, 0.0)
    header = [len(values), len(GRADE.distances), len(rows), *values, *GRADE.distances, *GRADE.grades]
    stdin = struct.pack(f"={len(header)}d", *header) + b"".join(struct.pack("=6d", *r) for r in rows)
    proc = subprocess.run([str(exe)], input=stdin, capture_output=True, timeout=120,
                          env={"ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
    assert proc.returncode == 0 and not proc.stderr, proc.stderr.decode(errors="replace")
    expected = b"".join(struct.pack(f"={len(OUTPUT_NAMES)}d", *(float(o[n]) for n in OUTPUT_NAMES))
                        for o in outs)
    assert proc.stdout == expected
    assert len({o["sensor.track_speed"] for o in outs}) > 10
