"""The harness side of the ATO: span scenarios, their metrics, their report.

- a [span] scenario parses to the ATO's spans (limits in km/h converted with models.units, the
  grade read from the scenario's own track.grade_profile: one source), [ato] and [ato.car]
  reach AtoTuning and CarTraction, and every bad input is a ScenarioError naming the file, the
  key and the reason (the ATO's own construction errors among them);
- the metrics (harness.metrics.ato) on hand-made traces, to exact or stated tolerances;
- closed loop on the models chain (seeded by the scenario): the nominal span arrives within
  +-2.5 s and stops within +-0.3 m, never over the limit, no intervention; the three-span line
  stops at each station, restarts the distance and the estimator there, boards its passengers;
  the commands a run's recorded outputs give (replay_steps) are the run's own, bit for bit;
- the report's figure, read from matplotlib's objects;
- ``harness run`` on the FMU (the session build): the table printed, summary.md, ato.png; a bad
  span is one line on stderr and exit code 2.

Runs on the chain take ~0.1 s per span; the FMU test needs the session's build (fmu layer).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from harness.metrics.ato import (INTERVENTIONS, ato_metrics, energy_kwh, standstill_time,
                                 step_work)
from harness.reports.ato_report import MODE_COLOURS, ato_figure, mode_runs
from harness.run.span_scenario import AtoDriver, AtoStep, replay_steps
from harness.run.driver import run_on_chain
from harness.run.result import RunResult
from harness.run.scenario import ScenarioError, load_scenario, scenario_from_dict
from models.ato.interface import AtoCommand, AtoMode, AtoTuning
from models.plant.dynamics import VehicleParams
from models.planning.span import CarTraction
from models.units import kmh_to_mps

ROOT = Path(__file__).resolve().parents[3]
LIBRARY = ROOT / "scenarios" / "library"
NOMINAL = LIBRARY / "ato_nominal.toml"
LINE = LIBRARY / "ato_line.toml"


def write(tmp_path: Path, text: str, name: str = "span.toml") -> Path:
    p = tmp_path / name
    p.write_text(text, encoding="utf-8")
    return p


BASE = '''name = "s"
step_s = 0.1
[parameters]
"track.grade_profile" = "{grade}"
'''
SPAN = '''[span]
stop_m = 2150.0
length_m = 2200.0
schedule_s = 135.0
limit_kmh = [[0, 80], [900, 60], [1300, 80]]
'''
GRADE = (ROOT / "scenarios" / "profiles" / "ato_span_grade.csv").as_posix()


# ------------------------------------------------------------------------------ parsing

def test_the_nominal_span_parses_to_the_atos_span():
    s = load_scenario(NOMINAL)
    (ls,) = s.ato.spans
    span = ls.span
    assert (span.stop, span.length, span.schedule) == (2150.0, 2200.0, 135.0)
    assert span.limit_distances == (0.0, 900.0, 1300.0)
    assert span.limit_speeds == (kmh_to_mps(80.0), kmh_to_mps(60.0), kmh_to_mps(80.0))   # the same doubles
    # the span's grade is the plant's: the profile the chain (and the FMU) read from the same file
    assert span.grade == s.chain_setup().grade
    assert span.grade.distances == (0.0, 300.0, 800.0, 1100.0, 1500.0)
    assert span.grade.grades == (0.0, 15.0, -10.0, 0.0, 5.0)
    assert s.ato.car == CarTraction() and s.ato.tuning == AtoTuning()
    assert s.duration_s == 135.0 + 60.0          # default: the schedule and a minute
    assert isinstance(s.new_driver(), AtoDriver) and s.new_driver() is not s.new_driver()


def test_ato_tuning_car_and_limits_in_mps(tmp_path):
    p = write(tmp_path, "duration_s = 300.0\n" + BASE.format(grade=GRADE) + '''[span]
stop_m = 2150.0
schedule_s = 160.0
limit_mps = [[0, 20.0], [900, 16.0]]
[ato]
replan_period = 3.0
replan = false
ep_stages = 4
[ato.car]
mass = 32.0
eta = 0.5
''')
    s = load_scenario(p)
    assert s.ato.spans[0].span.limit_speeds == (20.0, 16.0)
    assert s.ato.spans[0].span.length == 2150.0                     # default: the stop mark
    assert s.ato.tuning == AtoTuning(replan_period=3.0, replan=False, ep_stages=4)
    assert s.ato.car == CarTraction(mass=32.0, eta=0.5)
    assert s.duration_s == 300.0


def steep(tmp_path) -> str:
    p = tmp_path / "steep.csv"
    p.write_text("distance_m,grade_permille\n0,0\n100,-180\n", encoding="utf-8")
    return p.as_posix()


BAD = {   # name: (TOML after [parameters], key and reason the message must hold)
    "driver and span": (SPAN + '[[driver]]\naction = "coast"\nuntil_time_s = 1.0\n',
                        "give one of [[driver]] phases, [driver_table] or [span], not [[driver]] and [span]"),
    "ato without span": ('[[driver]]\naction = "coast"\nuntil_time_s = 1.0\n[ato]\nreplan = true\n',
                         "ato: tunes the ATO of a [span] scenario"),
    "no stop": ("[span]\nschedule_s = 135.0\nlimit_kmh = [[0, 80]]\n", "span: stop_m is missing"),
    "no schedule": ("[span]\nstop_m = 2150.0\nlimit_kmh = [[0, 80]]\n", "span: schedule_s is missing"),
    "stop not a number": ('[span]\nstop_m = "far"\nschedule_s = 135.0\nlimit_kmh = [[0, 80]]\n',
                          "span.stop_m: expected a finite number, got 'far'"),
    "stop <= 0": ("[span]\nstop_m = 0.0\nschedule_s = 135.0\nlimit_kmh = [[0, 80]]\n",
                  "span.stop_m: must be > 0, got 0.0"),
    "stop beyond the span": ("[span]\nstop_m = 2150.0\nlength_m = 2000.0\nschedule_s = 135.0\n"
                             "limit_kmh = [[0, 80]]\n",
                             "span.stop_m: 2150.0 m is beyond the span (length_m = 2000.0 m)"),
    "schedule <= 0": ("[span]\nstop_m = 2150.0\nschedule_s = -1.0\nlimit_kmh = [[0, 80]]\n",
                      "span.schedule_s: must be > 0, got -1.0"),
    "no limits": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\n",
                  "span: give the speed limits as limit_kmh or limit_mps ([[distance_m, speed], ...]), none given"),
    "both limits": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\nlimit_kmh = [[0, 80]]\nlimit_mps = [[0, 20]]\n",
                    "not both"),
    "limit row": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\nlimit_kmh = [[0, 80, 1]]\n",
                  "span.limit_kmh[0]: expected [distance_m, speed], got [0, 80, 1]"),
    "first limit not at 0": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\nlimit_kmh = [[10, 80]]\n",
                             "span.limit_kmh[0]: the first limit must start at distance 0, got 10.0"),
    "limits not increasing": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\nlimit_kmh = [[0, 80], [0, 60]]\n",
                              "span.limit_kmh[1]: distances must increase (0.0 after 0.0)"),
    "limit <= 0": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\nlimit_kmh = [[0, 0]]\n",
                   "span.limit_kmh[0][1]: a speed limit must be > 0, got 0.0"),
    "limit beyond the span": ("[span]\nstop_m = 2150.0\nschedule_s = 135.0\nlimit_kmh = [[0, 80], [2150, 60]]\n",
                              "span: speed limit 1 starts at 2150.0 m, not inside the span [0, 2150.0) m"),
    "unknown span key": (SPAN + "stop_km = 2.15\n", "span: unknown key 'stop_km'"),
    "dwell on the first span": (SPAN + "dwell_s = 30.0\n",
                                "span.dwell_s: only for the second and later spans of a line"),
    "infeasible schedule": ("[span]\nstop_m = 2150.0\nschedule_s = 100.0\nlimit_kmh = [[0, 80], [900, 60], [1300, 80]]\n",
                            "span: the ATO cannot run this span: span.schedule = 100.00 s is infeasible: the "
                            "fastest run the controller plans"),
    "schedule too long": ("[span]\nstop_m = 2150.0\nschedule_s = 5000.0\nlimit_kmh = [[0, 80]]\n",
                          "span: the ATO cannot run this span: span.schedule = 5000.00 s is too long"),
    "unknown tuning": (SPAN + "[ato]\nreplan_every = 2.0\n", "ato: unknown key 'replan_every'"),
    "bad tuning": (SPAN + "[ato]\nreplan_period = 0.0\n", "ato: tuning.replan_period must be > 0, got 0.0"),
    "tuning not a number": (SPAN + '[ato]\nreplan_period = "2 s"\n',
                            "ato.replan_period: expected a number, got '2 s'"),
    "tuning not a bool": (SPAN + "[ato]\nreplan = 1\n", "ato.replan: expected true or false, got 1"),
    "car field a bool": (SPAN + "[ato.car]\nmass = true\n", "ato.car.mass: expected a number, got True"),
    "unknown car field": (SPAN + "[ato.car]\nweight = 30.0\n", "ato.car: unknown key 'weight'"),
    "bad car": (SPAN + "[ato.car]\neta_f = 2.0\n", "ato.car: car.eta_f must be in (0, 1], got 2.0"),
    "line: dwell missing": (SPAN.replace("[span]", "[[span]]") + "[[span]]\nstop_m = 1400.0\nschedule_s = 100.0\n"
                            "limit_kmh = [[0, 70]]\n",
                            "span[1].dwell_s: the standstill at the station before this span is missing or <= 0"),
    "line: dwell shorter than a station": (
        SPAN.replace("[span]", "[[span]]") + "[[span]]\ndwell_s = 10.0\nstop_m = 1400.0\nschedule_s = 100.0\n"
        "limit_kmh = [[0, 70]]\n",
        "span[1].dwell_s: 10.0 s is shorter than track.station_dwell = 20.0 s"),
}


@pytest.mark.parametrize("case", BAD)
def test_every_bad_input_names_file_key_and_reason(tmp_path, case):
    body, expected = BAD[case]
    p = write(tmp_path, BASE.format(grade=GRADE) + body)
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    assert str(e.value).startswith(f"{p}: "), str(e.value)
    assert expected in str(e.value), str(e.value)


def test_a_duration_that_ends_before_the_schedule_is_refused(tmp_path):
    p = write(tmp_path, "duration_s = 100.0\n" + BASE.format(grade=GRADE) + SPAN)
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    assert str(e.value) == (f"{p}: duration_s: 100.0 s ends before the schedules and dwells (135 s); "
                            f"leave it out for them and a minute more")


def test_a_limit_the_brakes_cannot_keep_is_refused_naming_the_file(tmp_path):
    """-180 permille at 80 km/h needs ~51 kN of brake to hold; the car has 45 kN."""
    p = write(tmp_path, BASE.format(grade=steep(tmp_path)) + "[span]\nstop_m = 500.0\nschedule_s = 60.0\n"
                                                             "limit_kmh = [[0, 80]]\n")
    with pytest.raises(ScenarioError) as e:
        load_scenario(p)
    msg = str(e.value)
    assert msg.startswith(f"{p}: span: the ATO cannot run this span: span.limit_speeds[0] = "), msg
    assert "cannot be met" in msg and "-180.0 permille" in msg


def test_a_copy_with_another_grade_profile_drives_over_that_grade(tmp_path):
    """One source: a scenario copied with another track.grade_profile (as sweeps and tests make
    them) gives an ATO planning over that profile, not over the file's."""
    from dataclasses import replace
    s = load_scenario(NOMINAL)
    flat = replace(s, parameters={**s.parameters, "track.grade_profile": ""})
    assert flat.ato_setup().spans[0].span.grade.grades == (0.0,)
    assert flat.new_driver().controllers[0].span.grade.grades == (0.0,)
    assert s.ato_setup() is s.ato and s.new_driver().controllers[0].span.grade == s.chain_setup().grade
    other = tmp_path / "other.csv"
    other.write_text("distance_m,grade_permille\n0,3\n", encoding="utf-8")
    s3 = replace(s, parameters={**s.parameters, "track.grade_profile": str(other)})
    assert s3.new_driver().controllers[0].span.grade.grades == (3.0,)


