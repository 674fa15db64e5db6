"""The motion engine of the span planners: the distance grid and envelope, one step of motion,
runs under a policy, and the Plan they produce. The physics and conventions are described in
models/planning/trajectory.py (the public module); this module holds the shared machinery so that the
maximum-principle (models/planning/max_principle.py) and DP (models/planning/dp.py) planners and the
simulator step the car with the same arithmetic.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np
from scipy.optimize import brentq

from models.fpmath import square
from models.plant.dynamics import acceleration, acceleration_gain, main_resistance, specific_force_eq2
from models.planning.span import CarTraction, Span, check_span_for_car

J_PER_KWH = 3.6e6


class Mode(IntEnum):
    """The modes of Meleshin's (2011) Table 2, in decreasing p."""
    TG = 0   # full traction, u_f = 1                         p > 1
    C = 1    # speed holding by traction, 0 < u_f < 1        p = 1
    VB = 2   # coasting                                       eta eta_f < p < 1
    SR = 3   # holding by regenerative brake, 0 < u_r < 1     p = eta eta_f
    RK = 4   # full regenerative braking, u_r = 1             0 < p < eta eta_f
    ST = 5   # holding by regen (u_r = 1) + mechanical brake  p = 0
    TM = 6   # full braking (regen + mechanical)              p < 0


# free-step force laws
K_TRACTION, K_COAST, K_REGEN, K_SERVICE = 0, 1, 2, 3


@dataclass(frozen=True)
class Plan:
    """A run over a span. Node arrays s [m], V [m/s], t [s] (len n); per-segment arrays
    (len n - 1): mode (Mode codes), traction_force, regen_force, mech_force (mean over the
    segment [N]: times the segment length is the work [J]). ``switches``: (s [m], Mode) where
    the mode changes, the first at s = 0. energy_kwh = traction_kwh - regen_kwh, where
    traction_kwh = work of F / eta_f and regen_kwh = eta * work of the regen brake."""
    s: np.ndarray
    V: np.ndarray
    t: np.ndarray
    mode: np.ndarray
    traction_force: np.ndarray
    regen_force: np.ndarray
    mech_force: np.ndarray
    switches: tuple
    energy_kwh: float
    traction_kwh: float
    regen_kwh: float
    running_time_s: float
    method: str = ""
    hold_speed: float = math.nan        # V_c [m/s] (maximum-principle plans)
    lagrange: float = math.nan          # lambda [W] (maximum principle, DP)
    commands: tuple = ()                # (s, Mode, value) the simulator re-runs (DP, manual)

    @property
    def traction_applications(self) -> int:
        """Number of times traction (TG or C) is switched on."""
        on = np.isin(self.mode, (Mode.TG, Mode.C))
        return int(on[0]) + int(np.count_nonzero(on[1:] & ~on[:-1]))


