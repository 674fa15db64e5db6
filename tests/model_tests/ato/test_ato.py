"""The ATO controller (models/ato/controller.py, models/ato/planner.py, models/ato/stopping.py): its fast
re-planner against the maximum-principle synthesis, its errors and safe outputs, and the closed
loop with the RailCar chain (plant, sensors, estimator: models.compiled.open_chain, configured
as the RailCar FMU with its default parameters) on a library-like span.

Units: s [m], V [m/s], t [s], force [N], mass [t]. Every run is seeded (the chain's noise seed;
the controller has no randomness). Targets from the sources: arrival within +-2.5 s (Meleshin
2011, Sidorenko 1997), stop within +-0.3 m (Sidorenko), never past +1 m, the true speed never
above V_lim.
"""
from __future__ import annotations

import logging
import math
import statistics
import time
from dataclasses import dataclass, field

import pytest

from fmu_src.variables import FORMER_DEFAULTS
from models.ato.controller import AtoController
from models.ato.interface import INPUTS, AtoMode, AtoTuning
from models.ato.motion import PlanCar
from models.ato.planner import ReducedCourse, ReducedPlanner
from models.ato.stopping import RelayBrake
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile
from models.planning.trajectory import synthesize
from models.units import G, kmh_to_mps

V80, V60 = kmh_to_mps(80.0), kmh_to_mps(60.0)
GRADE = GradeProfile((0.0, 300.0, 800.0, 1100.0, 1500.0), (0.0, 15.0, -10.0, 0.0, 5.0))
# the library's demo grade profile, extended to 2.2 km with a 60 km/h zone; 135 s is 9.6 % above
# the minimum-time run (123.2 s), where the energy-optimal run has two traction applications
SPAN = Span(2200.0, 135.0, stop=2150.0, grade=GRADE, limit_distances=(0.0, 900.0, 1300.0),
            limit_speeds=(V80, V60, V80))
CAR = CarTraction()                   # the configured car: the RailCar FMU's defaults
STEP = 0.1                            # [s] communication step
REGULATED = AtoTuning()
FIXED = AtoTuning(replan=False, use_estimates=False)
ARRIVAL_TOL = 2.5                     # [s] Meleshin (2011), Sidorenko (1997)
STOP_TOL = 0.3                        # [m] Sidorenko (1997)


# ======================================================================= the closed loop

@dataclass
class Run:
    arrival: float                    # true standstill time - schedule [s]
    stop: float                       # true stop position - stop mark [m]
    margin: float                     # min over the run of V_lim(s) - V, true values [m/s]
    ctrl: AtoController
    modes: list = field(default_factory=list)
    brakes: list = field(default_factory=list)
    lag: list = field(default_factory=list)       # planned - true speed at each command [m/s]
    first_stop: float = math.nan      # true position at the first standstill - stop mark [m]


def closed_loop(tuning: AtoTuning, seed: int, overrides: dict | None = None, wind: float = 0.0,
                corrupt=None, span: Span = SPAN) -> Run:
    """The controller on the RailCar chain, one 0.1 s step at a time, until the car stands at
    the mark (the harness's scenario-driver loop will replace this). ``corrupt(t, outputs)``
    may change what the controller sees."""
    from fmu_src.adapter import chain_config
    from harness.run.scenario import railcar_values
    from models.compiled import open_chain
    values = railcar_values({**(overrides or {}), "seed": seed})
    chain = open_chain(chain_config(values), span.grade)
    ctrl = AtoController(span, CAR, tuning)
    out = chain.outputs()
    run = Run(math.inf, math.nan, math.inf, ctrl)
    t, k = 0.0, 0
    while k < 4000:
        seen = dict(out)
        if corrupt is not None:
            corrupt(t, seen)
        cmd = ctrl.demands(t, seen)
        v0, s0 = out["car.speed"], out["car.position"]
        run.modes.append(cmd.mode)
        run.brakes.append(cmd.brake)
        run.lag.append(cmd.planned_speed - v0)
        chain.do_step(t, STEP, cmd.traction, cmd.brake, wind, 0.0)
        k += 1
        t = k * STEP
        out = chain.outputs()
        v1, s1 = out["car.speed"], out["car.position"]
        run.margin = min(run.margin, span.v_lim(s1) - v1)
        if math.isinf(run.arrival) and v0 > 0.0 and v1 == 0.0 and s1 > 0.5 * span.stop:
            # stopped inside the step: at constant deceleration it took 2 ds / v0
            run.arrival = t - STEP + min(STEP, 2.0 * (s1 - s0) / v0) - span.schedule
            run.first_stop = s1 - span.stop
        if ctrl.finished and v1 == 0.0:
            break
    run.stop = out["car.position"] - span.stop
    return run