def test_an_empty_line_is_refused(tmp_path):
    p = write(tmp_path, "span = []\n" + BASE.format(grade=GRADE))
    with pytest.raises(ScenarioError, match="span: no spans given"):
        load_scenario(p)


# ------------------------------------------------------------------------------ metrics

TRUTH = VehicleParams()          # 30 t, 40 kN / 400 kW, 45 kN brake, dry rail
CAR = CarTraction()


def test_step_work_clips_to_the_plant_and_splits_the_brake():
    # 10 kN of traction over 2 m at 5 m/s: below every limit, 20 kJ exactly (products of small
    # integers are exact in binary floating point)
    assert step_work(4.0, 6.0, 100.0, 102.0, 10e3, 0.0, TRUTH, CAR) == (20e3, 0.0)
    # 60 kN asked at 5 m/s: the plant gives its 40 kN limit
    assert step_work(4.0, 6.0, 100.0, 102.0, 60e3, 0.0, TRUTH, CAR) == (80e3, 0.0)
    # a brake of 44 kN at 10 m/s: the regen's 40 kN (400 kW / 10 m/s) is regenerated
    assert step_work(11.0, 9.0, 0.0, 1.0, 0.0, 44e3, TRUTH, CAR) == (0.0, 40e3)
    # 20 kN of brake at 10 m/s: all of it regenerated; a brake wins over traction
    assert step_work(11.0, 9.0, 0.0, 1.0, 5e3, 20e3, TRUTH, CAR) == (0.0, 20e3)
    # at 1 m/s (below the regen's 5 km/h cut-off) nothing is regenerated
    assert step_work(1.2, 0.8, 0.0, 0.1, 0.0, 20e3, TRUTH, CAR) == (0.0, 0.0)
    # a departure after a station: the position restarted, s1 is the distance covered
    assert step_work(0.0, 0.5, 2150.0, 0.025, 8e3, 0.0, TRUTH, CAR) == (8e3 * 0.025, 0.0)


