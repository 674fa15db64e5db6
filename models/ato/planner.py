# Over 600 lines as one unit: the re-planner's two policies and their solves, for a C port to mirror.
"""The ATO's fast re-planner: Meleshin's (2011) energy-efficient structure for the rest of a span,
solved for the holding speed V_c in milliseconds, from any state (s, V, t) and for any mass and
resistance (models/ato/controller.py calls it every few seconds with the estimator's values).

It is the maximum-principle synthesis of models/planning/max_principle.py reduced to what a running-time
regulator needs, in plain scalar Python:

- a coarse grid (``step`` 10 m by default, plus every grade and limit change), RK2 (midpoint)
  in distance on q = V^2 instead of the planners' RK4, and no numpy in the loops;
- the same cruise policy (TG up to V_c, C at V_c, VB on a descent up to V_r, SR at V_r, all
  capped by the envelope U(s)) and the same coast rule: before every falling braking curve of U
  the cruise runs into, a coast that starts with p = 1 and ends on the curve with
  p = eta eta_f (Table 2's VB -> RK switch), p integrated with the coasting co-state equation
  dp/ds = (W'(V) p - V_c^2 W'(V_c) / V^2) / (m V) (models/planning/trajectory.py derives it);
- what it leaves out against synthesize(): the choice of one long coast through a lower-limit
  zone instead of a coast into it (synthesize tries every such choice), the jump of p at state
  constraints (synthesize leaves it out too);
- a fallback where that structure cannot meet the schedule (ReducedPlanner.plan says why):
  the same cruise without the coasts, solved for V_c, whose arrival falls continuously from
  the slowest run to the fastest (min_time), so that every schedule in between is planned for;
- its own final braking curve: the service brake (``brake_share`` of the regenerative brake, so
  that the tracking controller keeps a reserve) down to ``v_relay`` (7 km/h: where Meleshin's
  electric brake fades), then the constant deceleration ``a_ep`` of the electro-pneumatic
  stage to the stop mark (the curve models/ato/stopping.py tracks with Sidorenko's (1997) relay).

The envelope U(s) (limits less ``limit_margin``, braking curves to every lower limit ahead and
to the stop mark) is recomputed for each re-plan's mass and resistance: a heavier car brakes
later at the same force. Units: s [m], V [m/s], t [s], force [N], mass [t], grade [permille].
"""
from __future__ import annotations

import math
from bisect import bisect_right
from dataclasses import dataclass

from models.ato.motion import (
    K_BRAKE, K_COAST, K_TG, PlanCar, Trace, coast_step, free_step, hold_forces, q_at, step_time,
)
from models.ato.interface import AtoTuning
from models.ato.stopping import ep_deceleration
from models.fpmath import square
from models.planning.span import CarTraction, Span
from models.planning.engine import Mode

_EPS_Q = 1e-12                # relative tolerance on q = V^2 comparisons