class Course:
    """A span prepared for one car: the distance grid, grades per step and the envelope U(s).

    ``step`` [m] is the largest grid step; every grade change (and, for a car of length L, the
    change + L where the averaged grade has a kink) and every limit change is a node.
    """

    def __init__(self, span: Span, car: CarTraction, step: float = 5.0):
        if not (math.isfinite(step) and step > 0):
            raise ValueError(f"step must be > 0, got {step}")
        check_span_for_car(span, car)
        self.span, self.car, self.h = span, car, step
        n = max(1, int(math.ceil(span.stop / step)))
        nodes = set(np.linspace(0.0, span.stop, n + 1).tolist()) | set(span.breakpoints(car.length))
        nodes |= set(self._fade_nodes())
        s = np.array(sorted(nodes))
        keep = np.concatenate(([True], np.diff(s) > 1e-6))
        s = s[keep]
        s[-1] = span.stop
        self.s = s
        self.n = len(s)
        ga, gm, gb = [], [], []
        L = car.length
        for a, b in zip(s[:-1], s[1:]):
            if L > 0:
                ga.append(span.grade.average(a, L))
                gm.append(span.grade.average(0.5 * (a + b), L))
                gb.append(span.grade.average(b, L))
            else:
                g = span.grade.at(0.5 * (a + b))
                ga.append(g), gm.append(g), gb.append(g)
        self.ga, self.gm, self.gb = ga, gm, gb
        self.qlim = np.array([square(span.v_lim_at_node(x)) for x in s])
        self._envelope()

    def _fade_nodes(self) -> list[float]:
        """Where the braking curve to the stop mark passes regen_off_speed and regen_fade_speed
        (backward from rest in 0.01 m steps): grid nodes there put the regen's fade (and the
        electro-pneumatic brake taking over) on step boundaries, so the split of the last metres'
        braking between regen and mechanical brake does not depend on the step."""
        car, span = self.car, self.span
        out, q, x, d = [], 0.0, span.stop, 0.01
        targets = [square(car.regen_off_speed), square(car.regen_fade_speed)]
        while targets and x > d:
            g = span.grade.average(x - 0.5 * d, car.length)
            q1 = max(free_step(car, q, x, x - d, g, g, g, K_SERVICE, 1.0)[0], 0.0)
            while targets and q1 >= targets[0]:
                out.append(x - d * (targets[0] - q) / (q1 - q) if q1 > q else x - d)
                targets.pop(0)
            q, x = q1, x - d
        return [y for y in out if 0.0 < y < span.stop]

    # ----------------------------------------------------------------- grades off the grid
    def grades(self, a: float, b: float, i: int):
        """Grades [permille] at a, (a+b)/2, b for a sub-step inside grid step i."""
        if self.car.length > 0:
            g = self.span.grade.average
            L = self.car.length
            return g(a, L), g(0.5 * (a + b), L), g(b, L)
        return self.ga[i], self.gm[i], self.gb[i]

    def step_index(self, x: float) -> int:
        """Index i of the grid step [s_i, s_i+1) containing x."""
        i = int(np.searchsorted(self.s, x, side="right")) - 1
        return min(max(i, 0), self.n - 2)

    def envelope_at(self, x: float) -> float:
        """U(x)^2 [m^2/s^2], linear between nodes (used to locate crossings)."""
        return float(np.interp(x, self.s, self.qU))

    def _envelope(self):
        """U(s)^2: backward from rest at the stop mark with the service brake, capped by the
        limits (so U holds the braking curves to every lower limit ahead). Raises if U is 0
        inside the span (the brakes cannot keep the car to a limit/the stop on a descent)."""
        car, s = self.car, self.s
        qU = np.empty(self.n)
        qU[-1] = 0.0
        for i in range(self.n - 2, -1, -1):
            a, b = s[i + 1], s[i]
            q_back = free_step(car, qU[i + 1], a, b, self.gb[i], self.gm[i], self.ga[i],
                               K_SERVICE, 1.0)[0]
            qU[i] = min(max(q_back, 0.0), self.qlim[i])
            if qU[i] <= 0.0 and i > 0:
                raise ValueError(f"the span cannot be run: at s = {b:.1f} m (grade {self.gm[i]} "
                                 f"permille) the service brake cannot keep the car within the "
                                 f"speed limit {math.sqrt(self.qlim[i]):.2f} m/s / stop at "
                                 f"span.stop = {self.span.stop} m")
        self.qU = qU


# ===================================================================== one step of motion

def _stage_forces(car: CarTraction, kind: int, u, v):
    if kind == K_TRACTION:
        return u * car.f_max(v), 0.0, 0.0
    if kind == K_REGEN:
        return 0.0, u * car.r_max(v), 0.0
    if kind == K_SERVICE:
        r, m = car.service_brake(v)
        return 0.0, r, m
    return 0.0, 0.0, 0.0