def _interventions(run: Run) -> int:
    return sum(m in (AtoMode.SAFE, AtoMode.OVERSPEED) for m in run.modes)


# ======================================================================= the re-planner

def test_plan_car_has_the_cars_characteristics():
    """The re-planner's PlanCar binds CarTraction's traction, regenerative and total brake
    limits into scalar methods: they must agree with CarTraction (rel. 1e-12: the same
    formulas, the adhesion constant multiplied out once) from standstill to 30 m/s; a car with
    another power limit differs (the comparison can fail)."""
    pc = PlanCar(CAR, CAR.mass, CAR.A0, CAR.A1, CAR.A2)
    for v in (0.0, 1.0, CAR.regen_fade_speed, 9.9, 10.0, 17.3, 22.2, 30.0):
        assert pc.f_max(v) == pytest.approx(CAR.f_max(v), rel=1e-12)
        assert pc.b_service(v) == pytest.approx(min(CAR.r_max(max(v, CAR.regen_fade_speed)),
                                                    CAR.brake_total_max(v)), rel=1e-12)
        assert pc.w0(v) == pytest.approx(CAR.A0 + CAR.A1 * v + CAR.A2 * v * v, rel=1e-12)
    assert pc.hold_regen_speed(15.0) == pytest.approx(CAR.hold_speed_regen(15.0), rel=1e-9)
    other = PlanCar(CarTraction(traction_power_max=300e3), CAR.mass, CAR.A0, CAR.A1, CAR.A2)
    assert other.f_max(22.2) != pytest.approx(CAR.f_max(22.2), rel=1e-6)


@pytest.fixture(scope="module")
def synthesis():
    """Meleshin's maximum-principle plan for SPAN (models.planning.trajectory.synthesize, ~3 s)."""
    return synthesize(SPAN, CAR)


def _switches(plan):
    out = []
    for k, m in enumerate(plan.mode):
        if not out or out[-1][1] != m:
            out.append((plan.s[k], int(m)))
    return out


def test_reduced_planner_reproduces_the_maximum_principle_plan(synthesis):
    """With the synthesis's conditions (no limit margin, the full electric brake, the final
    curve at the service brake's ~1.34 m/s^2) the re-planner must find the same run: the same
    mode sequence, each switching point within 10 m (two grid steps), V_c within 2 % and the
    energy within 1 % (the issue's brute-force bound) of synthesize(), arriving within its
    0.05 s tolerance. Both differ in grid (10 m RK2 vs 5 m RK4), so not bit for bit. A plan for
    another schedule misses every bound (the comparison can fail)."""
    a_service = CAR.regen_force_max / (1000.0 * CAR.mass) + CAR.A0 * G / 1000.0
    course = ReducedCourse(SPAN, CAR, step=10.0, limit_margin=0.0, a_ep=a_service)
    pc = PlanCar(CAR, CAR.mass, CAR.A0, CAR.A1, CAR.A2, brake_share=1.0)
    plan = ReducedPlanner(course).plan(pc, 0.0, 0.0, 0.0, SPAN.schedule)
    assert plan.status == "ok"
    assert abs(plan.arrival - SPAN.schedule) <= 0.05
    ours, theirs = _switches(plan), [(s, int(m)) for s, m in synthesis.switches]
    assert [m for _, m in ours] == [m for _, m in theirs]
    assert max(abs(a - b) for (a, _), (b, _) in zip(ours, theirs)) <= 10.0
    assert plan.hold_speed == pytest.approx(synthesis.hold_speed, rel=0.02)
    assert plan.energy_kwh == pytest.approx(synthesis.energy_kwh, rel=0.01)
    tight = ReducedPlanner(course).plan(pc, 0.0, 0.0, 0.0, 129.0)
    assert tight.hold_speed != pytest.approx(synthesis.hold_speed, rel=0.02)
    assert tight.energy_kwh != pytest.approx(synthesis.energy_kwh, rel=0.01)