class ReducedCourse:
    """A span on the re-planner's grid: nodes (every ``step`` m, every grade change (+ the car
    length) and limit change, the start of the final electro-pneumatic curve, the stop mark),
    the grade of each cell and the planning limit (V_lim - ``limit_margin``)^2 at each node.
    Raises ValueError naming the value if a limit less the margin is not positive."""

    def __init__(self, span: Span, car: CarTraction, *, step: float = 10.0,
                 limit_margin: float = 0.0, v_relay: float | None = None, a_ep: float = 0.6):
        for name, val in (("step", step), ("a_ep", a_ep)):
            if not (math.isfinite(val) and val > 0.0):
                raise ValueError(f"{name} must be > 0 and finite, got {val}")
        if not (math.isfinite(limit_margin) and limit_margin >= 0.0):
            raise ValueError(f"limit_margin must be >= 0 and finite [m/s], got {limit_margin}")
        v_relay = car.regen_fade_speed if v_relay is None else v_relay
        if not (math.isfinite(v_relay) and v_relay > 0.0):
            raise ValueError(f"v_relay must be > 0 and finite [m/s], got {v_relay}")
        for k, v in enumerate(span.limit_speeds):
            if v - limit_margin <= v_relay:
                raise ValueError(
                    f"span.limit_speeds[{k}] = {v} m/s (from s = {span.limit_distances[k]} m) "
                    f"cannot be met with the speed margin {limit_margin} m/s: the planned limit "
                    f"{v - limit_margin:.3f} m/s is not above the relay speed {v_relay:.3f} m/s")
        self.span, self.car = span, car
        self.stop = span.stop
        self.h = step
        self.margin = limit_margin
        self.v_relay, self.a_ep = v_relay, a_ep
        self.d_relay = v_relay * v_relay / (2.0 * a_ep)      # length of the EP curve [m]
        if self.d_relay >= span.stop:
            raise ValueError(f"span.stop = {span.stop} m is shorter than the final "
                             f"electro-pneumatic braking curve ({self.d_relay:.1f} m)")
        n = max(1, int(math.ceil(span.stop / step)))
        nodes = {span.stop * k / n for k in range(n + 1)}
        nodes |= set(span.breakpoints(car.length))
        nodes.add(span.stop - self.d_relay)
        s = sorted(nodes)
        keep = [s[0]]
        for x in s[1:]:
            if x - keep[-1] > 1e-6:
                keep.append(x)
        keep[-1] = span.stop
        self.s = keep
        self.n = len(keep)
        L = car.length
        self.g = [span.grade.average(0.5 * (a + b), L) for a, b in zip(keep[:-1], keep[1:])]
        self.qlim = [square(span.v_lim_at_node(x) - limit_margin) for x in keep]
        x_relay = span.stop - self.d_relay           # a node: where the EP curve starts
        self.i_relay = min(range(self.n), key=lambda k: abs(keep[k] - x_relay))

    def cell(self, x: float) -> int:
        """Index i of the cell [s_i, s_i+1) containing x (clamped to the cells)."""
        i = bisect_right(self.s, x) - 1
        return 0 if i < 0 else (self.n - 2 if i > self.n - 2 else i)


@dataclass(frozen=True)
class ReducedPlan:
    """A re-plan: the policy the controller executes and the run it predicts.

    hold_speed V_c and regen_speed V_r [m/s] (the cruise); coasts: (s_c, s_end) [m], coast from
    s_c until the braking curve ahead, which ends at s_end (a lower limit or the stop mark);
    s, v, t: the predicted run's nodes [m, m/s, s]; mode: per segment (Mode codes);
    qU: the envelope U^2 on the course's nodes [m^2/s^2]; arrival [s]: t at the stop mark;
    energy [kWh] as models.planning.trajectory.Plan (traction / eta_f - eta regen); status "ok", "late"
    (even the fastest policy arrives after the target: the fastest is returned) or "early"
    (even the slowest holding speed tried arrives before it); trials: forward runs made;
    policy: "energy" (Meleshin's structure, the module docstring) or "capped" (the fallback
    where that structure cannot meet the schedule: full traction up to a speed cap V_c, held,
    no coasts; regen_speed = hold_speed = the cap, coasts empty)."""
    hold_speed: float
    regen_speed: float
    coasts: tuple
    s: tuple
    v: tuple
    t: tuple
    mode: tuple
    qU: tuple
    arrival: float
    energy_kwh: float
    traction_kwh: float
    regen_kwh: float
    status: str
    trials: int
    policy: str = "energy"

    def speed_at(self, x: float) -> float:
        """The planned speed [m/s] at distance x (linear between nodes)."""
        s = self.s
        k = bisect_right(s, x) - 1
        if k < 0:
            return self.v[0]
        if k >= len(s) - 1:
            return self.v[-1]
        w = (x - s[k]) / (s[k + 1] - s[k])
        return self.v[k] + w * (self.v[k + 1] - self.v[k])


