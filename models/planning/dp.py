"""Dynamic programming over a span: Sidorenko's (1997) limited-switching DP and a brute-force
optimum.

Units as in models.planning.trajectory: s [m], V [m/s], t [s], forces [N], energy [J] inside, [kWh] out.

Sidorenko (1997, ch. 2): the span is cut into M steps where the mode may change; the criterion is
the sum over the steps of the energy A_i plus lambda times the running time T_i; Bellman's
functional equation runs over the state (V_i, N_i) (speed, mode) with at most K traction
applications and a minimum time tau_min between mode switches, the speed limit entering as a
penalty. Ours:

- state: (speed on a grid, mode N in {TG, VB, RK}, traction applications used k <= K, stages
  spent in the current mode d, capped at D); a switch is allowed only after D stages (Sidorenko's
  tau_min, as a distance: D stages of ``stage`` metres);
- speed grid per stage: n_speeds points from 0 to the envelope U(s_j) (models.planning.trajectory), so
  the braking curve (and a speed limit) is a grid point, the cost-to-go interpolated linearly
  in V; the speed limit is a hard ceiling (every step is capped by U, see models.planning.trajectory)
  instead of Sidorenko's penalty;
- each stage integrated with the same step as the maximum-principle plans (models.planning.trajectory
  .step, numpy over the speed grid; the transition tables do not depend on lambda and are built
  once);
- lambda by bisection on a log scale until the running time brackets the schedule; the plan is
  the policy rolled out from rest with the exact (scalar) step, then its last switching point
  moved (brentq, the simulator) so the running time meets the schedule within ``tol``.

Sidorenko prunes the DP with necessary conditions of optimality (10x faster, same optimum);
on a grid of this size plain DP is fast enough, so we do not prune.

The brute-force optimum (issue 20's "brute-force optimum over a discretised control") is the
same DP on a fine grid without switching limits (state: speed only) and a richer control set:
full and half traction, speed holding (C/SR/ST), coasting, full and half regen braking.
It is an upper bound of the true optimum (a feasible plan, exactly simulated) that converges
as the grid is refined (studies/ato_energy.py shows two grid sizes).
"""
from __future__ import annotations

import math

import numpy as np

from models.planning.span import CarTraction, Span
from models.planning.engine import (
    K_COAST, K_REGEN, K_TRACTION, Course, Mode, Plan, Stall, _check_schedule, _flat_out,
    _plan_from, _root_within, _run_commands, run, step,
)

# an action: (free force law, share u, hold?, the simulator's Mode)
TG = (K_TRACTION, 1.0, False, Mode.TG)
TG_HALF = (K_TRACTION, 0.5, False, Mode.TG)
HOLD = (K_COAST, 0.0, True, Mode.C)
VB = (K_COAST, 0.0, False, Mode.VB)
RK = (K_REGEN, 1.0, False, Mode.RK)
RK_HALF = (K_REGEN, 0.5, False, Mode.RK)
SEED004_ACTIONS = (TG, VB, RK)
BRUTE_ACTIONS = (TG, TG_HALF, HOLD, VB, RK, RK_HALF)