def test_replanning_is_fast_and_meets_the_arrival_from_mid_span():
    """The regulator re-plans every 2 s from wherever the car is: from states along a run, with
    a 20 % heavier car, each re-plan must arrive on time (0.05 s, its tolerance) within a few
    forward runs of the policy (at most 12; measured at most 7), and take milliseconds: median
    CPU time < 50 ms (measured 2-10 ms on an idle machine; process time, so that other
    processes do not count, and room for a slow one), where synthesize() takes seconds."""
    ctrl = AtoController(SPAN, CAR, REGULATED)
    heavy = PlanCar(CAR, 36.0, CAR.A0, CAR.A1, CAR.A2, 0.85, brake_mass=36.0)
    walls, trials = [], []
    for k, x in enumerate(range(100, 2000, 100)):
        v = ctrl.initial_plan.speed_at(x)
        t = ctrl.initial_plan.t[min(range(len(ctrl.initial_plan.s)),
                                    key=lambda j: abs(ctrl.initial_plan.s[j] - x))]
        t0 = time.process_time()
        plan = ctrl.planner.plan(heavy, float(x), v, t + 0.5, SPAN.schedule)
        walls.append(time.process_time() - t0)
        trials.append(plan.trials)
        if plan.status == "ok":
            assert abs(plan.arrival - SPAN.schedule) <= 0.05, (x, plan.arrival)
        else:       # late in the run a heavier car can no longer make up 0.5 s
            assert plan.status == "late" and x >= 1500 and plan.arrival > SPAN.schedule
    assert statistics.median(walls) < 0.05
    assert max(trials) <= 12


# ======================================================================= bad inputs

@pytest.mark.parametrize("span, tuning, message", [
    (SPAN.with_schedule(110.0), REGULATED, "span.schedule = 110.00 s is infeasible"),
    (SPAN.with_schedule(3000.0), REGULATED, "span.schedule = 3000.00 s is too long"),
    (Span(2200.0, 135.0, stop=2150.0, grade=GradeProfile((0.0, 1000.0, 1200.0), (0.0, -170.0, 0.0)),
          limit_distances=(0.0, 1000.0), limit_speeds=(V80, V60)), REGULATED,
     "span.limit_speeds[1] = 16.666666666666668 m/s (from s = 1000.0 m) cannot be met"),
    (Span(2200.0, 135.0, stop=2150.0, limit_distances=(0.0, 1000.0, 1100.0),
          limit_speeds=(V80, 2.0, V80)), REGULATED, "span.limit_speeds[1] = 2.0 m/s"),
    (SPAN, AtoTuning(a_ep=2.0), "tuning.a_ep = 2.0 m/s^2 needs"),
])
def test_bad_spans_and_schedules_are_refused_naming_the_value(span, tuning, message):
    """An infeasible schedule, one too long to be met, a limit the brakes cannot keep on a
    -170 permille descent, a limit the 0.5 m/s margin leaves nothing of, an EP deceleration the
    electro-pneumatic brake cannot give: ValueError naming the value at construction."""
    with pytest.raises(ValueError) as e:
        AtoController(span, CAR, tuning)
    assert message in str(e.value)


def test_a_stop_mark_beyond_the_span_and_bad_tuning_are_refused():
    """The stop mark is checked where the span is built (models.planning.span.Span) and names both
    values; bad tuning and wrong argument types name the field."""
    with pytest.raises(ValueError, match=r"span.stop = 2300.0 m is beyond the span "
                                         r"\(span.length = 2200.0 m\)"):
        Span(2200.0, 135.0, stop=2300.0)
    for kw, name in (({"a_ep": 0.0}, "tuning.a_ep"), ({"ep_stages": 0}, "tuning.ep_stages"),
                     ({"brake_share": 1.5}, "tuning.brake_share"),
                     ({"replan": "yes"}, "tuning.replan"),
                     ({"limit_margin": math.nan}, "tuning.limit_margin"),
                     ({"mass_band": 0.5}, "tuning.mass_band")):
        with pytest.raises(ValueError, match=name):
            AtoTuning(**kw)
    with pytest.raises(ValueError, match="span must be a models.planning.span.Span"):
        AtoController("2150 m", CAR)
    with pytest.raises(ValueError, match="car must be a models.planning.span.CarTraction"):
        AtoController(SPAN, CAR.vehicle)


def _at_rest() -> dict:
    """The estimator's outputs before departure (the FMU's start values)."""
    return {"filter.speed": 0.0, "filter.position": 0.0, "filter.speed_std": 0.0,
            "filter.position_std": 0.0, "est.mass": 30.0, "est.A0": 1.0, "est.A1": 0.03,
            "est.A2": 0.01, "est.status": 0, "est.samples": 0}