class ReducedPlanner:
    """Re-plans the rest of a span on a ReducedCourse (see the module docstring).

    ``plan(car, s0, v0, t0, arrival)``: the policy from the state (s0 [m], v0 [m/s]) at time t0
    [s] that arrives at the stop mark at ``arrival`` [s] within ``tol`` [s], for the PlanCar
    ``car``. Warm-started from the previous plan (its V_c and coast points).
    """

    def __init__(self, course: ReducedCourse, *, tol: float = 0.05, v_min: float = 1.0):
        self.c = course
        self.tol = tol
        self.v_min = v_min
        self._last_vc = None
        self._vc_slope = None
        self._last_cap = None         # the last capped plan's cap [m/s] (its solve's start)
        self._coast_hints: dict = {}
        self.coast_runs = 0          # coasts simulated by the coast-point searches (a cost count)

    # ----------------------------------------------------------------- the envelope
    def envelope(self, car: PlanCar) -> list:
        """U(s)^2 on the nodes: backward from rest at the stop mark (a_ep on the last d_relay
        metres, then the service brake), capped by the planning limits. Raises ValueError naming
        the place if the brake cannot keep the car within a limit or stop it."""
        c = self.c
        s, g, qlim = c.s, c.g, c.qlim
        qU = [0.0] * c.n
        a2 = 2.0 * c.a_ep
        for i in range(c.n - 2, -1, -1):
            if i >= c.i_relay:
                qb = a2 * (c.stop - s[i])
            else:
                qb = free_step(car, qU[i + 1], s[i] - s[i + 1], g[i], K_BRAKE)[0]
            qU[i] = min(qb, qlim[i]) if qb > 0.0 else 0.0
            if qU[i] <= 0.0 and i > 0:
                raise ValueError(f"the span cannot be run: at s = {s[i]:.1f} m (grade {g[i]} "
                                 f"permille) the service brake ({car.share:g} of the electric "
                                 f"brake) cannot keep a {car.brake_mass:.1f} t car within the "
                                 f"speed limit / stop it at span.stop = {c.stop} m")
        return qU

    @staticmethod
    def _stretches(qU: list) -> list:
        """For each cell, (first node, last node) of the falling stretch of U it lies on, or
        None: the braking curves to a lower limit or to the stop mark."""
        n = len(qU)
        out = [None] * (n - 1)
        i = 0
        while i < n - 1:
            if qU[i + 1] < qU[i] * (1.0 - _EPS_Q):
                j = i
                while j < n - 1 and qU[j + 1] < qU[j] * (1.0 - _EPS_Q):
                    j += 1
                for k in range(i, j):
                    out[k] = (i, j)
                i = j
            else:
                i += 1
        return out

    # ----------------------------------------------------------------- runs
    def _step(self, car, q0, a, b, i, kind, floor, ca, cb, qU, fall):
        """One step [a, b] in cell i: free motion under ``kind``, bounded above by the ceiling
        (ca at a, cb at b, linear) and below by the constant ``floor``. Returns
        (q1, dt, mode, wF, wR, capped_on_U_falling)."""
        g = self.c.g[i]
        h = b - a
        q1, vm = free_step(car, q0, h, g, kind)
        over = q1 > cb
        if over:
            g0, g1 = q0 - ca, q1 - cb
            w = g0 / (g0 - g1) if g0 < 0.0 else 0.0
            qx, bound = (ca + w * (cb - ca) if w > 0.0 else q0), cb
        elif q1 < floor:
            g0, g1 = q0 - floor, q1 - floor
            w = g0 / (g0 - g1) if g0 > 0.0 else 0.0
            qx, bound = (floor if w > 0.0 else q0), floor
        else:
            wF = h * car.f_max(vm) if kind == K_TG else 0.0
            return q1, step_time(h, q0, q1), (Mode.TG if kind == K_TG else Mode.VB), wF, 0.0, False
        sx = a + w * h
        rest = b - sx
        wF1 = w * h * car.f_max(vm) if kind == K_TG else 0.0
        dt1 = step_time(sx - a, q0, qx) if w > 0.0 else 0.0
        if rest > 1e-9:
            F, R, M, ok = hold_forces(car, qx, bound, rest, g)
        else:
            F = R = M = 0.0
            ok = True
        if not (ok or over):    # the floor needs more than f_max: full traction for the step
            q1, vm = free_step(car, q0, h, g, K_TG)
            return q1, step_time(h, q0, q1), Mode.TG, h * car.f_max(vm), 0.0, False
        decel = bound < qx * (1.0 - 1e-9)
        if F > 0.0:
            mode = Mode.TG if F >= car.f_max(math.sqrt(bound)) * (1 - 1e-9) else Mode.C
        elif M > 0.0:
            mode = Mode.TM if decel else Mode.ST
        else:
            mode = Mode.RK if decel else Mode.SR
        on_u = over and decel and fall[i] is not None and cb >= qU[i + 1] * (1.0 - 1e-12)
        return bound, dt1 + step_time(rest, qx, bound), mode, wF1 + F * rest, R * rest, on_u

    def _u_at(self, qU, x, i):
        s = self.c.s
        if x <= s[i]:
            return qU[i]
        if x >= s[i + 1]:
            return qU[i + 1]
        return qU[i] + (x - s[i]) / (s[i + 1] - s[i]) * (qU[i + 1] - qU[i])

    def _cruise(self, car, tr: Trace, qc, qr, qU, fall, handled: float):
        """Extend ``tr`` with the cruise policy to the stop mark, or until it runs onto a falling
        braking curve of U ending beyond ``handled`` (returns (segment index, (j0, j1)))."""
        c = self.c
        s = c.s
        a, q0 = tr.s[-1], tr.q[-1]
        i = c.cell(a)
        if a >= s[i + 1] - 1e-9:
            i += 1
        while a < c.stop - 1e-9 and i < c.n - 1:
            b = s[i + 1]
            ua, ub = self._u_at(qU, a, i), qU[i + 1]
            if q0 < qc * (1.0 - _EPS_Q):
                kind, floor, cb, ca = K_TG, -math.inf, min(ub, qc), min(ua, qc)
            else:
                kind, floor, cb, ca = K_COAST, qc, min(ub, qr), min(ua, qr)
            q1, dt, mode, wF, wR, on_u = self._step(car, q0, a, b, i, kind, floor, ca, cb, qU,
                                                    fall)
            if on_u and fall[i] is not None and s[fall[i][1]] > handled + 1e-9:
                return len(tr.mode), fall[i]
            if q1 <= 0.0 and b < c.stop - 1e-9:
                raise _Stall(b)
            tr.add(b, q1, dt, mode, wF, wR)
            a, q0 = b, q1
            i += 1
        return None

    def _coast(self, car, tr: Trace, x: float, curve, k_lam, qU, fall, keep: bool):
        """Coast from x (on trace ``tr``) with p = 1 until the braking curve ``curve`` = (j0, j1)
        is met (in a step ending beyond its start) or its end is reached. Returns (residual
        p - eta eta_f there, met, trace from x or None); a stall returns -inf."""
        c = self.c
        s = c.s
        pe = car.eta * car.eta_f
        out = tr.cut_at(x) if keep else None
        a, q0 = x, q_at(tr, x)
        j0, j1 = curve
        s_start, s_end = s[j0], s[j1]
        i = c.cell(a)
        if a >= s[i + 1] - 1e-9:
            i += 1
        p = 1.0
        if q0 <= 0.0:
            return -math.inf, False, out
        while a < s_end - 1e-9:
            b = s[i + 1]
            g = c.g[i]
            h = b - a
            q1, p1 = coast_step(car, q0, p, h, g, k_lam)
            ub = qU[i + 1]
            if q1 > ub:
                ua = self._u_at(qU, a, i)
                g0, g1 = q0 - ua, q1 - ub
                w = g0 / (g0 - g1) if g0 < 0.0 else 0.0
                if b > s_start + 1e-9 and fall[i] is not None:
                    if keep:
                        sx = a + w * h
                        qx = ua + w * (ub - ua) if w > 0 else q0
                        if w > 0.0:
                            out.add(sx, qx, step_time(sx - a, q0, qx), Mode.VB)
                    return p + w * (p1 - p) - pe, True, out
                # a limit or another curve on the way: follow U (regen / mech), coast on
                sx = a + w * h
                qx = ua + w * (ub - ua) if w > 0 else q0
                F, R, M, _ = hold_forces(car, qx, ub, b - sx, g) if b - sx > 1e-9 else (0, 0, 0, 1)
                if keep:
                    mode = Mode.TM if M > 0 else (Mode.RK if ub < qx else Mode.SR)
                    dt = (step_time(sx - a, q0, qx) if w > 0 else 0.0) + step_time(b - sx, qx, ub)
                    out.add(b, ub, dt, mode, F * (b - sx), R * (b - sx))
                q1 = ub
            else:
                if q1 <= 0.0:
                    return -math.inf, False, out
                if keep:
                    out.add(b, q1, step_time(h, q0, q1), Mode.VB)
            a, q0, p = b, q1, p1
            i += 1
        return p - pe, False, out

    def _coast_point(self, car, tr, k_lo, k_b, curve, final, k_lam, qU, fall, key):
        """The coast point in [s(k_lo), s(k_b)]: the residual is > 0 at s(k_b) (no coast) and
        falls as the coast starts earlier. Solved to 1 m (a coast point 1 m off moves the
        arrival by ~0.05 s, and the next re-plan corrects it) from the last re-plan's point and
        slope for this curve."""
        lo_bound, hi = tr.s[k_lo], tr.s[k_b]
        if hi - lo_bound <= 1.0:
            return lo_bound

        def r(x):
            self.coast_runs += 1
            res, met, _ = self._coast(car, tr, x, curve, k_lam, qU, fall, False)
            return res if (met or final) else -math.inf

        hint, slope = self._coast_hints.get(key, (None, None))
        x0 = hint if hint is not None and lo_bound < hint < hi else max(lo_bound, hi - 100.0)
        best, below, above, slope = _solve(r, x0, 20.0, slope, lo_bound, hi, 1.0, 1e-4, True,
                                           upper=(hi, 1.0 - car.eta * car.eta_f))
        if abs(best[1]) <= 1e-4:
            x = best[0]
        elif below is None:
            return lo_bound                  # p stays above eta eta_f: coast from the start
        else:
            (xa, ga), (xb, gb) = below, above
            x = xa + (xb - xa) * (-ga) / (gb - ga) if math.isfinite(ga) and gb != ga else xb
        self._coast_hints[key] = (x, slope)
        return x

    def _run(self, car, s0, q0, t0, v_c, qU, fall):
        """The whole policy for V_c from (s0, q0, t0): returns (trace, coasts)."""
        qc = v_c * v_c
        vr = car.hold_regen_speed(v_c)
        qr = vr * vr if math.isfinite(vr) else math.inf
        k_lam = qc * car.w_slope(v_c)
        tr = Trace(s0, q0, t0)
        handled = s0 - 1.0
        k_lo = 0
        coasts = []
        for _ in range(len(self.c.span.limit_distances) + 2):
            ev = self._cruise(car, tr, qc, qr, qU, fall, handled)
            if ev is None:
                break
            k_b, curve = ev
            end = self.c.s[curve[1]]
            final = curve[1] == self.c.n - 1
            key = round(end, 3)
            x = self._coast_point(car, tr, k_lo, k_b, curve, final, k_lam, qU, fall, key)
            _, _, head = self._coast(car, tr, x, curve, k_lam, qU, fall, True)
            coasts.append((x, end))
            tr = head
            handled = end
            k_lo = len(tr.s) - 1
        return tr, tuple(coasts), v_c, vr

    def _capped_run(self, car, s0, q0, t0, v_cap, qU, fall):
        """The capped policy from (s0, q0, t0): the cruise policy of Meleshin's structure for
        V_c = v_cap [m/s] (full traction up to V_c, held by traction; above it coasting, held at
        V_r by the brake), everything under U, but no coasts before the braking curves. Its
        arrival is continuous and non-increasing in v_cap (the speed is, at every s: the force
        law rises with V_c at every speed), and with a cap above every speed of the envelope
        it is the fastest run (min_time). Returns (trace, V_r); raises _Stall."""
        qc = v_cap * v_cap
        vr = car.hold_regen_speed(v_cap)
        qr = vr * vr if math.isfinite(vr) else math.inf
        tr = Trace(s0, q0, t0)
        self._cruise(car, tr, qc, qr, qU, fall, math.inf)
        return tr, vr

    # ----------------------------------------------------------------- the plan
    def plan(self, car: PlanCar, s0: float, v0: float, t0: float, arrival: float,
             qU: list | None = None) -> ReducedPlan:
        """The policy from (s0, v0, t0) arriving at ``arrival`` [s] (see the class docstring).
        ``qU``: the envelope for ``car`` if already computed. Raises ValueError if the envelope
        cannot be built for this car (ReducedPlanner.envelope).

        First Meleshin's structure, solved for V_c. Its arrival is neither continuous nor
        monotone in V_c where limit zones cut the span (a coast point jumps to another root of
        its co-state condition, a coast starts in a lower zone, a cruise meets another braking
        curve first), so some schedules lie in its gaps; it is also flat over stretches of V_c
        (a run that coasts from s0 whatever V_c), which the solve crosses. Where it misses the
        schedule by more than ``tol``, the capped policy (_capped_run: the cruise without the
        coasts) is solved for V_c instead: its arrival is continuous and monotone from the
        fastest run (V_c above the envelope: min_time) to the slowest (V_c = v_min), so every
        schedule between them is met within ``tol``."""
        c = self.c
        qU = self.envelope(car) if qU is None else qU
        fall = self._stretches(qU)
        s0 = min(max(s0, 0.0), c.stop)
        q0 = square(max(v0, 0.0))
        runs = {}
        v_top = math.sqrt(max(qU))
        v_hi = 4.0 * max(v_top, v0)

        def trial(v_c):
            if v_c not in runs:
                try:
                    runs[v_c] = self._run(car, s0, q0, t0, v_c, qU, fall)
                except _Stall:
                    runs[v_c] = None
            r = runs[v_c]
            return math.inf if r is None else r[0].t[-1] - arrival

        guess = self._last_vc if self._last_vc is not None else 0.8 * v_top
        guess = min(max(guess, self.v_min), v_hi)
        # max_flat 8: arrival(V_c) is flat where the run coasts from s0 for every V_c in a stretch
        # (mid-run, on the coast to the stop: measured 14-30 m/s wide); the step doubling from
        # 3 % of V_c crosses 2^8 times that before giving up
        (best, e), _, _, self._vc_slope = _solve(trial, guess, 0.03 * guess, self._vc_slope,
                                                 self.v_min, v_hi, 1e-4, self.tol, False,
                                                 max_flat=8)
        if abs(e) <= self.tol and runs.get(best) is not None:
            trace, coasts, v_c, vr = runs[best]
            self._last_vc = v_c
            return self._plan_of(car, trace, v_c, vr, coasts, qU, "ok", len(runs), "energy")
        return self._plan_capped(car, s0, q0, t0, arrival, qU, fall, len(runs))

    def _plan_capped(self, car, s0, q0, t0, arrival, qU, fall, trials) -> ReducedPlan:
        """The capped policy whose arrival is ``arrival`` within ``tol``: Illinois false position
        on the cap between v_min and a cap never reached (the fastest run), first trying the last
        capped re-plan's cap. Status "late" (the fastest run returned) or "early" (the cap v_min
        returned) where the schedule lies outside that range."""
        runs = {}

        def trial(v_cap):
            if v_cap not in runs:
                try:
                    tr, vr = self._capped_run(car, s0, q0, t0, v_cap, qU, fall)
                    runs[v_cap] = (tr, tr.t[-1] - arrival, vr)
                except _Stall:
                    runs[v_cap] = (None, math.inf, math.inf)
            return runs[v_cap][1]

        def result(v_cap, status):
            tr, _, vr = runs[v_cap]
            if tr is None:
                raise ValueError(f"no holding speed runs the rest of the span from s = {s0:.1f} m, "
                                 f"V = {math.sqrt(q0):.2f} m/s: the car would stall")
            return self._plan_of(car, tr, v_cap, vr, (), qU, status, trials + len(runs),
                                 "capped")

        # "no cap": a cap above every speed of the run (the envelope's top, the start), as in
        # min_time; a finite one, for the controller tracks the hold speed
        v_top = max(math.sqrt(max(qU)), math.sqrt(q0))
        v_free = 4.0 * v_top
        e_fast = trial(v_free)
        if e_fast >= -self.tol:
            return result(v_free, "ok" if e_fast <= self.tol else "late")
        e_slow = trial(self.v_min)
        if e_slow <= self.tol:
            return result(self.v_min, "ok" if e_slow >= -self.tol else "early")
        lo, f_lo, hi, f_hi = self.v_min, e_slow, v_free, e_fast     # f(lo) > 0 > f(hi)
        hint = self._last_cap
        side = 0
        x = hint if hint is not None and lo < hint < hi else None
        best = v_free
        for _ in range(100):
            if x is None:
                if math.isfinite(f_lo):
                    x = lo + (hi - lo) * f_lo / (f_lo - f_hi)
                    x = min(max(x, lo + 0.01 * (hi - lo)), hi - 0.01 * (hi - lo))
                else:
                    x = 0.5 * (lo + hi)
            f = trial(x)
            if abs(f) < abs(runs[best][1]):
                best = x
            if abs(f) <= self.tol or hi - lo <= 1e-9:
                break
            if f > 0.0:
                lo, f_lo = x, f
                if side == 1:
                    f_hi *= 0.5           # Illinois: the stale end's value halved
                side = 1
            else:
                hi, f_hi = x, f
                if side == -1 and math.isfinite(f_lo):
                    f_lo *= 0.5
                side = -1
            x = None
        self._last_cap = best
        e = runs[best][1]
        return result(best, "ok" if abs(e) <= self.tol else ("late" if e > 0.0 else "early"))

    def _plan_of(self, car, trace, v_c, vr, coasts, qU, status, trials, policy) -> ReducedPlan:
        wF, wR = sum(trace.wF), sum(trace.wR)
        traction = wF / car.eta_f / 3.6e6
        regen = car.eta * wR / 3.6e6
        return ReducedPlan(hold_speed=v_c, regen_speed=vr, coasts=coasts, s=tuple(trace.s),
                           v=tuple(math.sqrt(q) if q > 0 else 0.0 for q in trace.q),
                           t=tuple(trace.t), mode=tuple(int(m) for m in trace.mode), qU=tuple(qU),
                           arrival=trace.t[-1], energy_kwh=traction - regen, traction_kwh=traction,
                           regen_kwh=regen, status=status, trials=trials, policy=policy)

    def min_time(self, car: PlanCar, qU: list | None = None) -> float:
        """Running time [s] of the fastest run from rest: full traction capped by U, the capped
        policy with a cap above the envelope (never reached): the run plan() returns for this
        schedule, computed by the same code."""
        qU = self.envelope(car) if qU is None else qU
        v_free = 4.0 * math.sqrt(max(qU))
        try:
            return self._capped_run(car, 0.0, 0.0, 0.0, v_free, qU, self._stretches(qU))[0].t[-1]
        except _Stall as e:    # a climb beyond the traction: say where (it escaped as "1150.0")
            raise ValueError(f"the span cannot be run: at full traction from rest the "
                             f"{car.mass:.1f} t car comes to rest at s = {e.args[0]} m, before "
                             f"span.stop = {self.c.stop} m (a climb beyond its traction)") from None