class _Tables:
    """Stage boundaries (every ``stride`` grid nodes), per-stage speed grids and the transition
    tables: next speed, time and energy (traction / eta_f - eta regen [J]) per action."""

    def __init__(self, course: Course, stride: int, n_speeds: int, actions):
        if stride < 1 or n_speeds < 3:
            raise ValueError(f"stride must be >= 1 and n_speeds >= 3, got {stride}, {n_speeds}")
        self.course, self.actions = course, actions
        car = course.car
        nodes = list(range(0, course.n - 1, stride)) + [course.n - 1]
        self.nodes = nodes
        self.M = len(nodes) - 1
        frac = np.linspace(0.0, 1.0, n_speeds)
        self.grid = [np.sqrt(course.qU[j]) * frac for j in nodes]
        A = len(actions)
        self.v_next = np.empty((self.M, A, n_speeds))
        self.cost_e = np.empty((self.M, A, n_speeds))
        self.dt = np.empty((self.M, A, n_speeds))
        for j in range(self.M):
            i0, i1 = nodes[j], nodes[j + 1]
            q_entry = self.grid[j] ** 2          # an array: numpy squares by x * x
            for a, act in enumerate(actions):
                q, t, e = self.propagate(q_entry, i0, i1, act)
                self.v_next[j, a] = np.sqrt(np.maximum(q, 0.0))
                self.dt[j, a] = t
                self.cost_e[j, a] = e
        self.eta_f, self.eta = car.eta_f, car.eta

    def propagate(self, q_entry, i0: int, i1: int, act):
        """Run action ``act`` over grid steps i0..i1 from q_entry (array or float); returns
        (q, time, energy [J]) with time = inf if the car stalls before the stop mark."""
        c, car = self.course, self.course.car
        kind, u, hold, _ = act
        q = q_entry
        t = 0.0 * q_entry
        e = 0.0 * q_entry
        for i in range(i0, i1):
            ceil, ceil_a = c.qU[i + 1], c.qU[i]
            if hold:
                mn = np.minimum if isinstance(q, np.ndarray) else min
                ceil, ceil_a = mn(q_entry, ceil), mn(q_entry, ceil_a)
                floor, floor_a = ceil, ceil_a
            else:
                floor = floor_a = -math.inf
            q, dt, wF, wR, _, _, _, _ = step(car, q, c.s[i], c.s[i + 1], (c.ga[i], c.gm[i], c.gb[i]),
                                             kind, u, floor, ceil, floor_a=floor_a, ceil_a=ceil_a)
            t = t + dt
            e = e + wF / car.eta_f - car.eta * wR
        if i1 < c.n - 1:
            stalled = q <= 0.0
            if isinstance(q, np.ndarray):
                t = np.where(stalled, math.inf, t)
            elif stalled:
                t = math.inf
        return q, t, e


def _interp(v, grid, values):
    """Linear interpolation of values on grid at v (grid all zeros at the stop mark)."""
    if grid[-1] <= 0.0:
        return np.full(np.shape(v), values[0]) if np.ndim(v) else float(values[0])
    return np.interp(v, grid, values)


class _SwitchDP:
    """Sidorenko's (1997) DP: state (V, mode, k, d)."""

    def __init__(self, tables: _Tables, max_tractions: int, min_stages: int):
        self.tb = tables
        self.K, self.D = max_tractions, max(1, min_stages)
        self.traction = [act[0] == K_TRACTION for act in tables.actions]

    def transitions(self, a: int, k: int, d: int):
        """Allowed (a', k', d') from state (a, k, d); a = -1 is rest before departure."""
        out = []
        for b in range(len(self.tb.actions)):
            if b == a:
                out.append((b, k, min(d + 1, self.D)))
            elif a == -1 or d >= self.D:
                k2 = k + (1 if self.traction[b] and (a == -1 or not self.traction[a]) else 0)
                if k2 <= self.K:
                    out.append((b, k2, 1))
        return out

    def solve(self, lam: float):
        tb = self.tb
        A, K, D = len(tb.actions), self.K, self.D
        nV = len(tb.grid[0])
        J = np.zeros((A, K + 1, D + 1, nV))          # at the stop mark: nothing left to pay
        self.cont = [None] * tb.M
        for j in range(tb.M - 1, -1, -1):
            cont = np.full((A, K + 1, D + 1, nV), np.inf)
            for b in range(A):
                stage = tb.cost_e[j, b] + lam * tb.dt[j, b]
                for k in range(K + 1):
                    for d in range(1, D + 1):
                        cont[b, k, d] = stage + _interp(tb.v_next[j, b], tb.grid[j + 1], J[b, k, d])
            self.cont[j] = cont
            Jn = np.full((A, K + 1, D + 1, nV), np.inf)
            for a in range(A):
                for k in range(K + 1):
                    for d in range(1, D + 1):
                        for b, k2, d2 in self.transitions(a, k, d):
                            np.minimum(Jn[a, k, d], cont[b, k2, d2], out=Jn[a, k, d])
            J = Jn

    def rollout(self, lam: float):
        """Commands of the policy from rest: at each stage the allowed action with the least
        cost-to-go interpolated at the actual speed, the state then propagated with the exact
        scalar step (so the plan is what the simulator runs)."""
        tb = self.tb
        c = tb.course
        q, state = 0.0, (-1, 0, self.D)
        cmds = []
        for j in range(tb.M):
            v = math.sqrt(max(q, 0.0))
            best = None
            for b, k2, d2 in self.transitions(*state):
                val = float(_interp(v, tb.grid[j], self.cont[j][b, k2, d2]))
                if best is None or val < best[0]:
                    best = (val, b, k2, d2)
            _, b, k2, d2 = best
            if not math.isfinite(best[0]):
                raise Stall(f"DP rollout: no action keeps the car moving at s = {c.s[tb.nodes[j]]:.1f} m")
            q, _, _ = tb.propagate(q, tb.nodes[j], tb.nodes[j + 1], tb.actions[b])
            if not cmds or cmds[-1][3] != b or tb.actions[b][2]:
                cmds.append((float(c.s[tb.nodes[j]]), tb.actions[b][3], _value(tb.actions[b]), b))
            state = (b, k2, d2)
        return [(s, m, v) for s, m, v, _ in cmds]


