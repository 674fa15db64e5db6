"""Meleshin's (2011) maximum-principle synthesis of the energy-efficient run (ch. 3): the modes of
Meleshin's Table 2 selected by the auxiliary function p(s), the iteration on the holding speed V_c.

Units and the derivation (co-state equation, lambda(V_c), V_r) in models/planning/trajectory.py.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from models.planning.span import CarTraction, Span
from models.planning.engine import (
    K_COAST, K_TRACTION, Course, Mode, Plan, Stall, _check_schedule, _flat_out, _plan_from,
    _root_within, _Trace, free_step, run, step,
)


def lagrange_of_hold(car: CarTraction, v_c: float) -> float:
    """lambda [W] for holding speed V_c [m/s]: V_c^2 W'(V_c) / eta_f (module docstring)."""
    return v_c * v_c * car.weight_kn * (car.A1 + 2.0 * car.A2 * v_c) / car.eta_f


class _MaxPrinciple:
    """Meleshin's (2011) synthesis for one holding speed V_c (ch. 3, the algorithm's second part):

    1. cruise: TG up to V_c, C at V_c; where holding needs no traction (a descent) VB lets the
       speed rise to V_r, held there by SR; everything capped by U (limits by C/SR/ST, braking
       curves by RK/TM); where traction cannot hold V_c (a climb) TG;
    2. before every braking curve the cruise runs into (to a lower limit or to the stop mark)
       a coast VB that starts where p = 1 and is placed so p falls to eta eta_f exactly where
       the coast meets the braking curve (the VB -> RK switch of Table 2), p integrated with
       the co-state equation of the module docstring; if even the longest coast keeps
       p > eta eta_f at a limit drop, the coast that just reaches the lower limit.

    Meleshin builds the trajectory "by sections whose borders are the speed-limit changes and
    hard grade elements", integrating the motion and p(s) with known boundary values of V and
    p (autoreferat ch. 3, Fig. 2); our sections are the braking curves of U. What we leave
    out: the jump of p where a state constraint (V = V_lim) starts or ends, and coasting or
    powering ahead of a hard grade element (the cruise reacts to the grade where it is).
    studies/ato_energy.py measures what that costs against a brute-force optimum.
    """

    def __init__(self, course: Course, v_c: float):
        self.course, self.car = course, course.car
        self.v_c = v_c
        self.lam = lagrange_of_hold(self.car, v_c)
        self.v_r = self.car.hold_speed_regen(v_c)
        self.qc = v_c * v_c
        self.qr = self.v_r * self.v_r
        self.p_switch = self.car.eta * self.car.eta_f

    def cruise(self, a, q0):
        if q0 < self.qc * (1.0 - 1e-12):
            return K_TRACTION, 1.0, -math.inf, self.qc
        return K_COAST, 0.0, self.qc, self.qr

    def _braking_start(self, tr: _Trace, after: float):
        """First segment k (node s_k >= after) where the trace follows a falling braking curve of
        U (a capped, decelerating RK/TM step); with where that falling stretch of U starts and
        ends (the lower limit's distance, or the stop mark)."""
        c = self.course
        for k in range(len(tr.mode)):
            if tr.s[k] < after - 1e-9:
                continue
            if tr.mode[k] in (Mode.RK, Mode.TM) and tr.q[k + 1] < tr.q[k]:
                j = int(np.searchsorted(c.s, tr.s[k], side="left"))
                j0 = j
                while j0 > 0 and c.qU[j0 - 1] > c.qU[j0] * (1 + 1e-12):
                    j0 -= 1
                while j < c.n - 1 and c.qU[j + 1] < c.qU[j] * (1 - 1e-12):
                    j += 1
                return k, float(c.s[j0]), float(c.s[j])
        return None

    def coast(self, tr: _Trace, s1: float, curve: tuple, keep: bool = False):
        """Coast with p = 1 from s1 (on trace ``tr``) until it meets the braking curve
        ``curve`` = (start, end) of U, or reaches its end below it.

        Returns (residual = p - eta eta_f where the free coast crosses U, met, trace or None).
        The crossing inside a step is located by linear interpolation of q - U^2. Where the
        coast runs into U before that curve (another limit's braking curve, a limit on a
        descent) it follows U (RK/SR/ST) and coasts on, p integrated on with the coasting
        co-state equation (the state constraint's jump in p is not modelled: ours).
        """
        curve_start, s_target = curve
        c, car = self.course, self.car
        k = int(np.searchsorted(np.asarray(tr.s), s1, side="right")) - 1
        k = min(k, len(tr.s) - 1)
        a, q0, t0 = tr.s[k], tr.q[k], tr.t[k]
        out = None
        if keep:
            out = _Trace()
            out.start(a, q0, t0)
        i = c.step_index(a)
        if s1 > a:      # the cruise up to s1 (part of a step)
            kind, u, qf, qx = self.cruise(a, q0)
            q1, dt, wF, wR, wM, mode, _, _ = step(car, q0, a, s1, c.grades(a, s1, i), kind, u, qf,
                                                  min(qx, c.envelope_at(s1)),
                                                  ceil_a=min(qx, c.envelope_at(a)))
            if keep:
                out.add(s1, q1, dt, wF, wR, wM, mode)
            a, q0 = s1, q1
        p = 1.0
        if q0 <= 0.0:
            raise Stall(f"coasting from rest at s = {a:.1f} m")
        while a < s_target - 1e-9:
            if c.s[i + 1] <= a:
                i += 1
            b = c.s[i + 1]
            qU_b = c.qU[i + 1]
            q1, dt, wF, wR, wM, mode, p1, capped = step(car, q0, a, b, c.grades(a, b, i), K_COAST,
                                                        0.0, -math.inf, qU_b, p, self.lam,
                                                        ceil_a=c.envelope_at(a))
            if q1 <= 0.0 and b < c.span.stop - 1e-9:
                raise Stall(f"the car stops at s ~ {b:.1f} m coasting")
            if keep:
                out.add(b, q1, dt, wF, wR, wM, mode)
            if capped and b > curve_start + 1e-9:
                qf = free_step(car, q0, a, b, *c.grades(a, b, i), K_COAST, 0.0)[0]
                g0 = q0 - c.envelope_at(a)
                g1 = qf - qU_b
                w = 0.0 if g1 == g0 else min(max(g0 / (g0 - g1), 0.0), 1.0)
                return p + w * (p1 - p) - self.p_switch, True, out
            a, q0, p = b, q1, p1
        return p - self.p_switch, False, out

    def _node_residual(self, tr: _Trace, k: int, curve: tuple, final: bool) -> float:
        """Residual of the coast from trace node k; -inf if it stalls or (at a limit drop)
        arrives below the lower limit without meeting the braking curve."""
        try:
            res, met, _ = self.coast(tr, tr.s[k], curve)
        except Stall:
            return -math.inf
        return res if met or final else -math.inf

    def _coast_point(self, tr: _Trace, k_lo: int, k_b: int, curve: tuple, final: bool,
                     hint: int | None) -> float:
        """The coast point: the residual is > 0 at k_b (no coast, p = 1) and falls as the coast
        starts earlier (p has longer to fall). Bracket a sign change between two adjacent trace
        nodes below k_b (from the hint, the previous V_c's node, by secant or doubling steps;
        then false position), and place the coast point by linear interpolation of the
        residual between them."""
        res = {k_b: 1.0 - self.p_switch}

        def r(k):
            if k not in res:
                res[k] = self._node_residual(tr, k, curve, final)
            return res[k]

        k = k_b if hint is None else min(max(hint, k_lo), k_b)
        d = 1
        prev = None
        if r(k) > 0.0:
            hi = k
            while True:
                if k <= k_lo:
                    return float(tr.s[k_lo])     # p stays above eta eta_f: coast from the start
                jump = d
                if prev is not None and r(prev) > r(k):
                    # the secant through the last two residuals, 1.5x past its root
                    jump = max(1, min(d, int(math.ceil(1.5 * r(k) * (prev - k) / (r(prev) - r(k))))))
                prev, k = k, max(k_lo, k - jump)
                d *= 2
                if r(k) <= 0.0:
                    lo = k
                    break
                hi = k
        else:
            lo = k
            while True:
                k = min(k_b, k + d)
                d *= 2
                if r(k) > 0.0:
                    hi = k
                    break
                lo = k
        moved = []                       # false position; bisect after one end moved twice
        while hi - lo > 1:
            r_lo, r_hi = r(lo), r(hi)
            if math.isfinite(r_lo) and moved[-2:] not in (["lo", "lo"], ["hi", "hi"]):
                mid = min(max(lo + int(round((hi - lo) * r_lo / (r_lo - r_hi))), lo + 1), hi - 1)
            else:
                mid = (lo + hi) // 2
            if r(mid) > 0.0:
                hi = mid
                moved.append("hi")
            else:
                lo = mid
                moved.append("lo")
        self.coast_nodes.append(lo)
        r0, r1 = r(lo), r(hi)
        if not math.isfinite(r0):
            return float(tr.s[hi])
        return float(tr.s[lo] + (tr.s[hi] - tr.s[lo]) * r0 / (r0 - r1))

    def build(self, hints: list | None = None, skip: frozenset = frozenset()) -> _Trace:
        """The trajectory for this V_c. ``hints``: the trace nodes of the coast points found for
        a nearby V_c (the brackets start there); this run's are in ``self.coast_nodes``.
        ``skip``: limit drops [m] that get no coast of their own: the next coast may then start
        before them and run through their zone (one long coast instead of two)."""
        c = self.course
        cruise = self.cruise
        tr = run(c, 0.0, 0.0, 0.0, cruise)
        after = search = 0.0
        self.coast_nodes = []
        self.residual_at_switch = []
        for _ in range(len(c.span.limit_distances) + 1):
            found = self._braking_start(tr, search)
            if found is None:
                break
            k_b, curve_start, curve_end = found
            final = curve_end >= c.span.stop - 1e-9
            if not final and any(abs(curve_end - x) < 1e-6 for x in skip):
                search = curve_end
                continue
            event = len(self.coast_nodes)
            k_lo = int(np.searchsorted(np.asarray(tr.s), after, side="left"))
            hint = hints[event] if hints and event < len(hints) else None
            s1 = self._coast_point(tr, k_lo, k_b, (curve_start, curve_end), final, hint)
            try:
                r, _, head = self.coast(tr, s1, (curve_start, curve_end), keep=True)
            except Stall:
                break
            self.residual_at_switch.append(r)
            new = tr.cut(head.s[0])
            new.extend(head)
            new.extend(run(c, new.s[-1], new.q[-1], new.t[-1], cruise))
            tr = new
            after = search = curve_end
            if final:
                break
        return tr


