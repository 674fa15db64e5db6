"""The ATO's input supervision (models/ato/supervision.py) and its use by the controller
(models/ato/controller.py): each check trips on its bad input and names it with the value, not
on the sane input next to it; the safe brake latches for RECOVERY_TIME of sane inputs; the
tuning and the re-planner's grid are bounded at construction.

Units: s [m], V [m/s], t [s], mass [t].
"""
from __future__ import annotations

import re
import tracemalloc

import pytest

from models.ato.controller import MAX_GRID_NODES, AtoController
from models.ato.interface import INPUTS, AtoMode, AtoTuning
from models.ato.supervision import (
    A0_MAX, CONSISTENCY_SLACK, MASS_FACTOR, MAX_CALL_GAP, NOISE_SIGMA, RECOVERY_TIME,
    RESPONSE_TIME, InputSupervisor,
)
from models.planning.span import CarTraction, Span

STEP = 0.1
SPAN = Span(2200.0, 135.0, stop=2150.0)
CAR = CarTraction()


def moving(k: int, **changes) -> dict:
    """Sane outputs at step k of a run at 10 m/s from 100 m, with ``changes`` (dots as __)."""
    out = {"filter.speed": 10.0, "filter.position": 100.0 + 10.0 * k * STEP,
           "filter.speed_std": 0.05, "filter.position_std": 0.1, "est.mass": 30.0,
           "est.A0": 1.0, "est.A1": 0.03, "est.A2": 0.01, "est.status": 1, "est.samples": 50 + k}
    out.update({n.replace("__", "."): v for n, v in changes.items()})
    return out


def values(out: dict) -> list[float]:
    return [float(out[n]) for n in INPUTS]


def check_at(k: int, **changes):
    """A supervisor fed steps 0..k-1 sane, then step k with ``changes``: its verdict."""
    sup = InputSupervisor(30.0)
    for j in range(k):
        assert sup.check(j * STEP, values(moving(j))) is None
    return sup.check(k * STEP, values(moving(k, **changes)))


@pytest.mark.parametrize("changes, name, words", [
    ({"filter__speed": -0.31}, "filter.speed", "filter.speed = -0.31 m/s is below -6 x"),
    ({"filter__speed": 201.0}, "filter.speed", "filter.speed = 201.0 m/s is beyond 200"),
    ({"filter__position": -0.61}, "filter.position", "filter.position = -0.61 m is below -6 x"),
    ({"filter__position": 1.1e7}, "filter.position", "filter.position = 11000000.0 m is beyond"),
    ({"filter__speed_std": -1e-9}, "filter.speed_std", "filter.speed_std = -1e-09 m/s: a standard"),
    ({"filter__speed_std": 0.0}, "filter.speed_std", "filter.speed_std = 0 m/s while filter.speed = 10.0"),
    ({"filter__position_std": 0.0}, "filter.position_std", "filter.position_std = 0 m while"),
    ({"filter__speed_std": 250.0}, "filter.speed_std", "filter.speed_std = 250.0 m/s is beyond 200"),
    ({"est__mass": 2.99}, "est.mass", "est.mass = 2.99 t is outside [3, 300] t"),
    ({"est__mass": 300.1}, "est.mass", "est.mass = 300.1 t is outside"),
    ({"est__A0": -1000.5}, "est.A0", "est.A0 = -1000.5 N/kN is beyond +-1000"),
    ({"est__A1": 101.0}, "est.A1", "est.A1 = 101.0 N/kN/(m/s) is beyond +-100"),
    ({"est__A2": 1e300}, "est.A2", "est.A2 = 1e+300"),
    ({"est__status": 4}, "est.status", "est.status = 4 is not one of"),
    ({"est__samples": -1}, "est.samples", "est.samples = -1 is outside"),
    ({"est__samples": 2**31 - 1}, "est.samples", "est.samples = 2147483647 is outside"),
])
def test_each_check_names_the_input_and_its_value(changes, name, words):
    got = check_at(5, **changes)
    assert got is not None and got[0] == name and words in got[1], got


@pytest.mark.parametrize("changes", [
    {"filter__speed": -0.29},            # within 6 x 0.05 m/s of 0: noise
    {"filter__position": -0.59},         # within 6 x 0.1 m (with the consistency slack)
    {"est__mass": 3.01}, {"est__mass": 299.0}, {"est__A0": -999.0}, {"est__status": 3},
    {"est__samples": 1e9},
])
def test_a_value_just_inside_each_bound_is_sane(changes):
    sup = InputSupervisor(30.0)
    # at rest at the station: the position may be a little negative, the speed too
    rest = dict(moving(0), **{"filter.speed": 0.0, "filter.position": 0.0})
    assert sup.check(0.0, values(rest)) is None
    out = dict(rest, **{n.replace("__", "."): v for n, v in changes.items()})
    assert sup.check(STEP, values(out)) is None


def test_zero_stds_are_accepted_only_at_rest():
    """RailCar's filter starts with zero covariance at the known standstill: accepted; the
    same with the car moving is not."""
    rest = {n: 0.0 for n in INPUTS} | {"est.mass": 30.0}
    assert InputSupervisor(30.0).check(0.0, values(rest)) is None
    got = InputSupervisor(30.0).check(0.0, values(rest | {"filter.speed": 0.5}))
    assert got[0] == "filter.speed_std"