def test_missing_or_non_finite_outputs_give_the_safe_brake_with_a_logged_reason(caplog):
    """Every output the controller reads, NaN, inf, missing or not a number (and a NaN time,
    or no mapping at all): the command is the full brake, no traction, mode SAFE, and the
    reason names the variable, logged once per episode (a NaN held for several steps is one
    warning). With good outputs back, the controller runs on (full traction from rest)."""
    ctrl = AtoController(SPAN, CAR, REGULATED)
    good = ctrl.demands(0.0, _at_rest())
    assert good.mode == AtoMode.TG and good.traction == CAR.traction_force_max and good.brake == 0.0
    bad_values = [(math.nan, "nan"), (math.inf, "inf"), (-math.inf, "-inf"), ("fast", "'fast'")]
    t = 0.0

    def recover():
        """The safe brake latches: held through 1 s of sane inputs, then released."""
        nonlocal t
        for _ in range(10):
            t += STEP
            assert ctrl.demands(t, _at_rest()).mode == AtoMode.SAFE
        t += STEP
        assert ctrl.demands(t, _at_rest()).mode == AtoMode.TG

    for name in INPUTS:
        for value, shown in bad_values:
            caplog.clear()
            with caplog.at_level(logging.WARNING, logger="models.ato.controller"):
                for _ in range(3):
                    t += STEP
                    out = _at_rest()
                    out[name] = value
                    cmd = ctrl.demands(t, out)
                    assert (cmd.traction, cmd.brake, cmd.mode) == (0.0, CAR.brake_force_max,
                                                                   AtoMode.SAFE)
            assert len(caplog.records) == 1
            assert f"{name} = {shown}" in caplog.records[0].getMessage()
            recover()
        out = _at_rest()
        del out[name]
        t += STEP
        assert ctrl.demands(t, out).mode == AtoMode.SAFE
        assert ctrl.events[-1][1] == f"{name} is missing: safe brake"
        recover()
    assert ctrl.demands(math.nan, _at_rest()).mode == AtoMode.SAFE
    assert "time t = nan" in ctrl.events[-1][1]
    t += STEP
    assert ctrl.demands(t, None).mode == AtoMode.SAFE
    recover()


def test_supervisor_brakes_when_the_speed_plus_its_uncertainty_is_over_the_limit():
    """The supervisor compares filter.speed + 3 filter.speed_std with V_lim (and the full-brake
    curves to lower limits ahead): at s = 500 m (80 km/h, the 60 km/h zone 400 m ahead) a car
    at V80 - 0.1 m/s with 0.01 m/s uncertainty is under it (the controller brakes along its
    own envelope, not OVERSPEED), with 0.1 m/s uncertainty over it (full brake, OVERSPEED);
    so is one 0.1 m/s over the limit with none."""
    def at(v, sd, s=500.0):
        ctrl = AtoController(SPAN, CAR, REGULATED)
        out = _at_rest()
        out.update({"filter.speed": v, "filter.speed_std": sd, "filter.position": s,
                    "filter.position_std": 1e-9})
        return ctrl.demands(0.0, out)
    calm = at(V80 - 0.1, 0.01)
    assert calm.mode != AtoMode.OVERSPEED and calm.traction == 0.0
    # (1e-9: a moving car's filter is never exact, a std of 0 is refused as a bad input)
    for cmd in (at(V80 - 0.1, 0.1), at(V80 + 0.1, 1e-9), at(V60 + 0.1, 1e-9, s=1000.0)):
        assert (cmd.mode, cmd.brake, cmd.traction) == (AtoMode.OVERSPEED, CAR.brake_force_max, 0.0)


