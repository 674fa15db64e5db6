"""Energy-efficient running over a span (issue 20, the pure part): the motion per distance,
Meleshin's (2011) maximum-principle synthesis, the minimum-time run and the manual driver's
reference, Sidorenko's (1997) DP and a brute-force optimum. The public API is here: simulate,
min_time_run, manual_driver, synthesize (models/planning/max_principle.py), dp_plan and brute_force
(models/planning/dp.py); all return a Plan. The shared stepping is models/planning/engine.py.

Units: distance s [m], speed V [m/s], time t [s], force [N], energy [J] inside, [kWh] in Plan.

Motion per distance (Sidorenko, ch. 2: dV/ds = zeta (u_f f(V) - w0(V) - w_i(s) - u_b b(V)) / V).
We integrate q = V^2 instead of V: dq/ds = 2 dV/dt = 2 a(V, s), with a from
models.plant.dynamics.acceleration (eq. (2) with the rotating-mass factor), which is regular at V = 0
(a start from rest needs no special case). RK4 in s on a grid that contains every grade and
limit change; the time over a step is dt = 2 h / (V0 + V1), exact for constant acceleration
(and finite from rest). Energy (MODEL.md section 9, Meleshin's eq. (8)):

    A_e = (integral of F ds) / eta_f - eta (integral of R_regen ds)     [J -> kWh / 3.6e6]

the integrals by Simpson's rule on the RK4 stages (exact for a constant force).

Controls and mode codes (Meleshin, ch. 3, Table 2; p the auxiliary function of eq. (10) there):
TG full traction, C speed holding by traction, VB coasting, SR holding by regenerative brake,
RK full regenerative braking, ST holding by regen + mechanical brake, TM full braking. Two
readings of ours: (1) below regen_fade_speed the braking curve's electro-pneumatic share makes
up the faded regen (CarTraction.service_brake); a step with that mechanical share is coded TM.
(2) With the cost above, minimising the Hamiltonian over u_f, u_r, u_b with
p = -psi eta_f / (m V) (psi the co-state of V, m the inertial mass) gives exactly Table 2 with
the table's eta read as eta * eta_f (traction energy is counted at the network, regenerated
energy at the wheel times eta): TG p > 1, C p = 1, VB eta eta_f < p < 1, SR p = eta eta_f,
RK 0 < p < eta eta_f, ST p = 0, TM p < 0. The co-state equation in p is

    dp/ds = [u_f f'(1 - p) + u_r r'(p - eta eta_f) + p u_b b' + p W' - eta_f lambda / V^2] / (m V)

(W = resistance force, ' = d/dV, lambda the multiplier of the running time [W]). On a traction
holding arc p = 1, dp/ds = 0 gives lambda = V_c^2 W'(V_c) / eta_f: V_c and lambda are one to one
(Meleshin: "V_c or the lambda uniquely tied to it"), and regen holding (p = eta eta_f) is at
V_r with V_r^2 W'(V_r) = eta_f lambda / (eta eta_f) (CarTraction.hold_speed_regen).

Speed limits: every run is capped by the envelope U(s), the lower of V_lim(s) and the braking
curves (service brake) to every lower limit ahead and to the stop mark, integrated backward
from them. A step whose free motion would end above U (or below a holding floor) is replaced by
the step that ends on it with the cheapest force in Table 2's order (traction, regen, then the
mechanical brake); its mode code follows from the forces. So no plan exceeds V_lim at a node.
"""
from __future__ import annotations

import math

import numpy as np

from models.planning.span import CarTraction, Span
from models.planning.dp import brute_force, dp_plan  # noqa: F401  (the public API)
from models.planning.engine import (  # noqa: F401  (the public API)
    J_PER_KWH, Course, Mode, Plan, Stall, _bracket_low, _check_commands, _check_schedule, _coast,
    _flat_out, _plan_from, _root_within, _run_commands, run,
)
from models.planning.max_principle import lagrange_of_hold, synthesize  # noqa: F401  (the public API)


# ===================================================================== (1) the simulator

def simulate(span: Span, car: CarTraction, commands, *, step: float = 5.0,
             course: Course | None = None) -> Plan:
    """Run ``commands`` over the span from rest at s = 0: a sequence of (s_switch [m], Mode,
    value) sorted by s_switch, the first at 0. Value: for TG the traction share u_f in (0, 1];
    for RK the regen share u_r; for C/SR/ST (speed holding) the speed to hold [m/s] or None
    for the speed at the switch; ignored for VB/TM (TM = the service brake). Every command is
    capped by the envelope U(s), so after the last command the car follows the braking curve
    to the stop mark. Raises Stall if the car stops before it."""
    course = course or Course(span, car, step)
    cmds = _check_commands(commands, span)
    return _plan_from(_run_commands(course, cmds), car, "simulated", commands=tuple(cmds))


def min_time_run(span: Span, car: CarTraction, *, step: float = 5.0,
                 course: Course | None = None) -> Plan:
    """The minimum-time run: full traction, held at the speed limits, then the braking curve
    to the stop mark. Raises ValueError naming the place if the car cannot climb the span."""
    course = course or Course(span, car, step)
    return _plan_from(run(course, 0.0, 0.0, 0.0, _flat_out), car, "minimum time")


def manual_driver(span: Span, car: CarTraction, *, step: float = 5.0, tol: float = 0.01,
                  course: Course | None = None) -> Plan:
    """What a driver does to meet the schedule: the minimum-time run up to a coast point, then
    coasting (still capped by the limits and the braking curves), then the braking curve to the
    stop mark; the coast point is chosen (brentq) so the running time is span.schedule within
    ``tol`` [s]. Raises ValueError if the schedule is shorter than the minimum-time run or so
    long that coasting from the start would stall."""
    course = course or Course(span, car, step)
    fast = run(course, 0.0, 0.0, 0.0, _flat_out)
    t_min = fast.t[-1]
    _check_schedule(span, t_min, tol)

    def trace_at(sc):
        i = int(np.searchsorted(np.asarray(fast.s), sc, side="right")) - 1
        head = fast.cut(fast.s[i])
        if sc > fast.s[i]:
            head.extend(run(course, fast.s[i], fast.q[i], fast.t[i], _flat_out, s_end=sc))
        head.extend(run(course, head.s[-1], head.q[-1], head.t[-1], _coast))
        return head

    def excess(sc):
        try:
            return trace_at(sc).t[-1] - span.schedule
        except Stall:
            return math.inf

    if span.schedule - t_min <= tol:
        return _plan_from(fast, car, "manual driver")
    lo = _bracket_low(excess, span.stop, course.h)
    if lo is None:
        raise ValueError(f"span.schedule = {span.schedule} s is too long for one coast: the "
                         f"manual driver cannot meet it")
    sc = _root_within(excess, lo, span.stop, tol)
    return _plan_from(trace_at(sc), car, "manual driver",
                      commands=((0.0, Mode.TG, 1.0), (sc, Mode.VB, None)))