class _FreeDP:
    """The brute-force DP: state V only (no switching limits)."""

    def __init__(self, tables: _Tables):
        self.tb = tables

    def solve(self, lam: float):
        tb = self.tb
        J = np.zeros(len(tb.grid[0]))
        self.cont = [None] * tb.M
        for j in range(tb.M - 1, -1, -1):
            stage = tb.cost_e[j] + lam * tb.dt[j]
            cont = stage + _interp(tb.v_next[j], tb.grid[j + 1], J)   # (A, nV)
            self.cont[j] = cont
            J = np.min(cont, axis=0)

    def rollout(self, lam: float):
        """As _SwitchDP.rollout, without switching limits."""
        tb = self.tb
        c = tb.course
        q = 0.0
        cmds = []
        for j in range(tb.M):
            v = math.sqrt(max(q, 0.0))
            vals = [float(_interp(v, tb.grid[j], self.cont[j][b])) for b in range(len(tb.actions))]
            b = int(np.argmin(vals))
            if not math.isfinite(vals[b]):
                raise Stall(f"DP rollout: no action keeps the car moving at s = {c.s[tb.nodes[j]]:.1f} m")
            act = tb.actions[b]
            q, _, _ = tb.propagate(q, tb.nodes[j], tb.nodes[j + 1], act)
            if not cmds or cmds[-1][3] != b or act[2]:
                cmds.append((float(c.s[tb.nodes[j]]), act[3], _value(act), b))
        return [(s, m, v) for s, m, v, _ in cmds]


def _value(act):
    kind, u, hold, mode = act
    return None if hold or mode == Mode.VB else u


def _merge_holds(cmds):
    """Consecutive C commands hold the same speed: keep the first."""
    out = []
    for cmd in cmds:
        if out and cmd[1] == Mode.C and out[-1][1] == Mode.C:
            continue
        out.append(cmd)
    return out


def _search_lambda(dp, course: Course, span: Span, tol: float):
    """Bisection on log lambda until the rolled-out running times bracket the schedule within
    2 % of lambda; returns the two bracketing (lambda, commands, trace)."""

    def attempt(lam):
        dp.solve(lam)
        try:
            cmds = _merge_holds(dp.rollout(lam))
            return lam, cmds, _run_commands(course, cmds)
        except Stall:                       # a very cheap time stalls the rolled-out plan
            return lam, None, _Stalled()

    lo = attempt(1.0)                     # lambda [W]: 1 W per second saved, nearly free time
    hi = attempt(1e6)
    k = 0
    while lo[2].t[-1] < span.schedule and k < 6:
        lo = attempt(lo[0] / 100.0)
        k += 1
    k = 0
    while hi[2].t[-1] > span.schedule and k < 6:
        hi = attempt(hi[0] * 100.0)
        k += 1
    if hi[2].t[-1] > span.schedule + tol:
        raise ValueError(f"the DP cannot meet span.schedule = {span.schedule:.2f} s "
                         f"(fastest DP plan {hi[2].t[-1]:.2f} s)")
    while hi[0] / lo[0] > 1.02:
        mid = attempt(math.sqrt(lo[0] * hi[0]))
        if mid[2].t[-1] > span.schedule:
            lo = mid
        else:
            hi = mid
    return lo, hi


class _Stalled:
    """Stands for the trace of a plan that stalls: infinitely slow."""
    t = (math.inf,)