def free_step(car: CarTraction, q0, a: float, b: float, ga: float, gm: float, gb: float,
              kind: int, u=1.0, p0=None, lam: float = 0.0):
    """RK4 over [a, b] (b < a integrates backward) of q = V^2 under a force law.

    ``q0`` a float or an array (the same arithmetic). Returns (q1, work_F, work_R, work_M [J],
    p1): the works by Simpson's rule on the stages; p1 the co-state p integrated alongside for
    a coasting step when p0 is given (else None).
    """
    arr = isinstance(q0, np.ndarray)
    sqrt = np.sqrt if arr else math.sqrt
    mx = np.maximum if arr else max
    h = b - a
    veh = car.vehicle
    coast_p = p0 is not None
    if coast_p:
        wprime = car.weight_kn * car.A1, car.weight_kn * 2.0 * car.A2   # W'(V) = c1 + c2 V [N s/m]
        m = car.inertial_mass_kg
        lam_f = car.eta_f * lam

    if kind == K_COAST:     # no force: the same arithmetic with F = R = M = 0, fewer calls
        v1 = sqrt(mx(q0, 0.0))
        k1 = 2.0 * acceleration(v1, 0.0, 0.0, ga, 0.0, veh)
        v2 = sqrt(mx(q0 + 0.5 * h * k1, 0.0))
        k2 = 2.0 * acceleration(v2, 0.0, 0.0, gm, 0.0, veh)
        v3 = sqrt(mx(q0 + 0.5 * h * k2, 0.0))
        k3 = 2.0 * acceleration(v3, 0.0, 0.0, gm, 0.0, veh)
        v4 = sqrt(mx(q0 + h * k3, 0.0))
        k4 = 2.0 * acceleration(v4, 0.0, 0.0, gb, 0.0, veh)
        q1 = q0 + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        wF = wR = wM = 0.0 * q0
    else:
        def deriv(q, g):
            v = sqrt(mx(q, 0.0))
            F, R, M = _stage_forces(car, kind, u, v)
            return 2.0 * acceleration(v, F, R + M, g, 0.0, veh), F, R, M, v

        k1, F1, R1, M1, v1 = deriv(q0, ga)
        k2, F2, R2, M2, v2 = deriv(q0 + 0.5 * h * k1, gm)
        k3, F3, R3, M3, v3 = deriv(q0 + 0.5 * h * k2, gm)
        k4, F4, R4, M4, v4 = deriv(q0 + h * k3, gb)
        q1 = q0 + h / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        wF = h / 6.0 * (F1 + 2.0 * F2 + 2.0 * F3 + F4)
        wR = h / 6.0 * (R1 + 2.0 * R2 + 2.0 * R3 + R4)
        wM = h / 6.0 * (M1 + 2.0 * M2 + 2.0 * M3 + M4)
    p1 = None
    if coast_p:
        def dp(p, v):
            v = mx(v, 1e-3)      # a coast reaching rest stalls (the caller's Stall); keep finite
            return (p * (wprime[0] + wprime[1] * v) - lam_f / (v * v)) / (m * v)
        j1 = dp(p0, v1)
        j2 = dp(p0 + 0.5 * h * j1, v2)
        j3 = dp(p0 + 0.5 * h * j2, v3)
        j4 = dp(p0 + h * j3, v4)
        p1 = p0 + h / 6.0 * (j1 + 2.0 * j2 + 2.0 * j3 + j4)
    return q1, wF, wR, wM, p1


def _allocate(car: CarTraction, q0, qt, h: float, gm: float):
    """Forces [N] (F, R, M) that take q0 to qt over h at constant acceleration: the net force
    from eq. (2) at the mean speed, given to traction if positive, else to the regenerative
    brake up to r_max and the rest to the mechanical brake. Also returns whether traction
    suffices (F <= f_max)."""
    arr = isinstance(q0, np.ndarray)
    sqrt = np.sqrt if arr else math.sqrt
    mn, mx = (np.minimum, np.maximum) if arr else (min, max)
    vm = 0.5 * (sqrt(mx(q0, 0.0)) + sqrt(mx(qt, 0.0)))
    a_req = (qt - q0) / (2.0 * h)                                  # dV/dt [m/s^2]
    net = car.weight_kn * specific_force_eq2(a_req, main_resistance(vm, 0.0, car.vehicle), gm,
                                             acceleration_gain(car.gamma))   # F - B [N], eq. (2)
    F = mx(net, 0.0)
    B = mx(-net, 0.0)
    R = mn(B, car.r_max(vm))
    M = B - R
    return F, R, M, F <= car.f_max(vm), vm


def _free_mode(kind: int, u) -> Mode:
    if kind == K_TRACTION:
        return Mode.TG if u == 1.0 else Mode.C
    if kind == K_COAST:
        return Mode.VB
    return Mode.RK if u == 1.0 else Mode.SR