def test_supervisor_reads_the_position_k_sigma_further_on():
    """The '+1 m past the mark' line (and every supervision curve) is read at filter.position
    + k_sigma x filter.position_std: 1 m before the mark, a speed the curve allows at the
    filter's position (0.05 m/s under it) wakes the supervisor once the position is 0.3 m
    uncertain (read 0.9 m further on, the curve is ~0.45 m/s lower), not when it is certain."""
    ctrl = AtoController(SPAN, CAR, REGULATED)
    s = SPAN.stop - 1.0
    q_here, _ = ctrl._interp(ctrl._sup_q, s)
    q_on, _ = ctrl._interp(ctrl._sup_q, s + 3.0 * 0.3)
    v = math.sqrt(q_here) - 0.05
    assert math.sqrt(q_on) < v - 0.3                  # the test point is where it matters

    def at(psd):
        out = _at_rest()
        out.update({"filter.speed": v, "filter.position": s, "filter.position_std": psd,
                    "filter.speed_std": 1e-9})
        return AtoController(SPAN, CAR, REGULATED).demands(0.0, out)
    assert at(1e-9).mode != AtoMode.OVERSPEED
    cmd = at(0.3)
    assert (cmd.mode, cmd.brake, cmd.traction) == (AtoMode.OVERSPEED, CAR.brake_force_max, 0.0)


def test_relay_enters_with_the_stages_the_remaining_distance_needs():
    """A car that reaches the EP stage above its programmed speed (2 m/s with 1 m to go: V_p
    is 1.41 m/s) must still stop at the aim: the first command gives the stages for v^2 / (2 d)
    = 2 m/s^2 (all 6; the a_ep feed-forward alone gave 4 and the relay needed 2 dwells for the
    rest), one at V_p the a_ep stages (4)."""
    def relay():
        return RelayBrake(stop=100.0, a_ep=1.0, stage_force=7500.0, n_stages=6, hysteresis=0.03,
                          stage_speed=0.1, dwell=0.3, creep_speed=0.3, creep_accel=0.2,
                          stop_window=0.15)
    pc = PlanCar(CAR, 30.0, CAR.A0, CAR.A1, CAR.A2)
    assert relay().command(0.0, 99.0, 2.0, pc, 0.0)[1:3] == (45000.0, 6)
    assert relay().command(0.0, 99.0, math.sqrt(2.0), pc, 0.0)[1:3] == (30000.0, 4)
    # below V_p (its aim moved towards the mark: 1.2 m/s with 2 m to go, V_p would be 2 m/s)
    # the programmed curve runs through where the car is, 0.36 m/s^2, and the relay brakes for
    # it (10.5 kN: 1 stage, not the a_ep's 4, nor 0 and a coast); never below 0.3 a_ep (then it
    # creeps on)
    r = relay()
    _, brake, stage, v_p = r.command(0.0, 98.0, 1.2, pc, 0.0)
    assert r.a_prog == pytest.approx(0.36, rel=1e-12) and v_p == pytest.approx(1.2, rel=1e-12)
    assert (brake, stage) == (7500.0, 1)
    r = relay()
    r.command(0.0, 90.0, 1.0, pc, 0.0)
    assert r.a_prog == 0.3                       # 1 / 20 = 0.05 m/s^2, bounded


def test_after_the_stand_the_car_creeps_once():
    """After the settle stand (models/ato/controller.py: short stop, stand, creep), a car that stands
    0.2 m short of the mark (filter) with every EP stage off creeps on (mode CREEP); once it has
    crept and the relay has braked, standing 0.2 m short by the filter ends the stop (HOLD):
    the filter's distance at rest wanders ~filter.position_std, and a second creep on that
    noise took a 0.444 m/s-noise run (seed 51) from 0.06 m short to 0.50 m past the mark.
    The controller's state is set as the closed loop leaves it (white box)."""
    def settled(crept):
        ctrl = AtoController(SPAN, CAR, REGULATED)
        ctrl.phase, ctrl._settle, ctrl.settled, ctrl._crept = "ep", True, True, crept
        ctrl.relay.stop = SPAN.stop - REGULATED.creep_aim
        ctrl.relay.stop_window = REGULATED.settle_window
        ctrl.relay.stage, ctrl.t_departure = (6 if crept else 0), 0.0
        return ctrl
    out = _at_rest()
    out.update({"filter.position": SPAN.stop - 0.2, "filter.position_std": 0.2,
                "est.status": 2, "est.samples": 1000})
    ctrl = settled(crept=False)
    assert ctrl.demands(140.0, out).mode == AtoMode.CREEP
    ctrl = settled(crept=True)
    modes = [ctrl.demands(140.0 + 0.1 * k, out).mode for k in range(7)]
    assert AtoMode.CREEP not in modes and modes[-1] == AtoMode.HOLD and ctrl.finished