def test_energy_and_standstill_time():
    # 0.9 x 3.6 MJ at the wheel = 1 kWh from the network; 1.2 MJ regenerated gives back 0.6 x
    # 1/3 kWh; exact to 2 ulp of 1 (two divisions and a product)
    assert energy_kwh(0.9 * 3.6e6, 0.0, CAR) == pytest.approx(1.0, rel=4e-16)
    assert energy_kwh(0.9 * 3.6e6, 1.2e6, CAR) == pytest.approx(1.0 - 0.6 / 3.0, rel=1e-15)
    # constant deceleration from 2 m/s over 0.05 m takes 0.05 s; a slower stop is capped at h
    assert standstill_time(100.0, 0.1, 2.0, 0.05) == 100.0 + 0.05
    assert standstill_time(100.0, 0.1, 0.5, 0.05) == 100.0 + 0.1
    assert standstill_time(7.0, 0.1, 0.0, 0.0) == 7.0


def hand_made_run():
    """A 300 m level span (schedule 60 s) and a hand-made trace of 12 rows at 0.1 s: accelerate
    at 10 kN, brake at 20 kN, come to rest 0.05 s into the last moving step; one supervisor
    step; the controller's calls as AtoSteps (HOLD at the end)."""
    s = scenario_from_dict({"name": "hand", "step_s": 0.1,
                            "span": {"stop_m": 300.0, "schedule_s": 60.0, "limit_kmh": [[0, 80], [200, 40]]}},
                           "hand.toml")
    v = np.array([0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 8.0, 6.0, 4.0, 2.0, 0.0, 0.0])
    x = np.empty_like(v)
    x[0] = 299.0
    for j in range(len(v) - 1):
        x[j + 1] = x[j] + 0.5 * (v[j] + v[j + 1]) * 0.1
    x[10] = x[9] + 0.05          # from 2 m/s over 0.05 m: at rest 0.05 s into the step
    x[11] = x[10]
    t = np.arange(len(v)) * 0.1
    f = np.array([10e3] * 5 + [0.0] * 7)
    b = np.array([0.0] * 5 + [20e3] * 7)
    u = {"traction_force_demand": f, "brake_force_demand": b, "wind_speed": np.zeros(12),
         "car.payload": np.zeros(12)}
    result = RunResult(s, t, {"car.speed": v, "car.position": x}, {}, inputs=u)
    modes = [int(AtoMode.TG)] * 5 + [int(AtoMode.RK), int(AtoMode.OVERSPEED)] + [int(AtoMode.TM)] * 3 \
        + [int(AtoMode.HOLD)] * 2
    steps = [AtoStep(float(t[j]), 0, AtoCommand(f[j], b[j], modes[j], 0.0)) for j in range(12)]
    return s, result, steps, v, x, t