def step(car: CarTraction, q0, a: float, b: float, grades, kind: int, u, q_floor, q_ceil,
         p0=None, lam: float = 0.0, floor_a=None, ceil_a=None):
    """One step [a, b] of a run: free motion under ``kind`` (u), bounded above by the ceiling
    (q_ceil at b, ceil_a at a, linear between) and below by the floor (likewise).

    If the free motion ends beyond a bound, the step is split where it crosses it (linear
    interpolation of q - bound, so the energy of the step is right to second order): free
    motion up to there, then along the bound with the forces of ``_allocate``. If a floor needs
    more than f_max, the whole step is full traction instead (a climb the car cannot hold).
    Returns (q1, dt, wF, wR, wM, mode, p1, capped); q0 a float or an array (the same
    arithmetic element by element; the array path is for the DP's tables).
    """
    ceil_a = q_ceil if ceil_a is None else ceil_a
    floor_a = q_floor if floor_a is None else floor_a
    ga, gm, gb = grades
    h = b - a
    q1, wF, wR, wM, p1 = free_step(car, q0, a, b, ga, gm, gb, kind, u, p0, lam)
    if isinstance(q0, np.ndarray):
        return _step_array(car, q0, a, b, grades, kind, u, q_floor, q_ceil, floor_a, ceil_a,
                           q1, wF, wR, wM, p1)
    free_mode = _free_mode(kind, u) if kind != K_SERVICE else (Mode.TM if wM > 0 else Mode.RK)
    over = q1 > q_ceil
    if not over and not q1 < q_floor:
        v0, v1 = math.sqrt(max(q0, 0.0)), math.sqrt(max(q1, 0.0))
        return q1, (2.0 * h / (v0 + v1) if v0 + v1 > 0 else math.inf), wF, wR, wM, free_mode, p1, False
    bound_a, bound_b = (ceil_a, q_ceil) if over else (floor_a, q_floor)
    g0, g1 = q0 - bound_a, q1 - bound_b
    w = g0 / (g0 - g1) if g0 != g1 else 0.0
    w = min(max(w, 0.0), 1.0)
    sx = a + w * h
    v0 = math.sqrt(max(q0, 0.0))
    if w > 0.0:
        qx = bound_a + w * (bound_b - bound_a)
        _, wF1, wR1, wM1, _ = free_step(car, q0, a, sx, ga, ga + 0.5 * w * (gb - ga),
                                        ga + w * (gb - ga), kind, u)
        vx = math.sqrt(max(qx, 0.0))
        dt1 = 2.0 * (sx - a) / (v0 + vx) if v0 + vx > 0 else math.inf
    else:
        qx, wF1, wR1, wM1, vx, dt1 = q0, 0.0, 0.0, 0.0, v0, 0.0
    rest = b - sx
    if rest > 1e-12 * h:
        F, R, M, ok, _ = _allocate(car, qx, bound_b, rest, ga + 0.5 * (1.0 + w) * (gb - ga))
    else:
        F = R = M = 0.0
        ok = True
    if not (ok or over):
        if kind == K_TRACTION:
            v1 = math.sqrt(max(q1, 0.0))
            return q1, (2.0 * h / (v0 + v1) if v0 + v1 > 0 else math.inf), wF, wR, wM, free_mode, p1, False
        q1, wF, wR, wM, _ = free_step(car, q0, a, b, ga, gm, gb, K_TRACTION, 1.0)
        v1 = math.sqrt(max(q1, 0.0))
        return q1, (2.0 * h / (v0 + v1) if v0 + v1 > 0 else math.inf), wF, wR, wM, Mode.TG, p1, False
    v1 = math.sqrt(max(bound_b, 0.0))
    dt = dt1 + (2.0 * rest / (vx + v1) if rest > 0 else 0.0)
    decel = bound_b < qx * (1.0 - 1e-9)
    if F > 0:
        mode = Mode.TG if F >= car.f_max(v1) else Mode.C
    elif M > 0:
        mode = Mode.TM if decel else Mode.ST
    else:
        mode = Mode.RK if decel else Mode.SR
    return bound_b, dt, wF1 + F * rest, wR1 + R * rest, wM1 + M * rest, mode, p1, True