def _solve(f, x0: float, dx: float, slope, lo: float, hi: float, xtol: float, ftol: float,
           rising: bool, upper=None, max_flat: int = 2):
    """A root of the monotone f on [lo, hi] (``rising`` or falling; f may be -inf on the low
    side of a rising f), from x0: Newton steps with ``slope`` (the last solve's, else a first
    step ``dx``), secant steps (a step doubling while the slope is unknown) until the root is
    bracketed, then Illinois false position (bisection next to -inf) to ``xtol`` or
    |f| <= ``ftol``; it gives up where f is the same at ``max_flat`` + 1 points running (no
    lever; the step doubles on each, so a larger ``max_flat`` crosses a wider flat stretch).
    ``upper``: a known (x, f) on the far side of the root (not evaluated).

    Returns (x, f(x)) of the best evaluated point, the bracket (lo point, hi point) as (x, f)
    pairs or None, and the last secant slope (for the next solve)."""
    sg = 1.0 if rising else -1.0
    below = above = None          # (x, g) with g = sg f < 0 (root above x) and > 0 (below x)
    best = None
    last_side = 0

    def take(x, y):
        nonlocal below, above, best, last_side
        g = sg * y
        if best is None or abs(y) < abs(best[1]):
            best = (x, y)
        if g < 0.0:
            if below is None or x > below[0]:
                below = (x, g)
            if last_side == -1 and above is not None:       # Illinois
                above = (above[0], 0.5 * above[1])
            last_side = -1
        else:
            if above is None or x < above[0]:
                above = (x, g)
            if last_side == 1 and below is not None and math.isfinite(below[1]):
                below = (below[0], 0.5 * below[1])
            last_side = 1

    if upper is not None:
        g = sg * upper[1]
        if g < 0.0:
            below = (upper[0], g)
        else:
            above = (upper[0], g)
    x, y = x0, f(x0)
    take(x, y)
    step = abs(dx)
    flat = 0
    for _ in range(60):
        if abs(y) <= ftol:
            break
        if below is not None and above is not None:
            (xa, ga), (xb, gb) = below, above
            if xb - xa <= xtol:
                break
            if math.isfinite(ga) and ga != gb:
                nx = xa + (xb - xa) * (-ga) / (gb - ga)
                nx = min(max(nx, xa + 0.02 * (xb - xa)), xb - 0.02 * (xb - xa))
            else:
                nx = 0.5 * (xa + xb)
            ny = f(nx)
            if math.isfinite(y) and math.isfinite(ny) and nx != x and ny != y:
                slope = (ny - y) / (nx - x)
            x, y = nx, ny
            take(x, y)
            continue
        up = sg * y < 0.0                  # the root lies above x
        if slope is not None and math.isfinite(y) and sg * slope > 0.0:
            d = min(max(abs(y / slope), 0.05 * step), 8.0 * step)
        else:
            d = step
            step *= 2.0
        nx = min(max(x + (d if up else -d), lo), hi)
        if nx == x:
            break                          # at a bound with the root beyond it
        ny = f(nx)
        if ny == y:                        # f does not depend on x here: no lever
            flat += 1
            slope = None
            if flat >= max_flat:
                break
        elif math.isfinite(y) and math.isfinite(ny):
            slope = (ny - y) / (nx - x)
        x, y = nx, ny
        take(x, y)
    return best, below, above, slope