def test_metrics_on_a_hand_made_trace():
    s, result, steps, v, x, t = hand_made_run()
    (m,) = ato_metrics(s, result, steps)
    # at rest 0.05 s into the step from row 9 (t = 0.9 s): arrival 0.95 s, departure 0; the
    # 0.05 m is a difference of positions near 300 m: exact to a few ulp of 300 (6e-14 m)
    assert m.departure_s == 0.0
    assert m.arrival_s == pytest.approx(t[9] + 0.05, abs=1e-12)
    assert m.arrival_error_s == pytest.approx(t[9] + 0.05 - 60.0, abs=1e-12)
    assert m.stop_error_m == x[11] - 300.0 and m.stop_error_m > 0.0      # past the mark here
    # the limit drops to 40 km/h at 200 m: the whole trace is beyond it; 10 m/s at row 5
    assert m.margin_mps == pytest.approx(kmh_to_mps(40.0) - 10.0, abs=1e-14)   # 1 ulp of 11 m/s
    assert m.interventions == 1 and int(AtoMode.OVERSPEED) in INTERVENTIONS
    assert m.arrived
    # energy by hand: traction rows 0-4 (below every limit), regen of 20 kN on rows 5-8 (at or
    # above 3 m/s mean speed: full regen); row 9 (1 m/s mean) regenerates nothing; the sum's
    # order differs from the module's: a few ulp
    ds = np.diff(x)
    w_f = float(np.sum(10e3 * ds[:5]))
    w_r = float(np.sum(20e3 * ds[5:9]))
    assert m.energy_kwh == pytest.approx((w_f / 0.9 - 0.6 * w_r) / 3.6e6, rel=1e-13)