def _retime(course: Course, span: Span, cmds, tol: float):
    """Plans meeting the schedule within tol, each by moving one switching point of ``cmds``
    that ends traction or starts a coast (brentq on the running time, the simulator); [] if no
    such single switch can."""
    out = []
    for k in range(1, len(cmds)):
        if not (cmds[k][1] == Mode.VB or cmds[k - 1][1] in (Mode.TG, Mode.C)):
            continue            # only the ends of traction / starts of coasting
        left = cmds[k - 1][0]
        right = cmds[k + 1][0] if k + 1 < len(cmds) else span.stop

        def excess(x, k=k):
            trial = list(cmds)
            trial[k] = (x,) + tuple(cmds[k][1:])
            try:
                return _run_commands(course, trial).t[-1] - span.schedule
            except Stall:
                return math.inf

        bracket = _bracket(excess, cmds[k][0], left + 1e-6, right - 1e-6, course.h)
        if bracket is None:
            continue
        x = _root_within(excess, *bracket, tol)
        if abs(excess(x)) <= tol:
            fixed = list(cmds)
            fixed[k] = (x,) + tuple(cmds[k][1:])
            out.append(fixed)
    return out


def _bracket(fun, x0: float, a: float, b: float, h: float):
    """[x, y] around x0 within [a, b] where fun changes sign (both finite), searching either
    way from x0 by doubling steps from h; None if there is none."""
    f0 = fun(x0)
    if not math.isfinite(f0):
        return None
    for direction in (-1.0, 1.0):
        x, fx, d = x0, f0, h
        while True:
            y = min(max(x + direction * d, a), b)
            if y == x:
                break
            fy = fun(y)
            if not math.isfinite(fy):
                break
            if np.sign(fy) != np.sign(fx):
                return (min(x, y), max(x, y))
            x, fx, d = y, fy, 2.0 * d
    return None


def _finish(course, span, lo, hi, tol, method):
    """Of the bracketing plans, each retimed to the schedule by every single switch that can,
    the one with the least energy."""
    car = course.car
    best = None
    for lam, cmds, trace in (lo, hi):
        if cmds is None:
            continue
        candidates = [cmds] if abs(trace.t[-1] - span.schedule) <= tol else _retime(course, span, cmds, tol)
        for fixed in candidates:
            plan = _plan_from(_run_commands(course, fixed), car, method, lagrange=lam,
                              commands=tuple(fixed))
            if best is None or plan.energy_kwh < best.energy_kwh:
                best = plan
    if best is None:
        raise ValueError(f"{method}: no single switching point of the bracketing plans meets "
                         f"span.schedule = {span.schedule:.2f} s within {tol} s")
    return best


def dp_plan(span: Span, car: CarTraction, *, stage: float = 25.0, n_speeds: int = 121,
            max_tractions: int = 2, min_stages: int = 2, step: float = 5.0, tol: float = 0.01,
            course: Course | None = None) -> Plan:
    """Sidorenko's (1997) DP: modes TG/VB/RK switched at stage boundaries ``stage`` [m] apart, at
    most ``max_tractions`` traction applications (Sidorenko's K), a mode held for at least
    ``min_stages`` stages (Sidorenko's tau_min as a distance), the speed on ``n_speeds`` points per
    stage. Returns the plan meeting span.schedule within ``tol`` [s]."""
    course = course or Course(span, car, step)
    _check_schedule(span, run(course, 0.0, 0.0, 0.0, _flat_out).t[-1], tol)
    if max_tractions < 1:
        raise ValueError(f"max_tractions must be >= 1, got {max_tractions}")
    stride = max(1, int(round(stage / course.h)))
    dp = _SwitchDP(_Tables(course, stride, n_speeds, SEED004_ACTIONS), max_tractions, min_stages)
    lo, hi = _search_lambda(dp, course, span, tol)
    return _finish(course, span, lo, hi, tol, f"DP (K = {max_tractions}, {stage:g} m stages)")


def brute_force(span: Span, car: CarTraction, *, n_speeds: int = 401, stride: int = 1,
                step: float = 5.0, tol: float = 0.01, course: Course | None = None) -> Plan:
    """The brute-force optimum: DP over speed only on every grid step with BRUTE_ACTIONS
    (full/half traction, holding, coasting, full/half regen) and ``n_speeds`` speeds per stage.
    Returns the retimed plan; compare two grid sizes to see how far it is from converged."""
    course = course or Course(span, car, step)
    _check_schedule(span, run(course, 0.0, 0.0, 0.0, _flat_out).t[-1], tol)
    dp = _FreeDP(_Tables(course, stride, n_speeds, BRUTE_ACTIONS))
    lo, hi = _search_lambda(dp, course, span, tol)
    return _finish(course, span, lo, hi, tol, f"brute force ({n_speeds} speeds, {course.h * stride:g} m)")