def synthesize(span: Span, car: CarTraction, *, step: float = 5.0, tol: float = 0.01,
               course: Course | None = None) -> Plan:
    """Meleshin's (2011) energy-efficient plan for span.schedule: the holding speed V_c is iterated
    (brentq on the running time; Meleshin, ch. 3: "the iteration ends when the residual of the
    running time is below a given value") until |T - schedule| <= ``tol`` [s].

    Where the speed limit drops, one long coast through the lower-limit zone can beat a coast
    into it plus a second traction application after it (or the reverse): the iteration is run
    for every choice of drops without a coast of their own (at most 3 drops are combined) and
    the plan with the least energy is returned.

    tol = 0.01 s is 1/250 of the +-2.5 s running-time accuracy of Meleshin (2011) and Sidorenko
    (1997). Raises ValueError naming both times if the schedule is shorter than the minimum-time
    run, or naming the schedule if it is too long to be met (a holding speed below 0.05 m/s).
    """
    course = course or Course(span, car, step)
    t_min = run(course, 0.0, 0.0, 0.0, _flat_out).t[-1]
    _check_schedule(span, t_min, tol)
    lims = span.limit_speeds
    drops = [d for k, d in enumerate(span.limit_distances) if k > 0 and lims[k] < lims[k - 1]]
    best, failures = None, []
    for n_skip in range(min(len(drops), 3) + 1):
        for skip in itertools.combinations(drops, n_skip):
            try:
                plan = _iterate_hold_speed(course, span, tol, t_min, frozenset(skip))
            except ValueError as e:
                failures.append(str(e))
                continue
            if best is None or plan.energy_kwh < best.energy_kwh:
                best = plan
    if best is None:
        raise ValueError("; ".join(dict.fromkeys(failures)))
    return best