def test_time_must_advance_by_at_most_the_gap():
    sup = InputSupervisor(30.0)
    assert sup.check(1.0, values(moving(0))) is None
    assert sup.check(1.0, values(moving(0)))[0] == "t"               # not later
    assert "does not continue" in sup.check(0.5, values(moving(0)))[1]
    got = sup.check(1.0 + MAX_CALL_GAP + 0.1, values(moving(0)))
    assert got[0] == "t" and "after the previous call" in got[1]
    assert sup.check(1.0 + MAX_CALL_GAP + 0.2, values(moving(0))) is None   # the gap ends there


def test_position_and_speed_must_agree():
    """The speed cut to 0 while the position advances at 10 m/s is found once the advance
    exceeds 6 x (the stds) + the slack, 1 m: here at t = 0.5 s, 0.2 s after the cut; a position
    frozen while the speed says 10 m/s the same; an advance within the tolerance is not."""
    sup = InputSupervisor(30.0)
    for k in range(3):
        assert sup.check(k * STEP, values(moving(k))) is None
    found = None
    for k in range(3, 40):
        got = sup.check(k * STEP, values(moving(k, filter__speed=0.0)))
        if got is not None:
            found = k * STEP
            break
    assert got[0] == "filter.speed vs filter.position" and "advanced" in got[1]
    # 10 m/s lost: tol = 6 (0.1 + 0.1 + 0.05 dt) + 1 = 2.2 m + 0.3 dt, reached after ~0.25 s
    assert found == pytest.approx(0.5, abs=0.15)
    sup = InputSupervisor(30.0)
    for k in range(3):
        assert sup.check(k * STEP, values(moving(k))) is None
    verdicts = [sup.check(k * STEP, values(moving(k, filter__position=102.0))) for k in range(3, 8)]
    assert any(v is not None and v[0] == "filter.speed vs filter.position" for v in verdicts)
    # a correction of 2 m in 2 s with the stds above is within the tolerance
    sup = InputSupervisor(30.0)
    for k in range(20):
        assert sup.check(k * STEP, values(moving(k, filter__position=100.0 + k + 0.1 * k))) is None


def test_a_disagreement_names_the_travel_it_compared():
    """The message states what the speeds accounted for in the window compared, not the
    restarted window's 0 m: the window opened at t = 0, the speed cut to 0 from 10 m/s at
    t = 0.3 s, found at t = 0.5 s: 10 x 0.2 + 0.5 x 10 x 0.1 = 2.5 m against 5 m advanced."""
    sup = InputSupervisor(30.0)
    for k in range(3):
        assert sup.check(k * STEP, values(moving(k))) is None
    got = None
    for k in range(3, 40):
        got = sup.check(k * STEP, values(moving(k, filter__speed=0.0)))
        if got is not None:
            break
    assert "advanced 5.000 m in 0.5 s" in got[1], got
    assert "accounts for 2.500 m" in got[1], got


def test_a_bad_episode_does_not_enter_the_next_window():
    """10 s of est.mass out of bounds while the car brakes from 10 m/s to a stop in 2 s and
    stands (position and speed consistent throughout): the first sane call after it starts a new
    window instead of integrating one trapezoid from the last sane speed (10 m/s) over the
    episode, which read a spurious disagreement (10 m advanced against that trapezoid's 50 m)."""
    sup = InputSupervisor(30.0)
    for k in range(3):
        assert sup.check(k * STEP, values(moving(k))) is None
    s, v = 100.0 + 10.0 * 2 * STEP, 10.0
    for k in range(3, 103):
        v_next = max(0.0, 10.0 - 5.0 * (k - 2) * STEP)
        s += 0.5 * (v + v_next) * STEP
        v = v_next
        out = moving(k, est__mass=1000.0, filter__speed=v, filter__position=s)
        assert sup.check(k * STEP, values(out))[0] == "est.mass"
    assert v == 0.0
    assert sup.check(103 * STEP, values(moving(103, filter__speed=0.0, filter__position=s))) is None


def test_inputs_that_do_not_follow_the_car_are_refused_until_they_move():
    """The FMU's inputs left unconnected are a car at rest (start values): the controller
    commands traction, the inputs stay exactly at rest: after RESPONSE_TIME (3 s) the safe
    brake, held while they do not move; a car that responds at once is never refused."""
    rest = {n: 0.0 for n in INPUTS} | {"est.mass": 30.0}
    ctrl = AtoController(SPAN, CAR)
    modes = [ctrl.demands(k * STEP, rest).mode for k in range(60)]
    k_safe = modes.index(AtoMode.SAFE)
    assert modes[:k_safe] == [AtoMode.TG] * k_safe and k_safe * STEP == pytest.approx(RESPONSE_TIME)
    assert set(modes[k_safe:]) == {AtoMode.SAFE}               # held: nothing says they are back
    assert sum("have not moved in 3 s of traction" in e for _, e in ctrl.events) == 1
    # they move (connected now): released 1 s later
    moved = [ctrl.demands(k * STEP, rest | {"filter.speed": 0.1, "filter.speed_std": 0.01,
                                            "filter.position": 0.01 * (k - 59),
                                            "filter.position_std": 0.01}).mode
             for k in range(60, 75)]
    assert moved[:10] == [AtoMode.SAFE] * 10 and AtoMode.SAFE not in moved[11:]
    ok = AtoController(SPAN, CAR)
    assert ok.demands(0.0, rest).mode == AtoMode.TG
    for k in range(1, 50):      # responds: 0.5 m/s^2 from rest
        v = 0.05 * k
        out = rest | {"filter.speed": v, "filter.position": 0.5 * 0.5 * (k * STEP) ** 2,
                      "filter.speed_std": 0.01, "filter.position_std": 0.01}
        assert ok.demands(k * STEP, out).mode != AtoMode.SAFE, ok.events