class _Stall(Exception):
    """The car comes to rest before the stop mark."""


def plan_setup(span: Span, car: CarTraction,
               tuning: AtoTuning) -> tuple[ReducedCourse, ReducedPlanner, PlanCar]:
    """(course, planner, configured car) the controller plans ``span`` with: the one copy that
    models.ato.controller.AtoController, ``fastest_run``, the harness's span-info, the studies
    and the tests share (the EP stage's deceleration follows the stop mark's grade:
    stopping.ep_deceleration)."""
    a_ep = ep_deceleration(car, tuning, span.grade.average(span.stop, car.length))
    course = ReducedCourse(span, car, step=tuning.grid_step, limit_margin=tuning.limit_margin,
                           v_relay=car.regen_fade_speed, a_ep=a_ep)
    planner = ReducedPlanner(course, tol=tuning.time_tol)
    return course, planner, PlanCar(car, car.mass, car.A0, car.A1, car.A2, tuning.brake_share)


def fastest_run(span: Span, car: CarTraction, tuning: AtoTuning | None = None) -> float:
    """[s] the fastest run the controller plans for ``span`` with ``car`` (the least schedule it
    accepts, less its time_tol), whatever span.schedule is."""
    _, planner, configured = plan_setup(span, car, AtoTuning() if tuning is None else tuning)
    return planner.min_time(configured, planner.envelope(configured))