def test_relay_brake_switches_stages_on_the_speed_error():
    """Sidorenko's relay (models/ato/stopping.py), stages of 7.5 kN: it starts with the stages
    the feed-forward needs (30 t x 1.0 m/s^2 less the resistance: 29.7 kN -> 4, rounded);
    more than the 0.03 m/s hysteresis above the programmed speed switches one more stage on
    (one more per further 0.1 m/s), as much below one off, within it nothing changes, and no
    stage changes within 0.3 s of the last (the valve's dwell). Stopped short of the mark with
    every stage off it creeps on with traction; at and past the mark: all stages."""
    relay = RelayBrake(stop=100.0, a_ep=1.0, stage_force=7500.0, n_stages=6, hysteresis=0.03,
                       stage_speed=0.1, dwell=0.3, creep_speed=0.3, creep_accel=0.2,
                       stop_window=0.15)
    pc = PlanCar(CAR, 30.0, CAR.A0, CAR.A1, CAR.A2)
    s = 98.0
    vp = relay.programmed_speed(s)
    assert vp == pytest.approx(2.0, rel=1e-12)
    steps = [(0.0, 0.0, 4), (0.1, 0.05, 4), (0.3, 0.05, 5), (0.4, 0.05, 5), (0.6, 0.25, 6),
             (0.9, -0.05, 5), (1.2, 0.02, 5), (1.5, -0.2, 3)]
    for t, err, stage in steps:
        traction, brake, got, v_p = relay.command(t, s, vp + err, pc, 0.0)
        assert (traction, brake, got, v_p) == (0.0, 7500.0 * stage, stage, vp), (t, err)
    f, b, stage, _ = relay.command(1.8, 99.0, 0.0, pc, 0.0)
    assert (stage, b) == (-1, 0.0) and f > 0.0                   # 1 m short, at rest: creep
    assert relay.command(1.9, 100.0, 0.1, pc, 0.0)[1:3] == (45000.0, 6)


# ======================================================================= closed loop

@pytest.mark.slow
def test_nominal_closed_loop_meets_the_schedule_and_the_stop_mark():
    """Four seeds, the estimator in the loop, the configured car equal to the true one: every
    run arrives within +-2.5 s, stops within +-0.3 m, the true speed stays under V_lim, no safe
    brake or supervisor intervention, and the controller re-planned with the identified mass
    and resistance (est.status usable after its 100 samples). The car follows the planned
    speed it reports: RMS of planned - true speed <= 0.3 m/s (measured 0.12 m/s; 0.3 m/s is
    1.9 % of the mean speed, what 2.5 s is of 135 s)."""
    for seed in (1, 2, 3, 4):
        run = closed_loop(REGULATED, seed)
        assert abs(run.arrival) <= ARRIVAL_TOL, (seed, run.arrival)
        assert abs(run.stop) <= STOP_TOL, (seed, run.stop)
        assert run.margin > 0.0, (seed, run.margin)
        assert _interventions(run) == 0
        assert run.ctrl.finished and run.ctrl.replans >= 40     # ~55 in 110 s before braking
        assert any("est.* usable" in e for _, e in run.ctrl.events)
        assert AtoMode.EP in run.modes and run.modes[-1] == AtoMode.HOLD
        # filter.position_std ~0.07 m at the final braking curve (< settle_std 0.1): one stop
        assert AtoMode.SETTLE not in run.modes and run.first_stop == run.stop
        moving = [x for x, m in zip(run.lag, run.modes) if m != AtoMode.HOLD]
        assert math.sqrt(statistics.fmean(x * x for x in moving)) <= 0.3