def test_the_safe_brake_latches_until_the_inputs_are_sane_for_the_recovery_time():
    ctrl = AtoController(SPAN, CAR)
    assert ctrl.demands(0.0, moving(0)).mode != AtoMode.SAFE
    cmd = ctrl.demands(STEP, moving(1, est__mass=0.0))
    assert (cmd.traction, cmd.brake, cmd.mode) == (0.0, CAR.brake_force_max, AtoMode.SAFE)
    assert "est.mass = 0.0 t" in ctrl.events[-1][1]
    modes = [ctrl.demands(k * STEP, moving(k)).mode for k in range(2, 14)]
    n_held = int(round(RECOVERY_TIME / STEP))            # 1 s of sane inputs: 10 calls held
    assert modes[:n_held] == [AtoMode.SAFE] * n_held and AtoMode.SAFE not in modes[n_held:]
    assert [t for t, e in ctrl.events if "released" in e] == [pytest.approx(1.2)]


def test_a_safe_brake_share_of_zero_and_other_bad_tuning_are_refused():
    for kw, words in (({"safe_brake": 0.0}, "tuning.safe_brake must be > 0"),
                      ({"hold_brake": 0.0}, "tuning.hold_brake must be > 0"),
                      ({"creep_accel": 0.0}, "tuning.creep_accel must be > 0"),
                      ({"ep_stages": 33}, "tuning.ep_stages must be in [1, 32]"),
                      ({"ep_stages": 2**31 - 1}, "tuning.ep_stages must be in [1, 32]"),
                      ({"mass_band": 5.5}, "tuning.mass_band must be in [1, 5]")):
        with pytest.raises(ValueError) as e:
            AtoTuning(**kw)
        assert words in str(e.value)
    AtoTuning(ep_stages=32, mass_band=5.0, safe_brake=0.01)       # the bounds themselves pass


def test_the_replanning_grid_is_capped_and_refused_before_it_is_built():
    """ato.grid_step = 1e-3 m used to take 125 s and 1 GB to initialise: refused before any grid
    is allocated (its peak Python memory, not a wall time, which a busy host stretches), naming
    the step, the nodes and the smallest step allowed; a grid at the cap builds."""
    tracemalloc.start()
    try:
        with pytest.raises(ValueError) as e:
            AtoController(SPAN, CAR, AtoTuning(grid_step=1e-3))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 1e6        # [B] measured: the refusal ~3 kB; a grid at the 10,000-node cap ~9 MB
    assert "tuning.grid_step = 0.001 m puts 2.15e+06 nodes" in str(e.value)
    assert f"at most {MAX_GRID_NODES}" in str(e.value) and ">= 0.215 m" in str(e.value)
    AtoController(SPAN, CAR, AtoTuning(grid_step=0.22))


def test_a_schedule_beyond_the_slowest_run_is_refused():
    for schedule, shown in ((1e20, "1e+20"), (1e300, "1e+300"), (1e6, "1000000.00")):
        with pytest.raises(ValueError, match=rf"span.schedule = {re.escape(shown)} s is too long"):
            AtoController(SPAN.with_schedule(schedule), CAR)


def test_bounds_are_the_documented_ones():
    """docs/ato.md quotes these numbers: a change here must change the doc."""
    assert (NOISE_SIGMA, RECOVERY_TIME, MAX_CALL_GAP, MASS_FACTOR, A0_MAX, MAX_GRID_NODES,
            CONSISTENCY_SLACK) == (6.0, 1.0, 10.0, 10.0, 1000.0, 10_000, 1.0)



def test_a_climb_beyond_the_traction_is_refused_naming_where():
    """A 150 permille climb from 500 m: the fastest run stalls, and the controller's construction
    says so with the place (it raised a bare _Stall, '1150.0')."""
    from models.plant.track import GradeProfile
    span = Span(2200.0, 300.0, stop=2150.0, grade=GradeProfile((0.0, 500.0, 1400.0), (0.0, 150.0, 0.0)))
    with pytest.raises(ValueError, match=r"^the span cannot be run: at full traction from rest the "
                                         r"30\.0 t car comes to rest at s = 1150\.0 m, before "
                                         r"span\.stop = 2150\.0 m"):
        AtoController(span, CAR)