def _step_array(car, q0, a, b, grades, kind, u, q_floor, q_ceil, floor_a, ceil_a,
                q1, wF, wR, wM, p1):
    """``step`` for an array q0: the scalar path's arithmetic, branches by np.where."""
    ga, gm, gb = grades
    h = b - a
    shape = np.shape(q0)
    q_ceil, ceil_a = np.broadcast_to(q_ceil, shape), np.broadcast_to(ceil_a, shape)
    q_floor, floor_a = np.broadcast_to(q_floor, shape), np.broadcast_to(floor_a, shape)
    over = q1 > q_ceil
    under = ~over & (q1 < q_floor)
    bound_a = np.where(over, ceil_a, floor_a)
    bound_b = np.where(over, q_ceil, q_floor)
    g0, g1 = q0 - bound_a, q1 - bound_b
    with np.errstate(invalid="ignore", divide="ignore"):
        w = np.where(g0 != g1, g0 / np.where(g0 != g1, g0 - g1, 1.0), 0.0)
    w = np.minimum(np.maximum(w, 0.0), 1.0)
    w = np.where(over | under, w, 0.0)
    sx = a + w * h
    v0 = np.sqrt(np.maximum(q0, 0.0))
    with np.errstate(invalid="ignore"):
        qx = np.where(w > 0.0, bound_a + w * (bound_b - bound_a), q0)
    _, wF1, wR1, wM1, _ = free_step(car, q0, a, sx, ga, ga + 0.5 * w * (gb - ga),
                                    ga + w * (gb - ga), kind, u)
    vx = np.sqrt(np.maximum(qx, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        dt1 = np.where(w > 0.0, np.where(v0 + vx > 0, 2.0 * (sx - a) / np.where(v0 + vx > 0, v0 + vx, 1.0), np.inf), 0.0)
        wF1, wR1, wM1 = (np.where(w > 0.0, x, 0.0) for x in (wF1, wR1, wM1))
        rest = b - sx
        has_rest = rest > 1e-12 * h
        F, R, M, ok, _ = _allocate(car, qx, bound_b, np.where(has_rest, rest, 1.0),
                                   ga + 0.5 * (1.0 + w) * (gb - ga))
    F, R, M = (np.where(has_rest, x, 0.0) for x in (F, R, M))
    ok = ok | ~has_rest
    clamp = over | (under & ok)
    tg = under & ~ok & (kind != K_TRACTION)
    if kind == K_SERVICE:
        fmode = np.where(wM > 0, int(Mode.TM), int(Mode.RK))
    else:
        fmode = np.full(shape, int(_free_mode(kind, u)))
    if np.any(tg):
        qtg, wFt, wRt, wMt, _ = free_step(car, q0, a, b, ga, gm, gb, K_TRACTION, 1.0)
        q1, wF, wR, wM = (np.where(tg, x, y) for x, y in ((qtg, q1), (wFt, wF), (wRt, wR), (wMt, wM)))
        fmode = np.where(tg, int(Mode.TG), fmode)
    v1c = np.sqrt(np.maximum(bound_b, 0.0))
    decel = bound_b < qx * (1.0 - 1e-9)
    cmode = np.where(F > 0, np.where(F >= car.f_max(v1c), int(Mode.TG), int(Mode.C)),
                     np.where(M > 0, np.where(decel, int(Mode.TM), int(Mode.ST)),
                              np.where(decel, int(Mode.RK), int(Mode.SR))))
    v1f = np.sqrt(np.maximum(q1, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        dt_free = np.where(v0 + v1f > 0, 2.0 * h / np.where(v0 + v1f > 0, v0 + v1f, 1.0), np.inf)
        dt_clamp = dt1 + np.where(rest > 0, 2.0 * rest / np.where(vx + v1c > 0, vx + v1c, 1.0), 0.0)
    q_out = np.where(clamp, bound_b, q1)
    return (q_out, np.where(clamp, dt_clamp, dt_free), np.where(clamp, wF1 + F * rest, wF),
            np.where(clamp, wR1 + R * rest, wR), np.where(clamp, wM1 + M * rest, wM),
            np.where(clamp, cmode, fmode).astype(np.int8), p1, clamp)


# ===================================================================== runs on the grid

@dataclass
class _Trace:
    """A run under construction: node lists and per-segment lists."""
    s: list = field(default_factory=list)
    q: list = field(default_factory=list)
    t: list = field(default_factory=list)
    mode: list = field(default_factory=list)
    wF: list = field(default_factory=list)
    wR: list = field(default_factory=list)
    wM: list = field(default_factory=list)

    def start(self, s, q, t):
        self.s.append(s), self.q.append(q), self.t.append(t)

    def add(self, s, q, dt, wF, wR, wM, mode):
        self.s.append(s), self.q.append(q), self.t.append(self.t[-1] + dt)
        self.wF.append(wF), self.wR.append(wR), self.wM.append(wM), self.mode.append(int(mode))

    def cut(self, s_end: float) -> "_Trace":
        """The prefix with nodes s <= s_end (a node exactly there included)."""
        k = int(np.searchsorted(np.asarray(self.s), s_end, side="right"))
        return _Trace(self.s[:k], self.q[:k], self.t[:k], self.mode[:k - 1], self.wF[:k - 1],
                      self.wR[:k - 1], self.wM[:k - 1])

    def extend(self, other: "_Trace"):
        """Append ``other``, which starts at this trace's last node."""
        self.s += other.s[1:]
        self.q += other.q[1:]
        self.t += other.t[1:]
        self.mode += other.mode
        self.wF += other.wF
        self.wR += other.wR
        self.wM += other.wM


class Stall(ValueError):
    """The car came to rest before the stop mark."""


def run(course: Course, s0: float, q0: float, t0: float, policy, s_end: float | None = None) -> _Trace:
    """Integrate from (s0, q0, t0) to s_end (default: the stop mark) on the course grid.

    ``policy(s_a, q0) -> (kind, u, q_floor, q_ceil_extra)``: the free force law and the band
    (the envelope U is always a ceiling). Raises Stall if the car stops early.
    """
    car, s, qU = course.car, course.s, course.qU
    s_end = course.span.stop if s_end is None else s_end
    tr = _Trace()
    tr.start(s0, q0, t0)
    a = s0
    i = course.step_index(s0)
    if s[i + 1] <= a and i + 1 < course.n - 1:
        i += 1
    while a < s_end - 1e-9:
        b = min(s[i + 1], s_end)
        qc = qU[i + 1] if b == s[i + 1] else course.envelope_at(b)
        qa = qU[i] if a == s[i] else course.envelope_at(a)
        kind, u, q_floor, q_cap = policy(a, q0)
        q1, dt, wF, wR, wM, mode, _, _ = step(
            car, q0, a, b, course.grades(a, b, i), kind, u, q_floor, min(qc, q_cap),
            ceil_a=min(qa, q_cap))
        if q1 <= 0.0 and b < course.span.stop - 1e-9:
            raise Stall(f"the car stops at s ~ {b:.1f} m before the stop mark "
                        f"({course.span.stop} m): grade there {course.gm[i]} permille")
        tr.add(b, q1, dt, wF, wR, wM, mode)
        a, q0 = b, q1
        i += 1
    return tr


def _plan_from(trace: _Trace, car: CarTraction, method: str, **extra) -> Plan:
    s = np.asarray(trace.s)
    h = np.diff(s)
    wF, wR, wM = (np.asarray(x, dtype=float) for x in (trace.wF, trace.wR, trace.wM))
    mode = np.asarray(trace.mode, dtype=np.int8)
    with np.errstate(invalid="ignore", divide="ignore"):
        F, R, M = (np.where(h > 0, w / np.where(h > 0, h, 1.0), 0.0) for w in (wF, wR, wM))
    traction = float(np.sum(wF)) / car.eta_f / J_PER_KWH
    regen = car.eta * float(np.sum(wR)) / J_PER_KWH
    switches = []
    for k, m in enumerate(mode):
        if not switches or switches[-1][1] != m:
            switches.append((float(s[k]), Mode(int(m))))
    return Plan(s=s, V=np.sqrt(np.maximum(np.asarray(trace.q), 0.0)), t=np.asarray(trace.t),
                mode=mode, traction_force=F, regen_force=R, mech_force=M,
                switches=tuple(switches), energy_kwh=traction - regen, traction_kwh=traction,
                regen_kwh=regen, running_time_s=float(trace.t[-1]), method=method, **extra)


# ===================================================================== commands

_KIND_OF = {Mode.TG: K_TRACTION, Mode.VB: K_COAST, Mode.RK: K_REGEN, Mode.TM: K_SERVICE}


def _check_commands(commands, span):
    cmds = []
    for k, c in enumerate(commands):
        sw, mode = float(c[0]), Mode(c[1])
        val = c[2] if len(c) > 2 else None
        if not (math.isfinite(sw) and 0.0 <= sw <= span.stop):
            raise ValueError(f"commands[{k}]: switching point {sw} m outside [0, {span.stop}]")
        if cmds and sw < cmds[-1][0]:
            raise ValueError(f"commands[{k}]: switching points must not decrease ({sw} after {cmds[-1][0]})")
        if val is not None and mode in (Mode.TG, Mode.RK) and not 0.0 < float(val) <= 1.0:
            raise ValueError(f"commands[{k}]: the share u of {mode.name} must be in (0, 1], got {val}")
        if val is not None and mode in (Mode.C, Mode.SR, Mode.ST) and not 0.0 < float(val) < math.inf:
            raise ValueError(f"commands[{k}]: the speed {mode.name} holds must be > 0 and finite [m/s], "
                             f"got {val}")
        cmds.append((sw, mode, val))
    if not cmds or cmds[0][0] != 0.0:
        raise ValueError("commands: the first switching point must be 0")
    return cmds


def _run_commands(course: Course, cmds) -> _Trace:
    trace = None
    q, t = 0.0, 0.0
    for k, (sw, mode, val) in enumerate(cmds):
        s_next = cmds[k + 1][0] if k + 1 < len(cmds) else course.span.stop
        if s_next <= sw:
            continue
        if mode in (Mode.C, Mode.SR, Mode.ST):
            qh = q if val is None else square(float(val))
            policy = (lambda a, q0, qh=qh: (K_COAST, 0.0, qh, qh))
        else:
            u = 1.0 if val is None or mode == Mode.TM else float(val)
            policy = (lambda a, q0, kind=_KIND_OF[mode], u=u: (kind, u, -math.inf, math.inf))
        seg = run(course, sw, q, t, policy, s_end=s_next)
        if trace is None:
            trace = seg
        else:
            trace.extend(seg)
        q, t = trace.q[-1], trace.t[-1]
    return trace


# ===================================================================== policies and helpers

def _flat_out(a, q0):
    return K_TRACTION, 1.0, -math.inf, math.inf


def _coast(a, q0):
    return K_COAST, 0.0, -math.inf, math.inf


class _Found(Exception):
    def __init__(self, x):
        self.x = x


def _root_within(fun, lo: float, hi: float, tol: float) -> float:
    """brentq on [lo, hi] that stops as soon as |fun(x)| <= tol / 2 (fun in seconds here: a
    running-time residual); returns the best x seen."""
    best = [None, math.inf]

    def f(x):
        y = fun(x)
        if abs(y) < best[1]:
            best[0], best[1] = x, abs(y)
        if abs(y) <= 0.5 * tol:
            raise _Found(x)
        return y

    try:
        f(lo), f(hi)
        brentq(f, lo, hi, xtol=1e-12, rtol=1e-14)
    except _Found as found:
        return found.x
    return best[0]


def _check_schedule(span: Span, t_min: float, tol: float):
    if span.schedule < t_min - tol:
        raise ValueError(f"span.schedule = {span.schedule:.2f} s is infeasible: the minimum-time "
                         f"run takes {t_min:.2f} s")


def _bracket_low(excess, hi: float, h: float):
    """A point below ``hi`` where excess > 0 (scanning down by doubling steps), or None."""
    d = 10.0 * h
    x = hi
    while x > 0.0:
        x = max(0.0, x - d)
        if excess(x) > 0.0:
            return x
        d *= 2.0
    return None