def _iterate_hold_speed(course: Course, span: Span, tol: float, t_min: float, skip) -> Plan:
    """brentq on V_c for one coast structure (``skip``, see _MaxPrinciple.build)."""
    car = course.car
    cache = {}
    hints = [None]

    def trace(v_c):
        if v_c not in cache:
            mp = _MaxPrinciple(course, v_c)
            cache[v_c] = (mp.build(hints[0], skip), mp)
            hints[0] = mp.coast_nodes
        return cache[v_c][0]

    def excess(v_c):
        return trace(v_c).t[-1] - span.schedule

    v_top = math.sqrt(float(np.max(course.qU)))
    hi = v_top
    while excess(hi) > 0.0 and hi < 1e3:
        hi *= 2.0
    if excess(hi) > tol:
        raise ValueError(f"no holding speed meets span.schedule = {span.schedule:.2f} s: the "
                         f"fastest plan takes {trace(hi).t[-1]:.2f} s (minimum-time run {t_min:.2f} s)")
    lo = min(hi, 0.5 * v_top)
    while excess(lo) < 0.0:
        lo *= 0.5
        if lo < 0.05:
            raise ValueError(f"span.schedule = {span.schedule:.2f} s is too long: holding "
                             f"{lo:.3f} m/s is still faster")
    v_c = _root_within(excess, lo, hi, tol)
    if abs(excess(v_c)) > tol:
        raise ValueError(f"the maximum-principle iteration did not meet span.schedule = "
                         f"{span.schedule:.2f} s within {tol} s: the running time jumps at "
                         f"V_c = {v_c:.4f} m/s (to {trace(v_c).t[-1]:.3f} s)")
    tr, mp = cache[v_c]
    return _plan_from(tr, car, "maximum principle", hold_speed=v_c, lagrange=mp.lam)