def test_metrics_of_a_car_that_never_came_to_rest():
    s, result, steps, v, x, t = hand_made_run()
    result.signals["car.speed"] = np.where(v == 0.0, 0.5, v)
    result.signals["car.speed"][0] = 0.0
    (m,) = ato_metrics(s, result, steps)
    assert math.isnan(m.arrival_error_s) and not m.arrived


# ------------------------------------------------------------------------------ closed loop

@pytest.fixture(scope="module")
def nominal():
    s = load_scenario(NOMINAL)
    d = s.new_driver()
    return s, run_on_chain(s, driver=d), d


def test_the_nominal_span_in_closed_loop_on_the_chain(nominal):
    """The chain as the RailCar FMU builds it, seed 31 (the scenario's): the ATO's targets."""
    s, r, d = nominal
    (m,) = ato_metrics(s, r, d.steps)
    assert m.arrived and d.finished
    assert abs(m.arrival_error_s) <= 2.5, m          # [s] target of Meleshin (2011), Sidorenko (1997)
    assert abs(m.stop_error_m) <= 0.3, m             # [m] target of Sidorenko (1997)
    assert m.margin_mps > 0.0 and m.interventions == 0, m
    assert 1.5 < m.energy_kwh < 3.5, m               # [kWh] the study's ~2.25 kWh, loosely
    assert r.time[-1] < s.duration_s                 # ended when the car stood at the mark
    assert len(d.steps) == len(r.time)               # one call per row, the last not applied


def test_the_recorded_outputs_give_the_runs_commands(nominal):
    s, r, d = nominal
    again = replay_steps(s, r)
    assert again.steps == d.steps                    # AtoCommand floats equal, every call


def test_the_line_stops_at_each_station(tmp_path):
    """Three spans in one run: each arrives and stops at its own mark, the plant restarts the
    distance and the estimator recognises both intermediate stations, 4 t board at the second."""
    s = load_scenario(LINE)
    d = s.new_driver()
    r = run_on_chain(s, driver=d)
    ms = ato_metrics(s, r, d.steps)
    assert [m.stop_m for m in ms] == [2150.0, 1400.0, 1800.0]
    for m in ms:
        assert m.arrived and abs(m.stop_error_m) <= 0.3 and abs(m.arrival_error_s) <= 2.5, m
        assert m.margin_mps > 0.0 and m.interventions == 0, m
    assert int(r["est.station_stops"][-1]) == 2
    # each span departs after its predecessor's arrival and the 30 s dwell; the dwell counts
    # from the call at which the ATO declared the stop (its filter standing for stand_time,
    # 0.5 s): a few seconds after the true rest at most
    for prev, m in zip(ms, ms[1:]):
        assert prev.arrival_s + 30.0 <= m.departure_s <= prev.arrival_s + 30.0 + 5.0, (prev, m)
    mass = r["car.total_mass"]
    assert mass[0] == 30.0 and mass.max() == 34.0 and mass[-1] == 32.0   # [t] exact sums


def test_a_span_scenario_on_the_chain_needs_nothing_but_the_atos_reads(nominal):
    """AtoDriver.reads: what an FMU stepper must read for it (models.ato.interface.ALL_INPUTS and
    est.station_stops for a line; never the plant's truth); every one is a RailCar output the run records."""
    s, r, d = nominal
    from models.ato.interface import ALL_INPUTS as ATO_INPUTS
    assert set(ATO_INPUTS) <= set(AtoDriver.reads) <= set(r.signals)
    assert set(AtoDriver.reads) - set(ATO_INPUTS) == {"est.station_stops"}


