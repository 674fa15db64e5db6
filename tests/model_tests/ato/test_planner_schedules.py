"""The ATO planner honours every schedule it accepts (issue 29): the departure plan of
models.ato.controller.AtoController arrives within 0.1 s of the schedule for every schedule from
the fastest run it reports (ReducedPlanner.min_time) to 30 % above it, on a seeded family of
generated spans with low limit zones at both ends, and on the issue's own span."""
from __future__ import annotations

import math
import random

import pytest

from models.ato.controller import AtoController
from models.ato.planner import fastest_run as fastest_run_of
from models.planning.span import CarTraction, Span
from models.plant.track import GradeProfile
from models.units import kmh_to_mps

CAR = CarTraction()
ARRIVAL_TOL = 0.1              # [s] the issue's bound (the planner's own tolerance is 0.05 s)
SCHEDULE_FACTORS = (1.0, 1.01, 1.05, 1.1, 1.2, 1.3)   # x the fastest run
N_SPANS = 200


def generated_span(rng: random.Random) -> Span:
    """A span of 0.7-2.5 km, 1-6 grade elements of -35..+40 permille, 1-4 limit changes: the
    first and the last zone 30-45 km/h (a low zone at the start and at the stop), those between
    30-80 km/h, zones at least 40 m long. The schedule is a placeholder (the test sets it)."""
    length = rng.uniform(700.0, 2500.0)
    n_grades = rng.randint(1, 6)
    cuts = sorted(rng.uniform(0.0, length) for _ in range(n_grades - 1))
    grade = GradeProfile(tuple([0.0] + cuts),
                         tuple(round(rng.uniform(-35.0, 40.0), 1) for _ in range(n_grades)))
    changes = rng.randint(1, 4)
    while True:
        starts = sorted(rng.uniform(60.0, length - 60.0) for _ in range(changes))
        if all(b - a >= 40.0 for a, b in zip([0.0] + starts, starts)):
            break
    kmh = ([rng.uniform(30.0, 45.0)] + [rng.uniform(30.0, 80.0) for _ in range(changes - 1)]
           + [rng.uniform(30.0, 45.0)])
    return Span(length, length, grade=grade, limit_distances=tuple([0.0] + starts),
                limit_speeds=tuple(kmh_to_mps(round(v)) for v in kmh))


def fastest_run(span: Span) -> float:
    """The fastest run [s] as the controller computes it at construction, without needing a
    feasible schedule (models.ato.planner.fastest_run)."""
    return fastest_run_of(span, CAR)


@pytest.mark.slow          # ~30 s: 1200 controllers built and planned
def test_every_schedule_from_the_fastest_to_30_percent_above_is_planned_for():
    """200 generated spans x 6 schedules (the fastest run, +1, +5, +10, +20, +30 %): every
    controller accepts its schedule and its departure plan arrives within 0.1 s of it with
    status "ok". Before the fix 282 of these 1200 plans missed (91 of them at the fastest run,
    the worst by 52 s). The fallback policy is counted, not bounded: what it is used for is
    reported (measured 13 % of the plans), but both policies must meet the schedule."""
    rng = random.Random(29)
    misses, policies = [], {"energy": 0, "capped": 0}
    for k in range(N_SPANS):
        span = generated_span(rng)
        t_min = fastest_run(span)
        for factor in SCHEDULE_FACTORS:
            schedule = t_min * factor
            plan = AtoController(span.with_schedule(schedule), CAR).initial_plan
            policies[plan.policy] += 1
            if plan.status != "ok" or abs(plan.arrival - schedule) > ARRIVAL_TOL:
                misses.append((k, factor, round(schedule, 2), round(plan.arrival, 2), plan.status))
    assert misses == []
    assert sum(policies.values()) == N_SPANS * len(SCHEDULE_FACTORS)
    assert policies["energy"] > policies["capped"]     # the fallback stays the exception


# the issue's span: 1.1 km, level, 40 -> 75 -> 60 -> 35 km/h (fastest run 92.9 s); before the fix
# the departure plan arrived 95.32 s after departure for all four schedules
ISSUE_SPAN = Span(1100.0, 100.0, limit_distances=(0.0, 200.0, 500.0, 900.0),
                  limit_speeds=tuple(kmh_to_mps(v) for v in (40.0, 75.0, 60.0, 35.0)))


@pytest.mark.parametrize("schedule", [96.0, 99.5, 101.0, 104.0])
def test_the_issues_span_follows_each_schedule(schedule):
    """The issue's schedules of 96, 99.5, 101 and 104 s on its 40/75/60/35 km/h span: four
    departure plans, each within 0.1 s of its schedule."""
    plan = AtoController(ISSUE_SPAN.with_schedule(schedule), CAR).initial_plan
    assert plan.status == "ok"
    assert abs(plan.arrival - schedule) <= ARRIVAL_TOL


def test_the_fastest_run_reported_is_the_run_planned_for_it():
    """A schedule equal to the fastest run the controller reports plans to that run (within
    0.1 s), one 0.1 s shorter is refused, and the controller reports the planner's min_time."""
    t_min = fastest_run(ISSUE_SPAN)
    plan = AtoController(ISSUE_SPAN.with_schedule(t_min), CAR).initial_plan
    assert plan.status == "ok"
    assert abs(plan.arrival - t_min) <= ARRIVAL_TOL
    ctrl = AtoController(ISSUE_SPAN.with_schedule(1.2 * t_min), CAR)
    with pytest.raises(ValueError, match="is infeasible"):
        AtoController(ISSUE_SPAN.with_schedule(t_min - 0.1), CAR)
    assert ctrl.planner.min_time(ctrl.configured) == t_min


def test_the_capped_policys_arrival_falls_continuously_with_its_cap():
    """The fallback's premise: on the issue's span the capped policy's arrival never rises as
    its V_c (the cap on traction) rises (5 cm/s steps from 2 m/s to the envelope's top), moves per step by at most
    twice what holding the cap over the whole span would (stop dV / V^2: no jump, so the
    solve's false position always converges), and a cap above the envelope gives the fastest
    run exactly."""
    ctrl = AtoController(ISSUE_SPAN, CAR)
    planner, car = ctrl.planner, ctrl.configured
    qU = planner.envelope(car)
    fall = planner._stretches(qU)
    v_top = math.sqrt(max(qU))
    caps = [2.0 + 0.05 * k for k in range(int((v_top - 2.0) / 0.05) + 1)]
    arrivals = [planner._capped_run(car, 0.0, 0.0, 0.0, v, qU, fall)[0].t[-1] for v in caps]
    steps = [b - a for a, b in zip(arrivals, arrivals[1:])]
    assert max(steps) <= 1e-9
    jumps = [(v, d) for v, d in zip(caps, steps) if -d > 2.0 * ISSUE_SPAN.stop * 0.05 / (v * v)]
    assert jumps == []
    assert arrivals[0] - arrivals[-1] > 300.0          # the family spans the schedules
    free = planner._capped_run(car, 0.0, 0.0, 0.0, 4.0 * v_top, qU, fall)[0].t[-1]
    assert free == planner.min_time(car, qU)