DISTURBANCES = {   # RailCar overrides (the truth), wind [m/s]; the controller keeps CAR
    "mass +20 %": ({"car.mass": 36.0}, 0.0),
    "mass -20 %": ({"car.mass": 24.0}, 0.0),
    "headwind 5 m/s": ({}, 5.0),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", list(DISTURBANCES))
def test_the_regulator_absorbs_what_the_fixed_plan_does_not(case):
    """Mass +-20 % and a 5 m/s headwind (Meleshin's disturbances; the controller is configured
    with the 30 t car and still air): the fixed plan (configured coefficients, no re-planning)
    is off by at least 2 s (100-seed means: +6.0 s and -3.7 s for the mass, +2.3 s for the
    wind), the regulator (identified values, re-planning) arrives within +-2.5 s and removes at
    least 1.5 s of the fixed plan's error; both stop within +-0.3 m and stay under V_lim."""
    overrides, wind = DISTURBANCES[case]
    for seed in (11, 12):
        reg = closed_loop(REGULATED, seed, overrides, wind)
        fix = closed_loop(FIXED, seed, overrides, wind)
        assert abs(fix.arrival) >= 2.0, (case, seed, fix.arrival)
        assert abs(reg.arrival) <= ARRIVAL_TOL, (case, seed, reg.arrival)
        assert abs(fix.arrival) - abs(reg.arrival) >= 1.5, (case, seed, reg.arrival, fix.arrival)
        for run in (reg, fix):
            assert abs(run.stop) <= STOP_TOL and run.margin > 0.0, (case, seed, run.stop)
            assert _interventions(run) == 0


@pytest.mark.slow
def test_a0_off_by_half_and_speed_noise():
    """A0 off by +-50 % moves the arrival by less than 1 s on this span (A0 = 0.45 N/kN of
    ~3 N/kN of resistance at speed): regulator and fixed plan both within +-2.5 s and +-0.3 m.
    Speed-sensor noise of 2 % of 80 km/h as 2 sigma (0.222 m/s): the filter's position at the
    stop lags the car by 0.14 m on average with sd 0.15 m (30 seeds; it claims 0.14 m, so a
    single stop is within +-0.3 m in ~80 % of runs). filter.position_std (~0.14 m) is above
    settle_std (0.1 m), so the controller stops short (6 x filter.position_std: 0.73 and 0.88 m
    short, true, for these seeds), stands 5 s while the filter's distance catches up with the
    car, and creeps on: the final stop within +-0.3 m, the first one at least 0.3 m short (never
    past the mark); the first standstill within +-2.5 s (the final one comes ~9 s later: the
    price of the settle, docs/ato.md); no intervention; the true speed stays under V_lim."""
    for a0 in (1.5 * CAR.A0, 0.5 * CAR.A0):
        for tuning in (REGULATED, FIXED):
            run = closed_loop(tuning, 21, {"car.A0": a0})
            assert abs(run.arrival) <= ARRIVAL_TOL and abs(run.stop) <= STOP_TOL, (a0, run)
            assert run.margin > 0.0
    for seed in (21, 22):   # the paper's estimator (est.method 0), whose filter settles here
        run = closed_loop(REGULATED, seed, {"sensor.speed_std": 0.01 * V80, **FORMER_DEFAULTS})
        assert abs(run.arrival) <= ARRIVAL_TOL, (seed, run.arrival)
        assert run.first_stop <= -0.3, (seed, run.first_stop)
        assert AtoMode.SETTLE in run.modes and AtoMode.CREEP in run.modes
        assert abs(run.stop) <= STOP_TOL and run.margin > 0.0, (seed, run.stop)
        assert _interventions(run) == 0 and run.ctrl.finished


@pytest.mark.slow
def test_the_worst_stress_seed_no_longer_passes_one_metre():
    """Speed noise 0.444 m/s (2 % of 80 km/h as 1 sigma, the study's stress case), seed 11: the
    identified mass is 27.1 t (30 t true) and the filter's position lags the car by 1.0 m at the
    EP stage while claiming 0.18 m. Before the aim applied to the whole final braking curve and
    the short stop, this run stopped 1.43 m past the mark; now it aims 1.1 m short (6 x
    filter.position_std) and ends within +1 m (measured +0.25 m: the first stop, past the mark
    because the lag exceeds the aim, cannot be undone; the stand and creep do nothing)."""
    run = closed_loop(REGULATED, 11, {"sensor.speed_std": 0.02 * V80})
    assert run.stop < 1.0 and run.ctrl.finished, run.stop
    assert AtoMode.SETTLE in run.modes


@pytest.mark.slow
def test_nan_estimates_in_the_loop_brake_and_the_run_recovers():
    """filter.speed is NaN for 1 s at t = 50 s (a dropped estimator output): those 10 steps
    and the 1 s of sane inputs the latch waits for (models.ato.supervision.RECOVERY_TIME) are
    safe-brake commands (full brake), one event names filter.speed, nothing raises; the
    regulator then makes up the lost time: arrival within +-2.5 s, stop within +-0.3 m."""
    def corrupt(t, out):
        if 50.0 <= t < 51.0 - 1e-9:
            out["filter.speed"] = math.nan
    run = closed_loop(REGULATED, 31, corrupt=corrupt)
    k0 = int(round(50.0 / STEP))
    assert run.modes[k0:k0 + 20] == [AtoMode.SAFE] * 20
    assert run.brakes[k0:k0 + 20] == [CAR.brake_force_max] * 20
    assert run.modes[k0 + 20] != AtoMode.SAFE
    assert [e for _, e in run.ctrl.events if "filter.speed" in e] == \
        ["filter.speed = nan is not finite: safe brake"]
    assert [t for t, e in run.ctrl.events if "released" in e] == [pytest.approx(52.0)]
    assert abs(run.arrival) <= ARRIVAL_TOL and abs(run.stop) <= STOP_TOL, run


@pytest.mark.slow
def test_the_speed_limit_check_can_fail_without_the_margins():
    """Negative control for the margin assertions: with no planning margin, no uncertainty term
    and no gap to the supervisor, the car holds V_lim on the filter's estimate and the true
    speed goes over it (by the filter's error), which the margin > 0 checks above would catch."""
    bare = AtoTuning(limit_margin=0.0, k_sigma=0.0, supervisor_gap=0.0, gap_sigma=0.0)
    run = closed_loop(bare, 1)
    assert run.margin < 0.0


def test_estimates_wait_for_min_samples_since_departure():
    """est.samples runs on over station stops while the mass identification restarts: a
    controller departing with est.samples = 5000 (a later span of a line) plans with the
    configured car until 100 more samples (tuning.min_samples) have come, then est.* get weight
    (blend_estimates: growing to full over min_samples more, the gate factor at most
    GATE_RATE per second)."""
    ctrl = AtoController(SPAN, CAR, REGULATED)
    out = _at_rest()
    out.update({"est.status": 1, "est.samples": 5000, "est.mass": 33.0, "est.A0": 0.9,
                "est.A1": 0.03, "est.A2": 0.0105})
    ctrl.demands(0.0, out)
    assert not ctrl._using_estimates                     # 0 samples since departure
    # the car moves (a car that stands for 9.9 s of traction: inputs not connected)
    out.update({"est.samples": 5099, "filter.speed": 5.0, "filter.position": 0.5 * 5.0 * 9.9,
                "filter.speed_std": 0.05, "filter.position_std": 0.1})
    ctrl.demands(9.9, out)
    assert not ctrl._using_estimates                     # 99 < 100
    out.update({"est.samples": 5100, "filter.position": out["filter.position"] + 0.5})
    ctrl.demands(10.0, out)
    assert not ctrl._using_estimates                     # the ramp starts at 100: weight 0
    out.update({"est.samples": 5200, "filter.position": out["filter.position"] + 25.0,
                "est.mass_std": 0.3, "est.A0_std": 0.2, "est.A1_std": 0.005, "est.A2_std": 5e-4})
    ctrl.demands(15.0, out)
    assert ctrl._using_estimates
    assert ctrl.weights[0] == pytest.approx(9.0 / (9.0 + 0.09), rel=1e-12)   # the mass's weight
    # the blend (30 + 3 x that weight) is lighter than est.mass: the plan takes the heavier car
    # (motion.heavier_mass), the braking curves it rounded up to BRAKE_MASS_STEP
    assert ctrl.plan_car.mass == ctrl.plan_car.brake_mass == 33.0


@pytest.mark.slow
@pytest.mark.parametrize("rel", [0.01, 0.02])
def test_relative_speed_noise_stops_once_on_time_and_on_the_mark(rel):
    """Meleshin's 2 % read as it is written, relative to the speed (sensor.speed_std_rel, 2 % as
    2 sigma and as 1 sigma, over a 0.01 m/s floor): at the EP stage the filter's distance is
    certain again (filter.position_std ~0.09 / 0.12 m, below settle_std = 0.13 m), so the
    controller cancels the short stop it chose at speed and stops once, aiming from the low
    speed's filter.speed_std: the one standstill within +-2.5 s and +-0.3 m, never over V_lim."""
    for seed in (21, 22):
        run = closed_loop(REGULATED, seed, {"sensor.speed_std": 0.01, "sensor.speed_std_rel": rel})
        # one stop: no stand, the one standstill the final one; a step or two of creep traction
        # inside the EP stage (every stage off and the car below V_p) is not a second stop
        assert AtoMode.SETTLE not in run.modes and run.modes.count(AtoMode.CREEP) <= 2, seed
        assert run.first_stop == run.stop and run.ctrl.finished, seed
        assert abs(run.arrival) <= ARRIVAL_TOL and abs(run.stop) <= STOP_TOL, (seed, run)
        assert run.margin > 0.0, seed