# ------------------------------------------------------------------------------ the report

def test_the_report_figure_shows_planned_and_actual_speed_and_the_modes(nominal):
    from matplotlib.collections import PolyCollection
    s, r, d = nominal
    fig = ato_figure(r, d.steps)
    ax, bar = fig.axes[0], fig.axes[1]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    assert {"speed limit V_lim", "true car.speed", "filter.speed (what the ATO reads)",
            "planned (ATO commands)"} <= set(lines)
    span = s.ato.spans[0].span
    lim = lines["speed limit V_lim"]
    assert list(lim.get_xdata()) == [0.0, 900.0, 1300.0, 2150.0]
    assert list(lim.get_ydata()) == [*span.limit_speeds, span.limit_speeds[-1]]
    assert np.array_equal(lines["true car.speed"].get_ydata(), r["car.speed"][:len(d.steps)])
    planned = lines["planned (ATO commands)"].get_ydata()
    assert np.nanmax(planned) <= span.limit_speeds[0]          # never planned over the limit
    assert ax.get_ylabel() == "speed [m/s]" and "[m]" in bar.get_xlabel()
    # one bar segment per run of equal modes, in the mode's colour
    runs = mode_runs([st.command.mode for st in d.steps])
    bars = [c for c in bar.collections if isinstance(c, PolyCollection)]
    assert len(bars) == len(runs)
    import matplotlib.colors as mc
    for c, (mode, _, _) in zip(bars, runs):
        assert np.allclose(c.get_facecolor()[0], mc.to_rgba(MODE_COLOURS[AtoMode(mode)]), atol=0)
    names = [t.get_text() for t in bar.get_legend().get_texts()]
    assert {"TG", "VB", "HOLD"} <= set(names)
    import matplotlib.pyplot as plt
    plt.close(fig)


def test_every_mode_has_a_colour_of_its_own():
    assert set(MODE_COLOURS) == set(AtoMode)
    assert len(set(MODE_COLOURS.values())) == len(AtoMode)


def test_mode_runs():
    assert mode_runs([0, 0, 2, 2, 2, 8]) == [(0, 0, 2), (2, 2, 5), (8, 5, 6)]
    assert mode_runs([]) == []


# ------------------------------------------------------------------------------ harness run (FMU)

def test_harness_run_prints_and_writes_the_ato_report(built_fmus, tmp_path, capsys):
    """``harness run`` on the native FMU of the session build: the ATO table with units, the
    same figures as the chain's run (the FMU is bit-identical to the chain), summary.md and
    ato.png; and FmuRunner.run with a restricted output list still reads what the ATO needs."""
    from harness.__main__ import main
    from harness.run.runner import FmuRunner
    out = tmp_path / "out"
    dist = built_fmus["RailCar"].parent
    assert main(["run", str(NOMINAL), "--out", str(out), "--dist", str(dist), "--fmu", "native"]) == 0
    text = capsys.readouterr().out
    assert "ATO, per span:" in text and "arrival err [s]" in text and "stop err [m]" in text
    assert "energy [kWh]" in text and "V_lim margin [m/s]" in text
    md = (out / "summary.md").read_text(encoding="utf-8")
    assert "| span | schedule [s] | arrival err [s] |" in md and "![ato](ato.png)" in md
    assert (out / "ato.png").stat().st_size > 10_000

    s = load_scenario(NOMINAL)
    chain_driver = s.new_driver()
    run_on_chain(s, driver=chain_driver)
    with FmuRunner(dist / "native" / "RailCarNative.fmu") as runner:
        d = s.new_driver()
        r = runner.run(s, outputs=["car.speed", "car.position"], driver=d)
    assert d.steps == chain_driver.steps             # the ATO got its reads, bit for bit
    assert set(r.signals) == {"car.speed", "car.position"}


def test_harness_run_refuses_a_bad_span_in_one_line(tmp_path, capsys):
    """Invalid input: exit code 2, one line on stderr naming file, key and reason; no FMU built."""
    from harness.__main__ import main
    p = write(tmp_path, BASE.format(grade=GRADE) + BAD["stop beyond the span"][0])
    assert main(["run", str(p), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"error: {p}: span.stop_m: 2150.0 m is beyond the span (length_m = 2000.0 m)"]
    assert not (tmp_path / "out").exists()
