"""The ATO re-planner's car and its motion on the coarse grid (models/ato/planner.py): the
PlanCar (a CarTraction's characteristics with the mass and resistance of one re-plan; the
controller's blend_estimates gives that mass and resistance), one RK2
step of q = V^2 in distance under a force law, a coasting step with the co-state p, the forces
that hold a bound, and the run trace. Plain scalar Python: the re-planner calls these ~10^4
times per re-plan.

Units: s [m], V [m/s], q [m^2/s^2], t [s], force [N], mass [t], grade [permille].
"""
from __future__ import annotations

import math
from bisect import bisect_right

from models.planning.span import CarTraction
from models.plant.dynamics import acceleration_gain, specific_force_eq2
from models.units import G

K_TG, K_COAST, K_BRAKE = 0, 1, 2      # free-step force laws: full traction, coast, service brake


class PlanCar:
    """The car for one re-plan: the characteristics of a CarTraction (traction, regenerative and
    total brake limits, adhesion, efficiencies) with the mass [t] and resistance A0..A2 the
    re-plan is made for. The planned braking curves assume ``brake_mass`` [t] (default: mass):
    the controller plans them for the heavier of the identified and the configured mass, so an
    identified mass that is too low cannot make them too late. Scalar methods with the
    constants bound once (the planner's loops call them ~10^4 times per re-plan); the
    arithmetic is CarTraction's (tests compare them)."""

    __slots__ = ("mass", "brake_mass", "inv_pg_brake", "A0", "A1", "A2", "pg", "inv_pg", "m_in",
                 "k_acc", "f_force", "f_power", "k_adh", "frac", "r_force", "r_power", "v_fade",
                 "b_total", "share", "eta_f", "eta", "car")

    def __init__(self, car: CarTraction, mass: float, A0: float, A1: float, A2: float,
                 brake_share: float = 1.0, brake_mass: float | None = None):
        self.car = car
        self.mass, self.A0, self.A1, self.A2 = mass, A0, A1, A2
        self.brake_mass = mass if brake_mass is None else brake_mass
        self.inv_pg_brake = 1.0 / (self.brake_mass * G)
        self.pg = mass * G                                   # weight [kN]
        self.inv_pg = 1.0 / self.pg
        self.m_in = 1000.0 * mass * (1.0 + car.gamma)        # inertial mass [kg]
        self.k_acc = acceleration_gain(car.gamma)            # [m/s^2 per N/kN]
        self.f_force, self.f_power = car.traction_force_max, car.traction_power_max
        self.k_adh = 1000.0 * mass * car.adhesion_mass_fraction * G * car.adhesion_factor
        self.frac = car.adhesion_mass_fraction
        self.r_force, self.r_power = car.regen_force_max, car.regen_power_max
        self.v_fade = car.regen_fade_speed
        self.b_total = car.brake_force_max
        self.share = brake_share
        self.eta_f, self.eta = car.eta_f, car.eta

    def adhesion(self, v: float) -> float:
        """Adhesion limit on the driven axles [N] (models.plant.dynamics.adhesion_coefficient's
        Curtius-Kniffler psi_k, V in km/h)."""
        return self.k_adh * (0.161 + 7.5 / (abs(v) * 3.6 + 44.0))

    def f_max(self, v: float) -> float:
        """Traction limit [N]: constant force, constant power, adhesion."""
        f = self.f_force
        if v > 0.0 and self.f_power / v < f:
            f = self.f_power / v
        a = self.adhesion(v)
        return a if a < f else f

    def r_full(self, v: float) -> float:
        """Regenerative brake limit [N] without its fade (used above v_fade only)."""
        r = self.r_force
        if v > 0.0 and self.r_power / v < r:
            r = self.r_power / v
        a = self.adhesion(v)
        return a if a < r else r

    def b_service(self, v: float) -> float:
        """The planned braking force [N]: brake_share of the regenerative brake, within the
        total brake limit (models.plant.dynamics.brake_force_limit)."""
        r = self.r_full(v)
        lim = self.adhesion(v) / self.frac
        lim = lim if lim < self.b_total else self.b_total
        return self.share * (r if r < lim else lim)

    def w0(self, v: float) -> float:
        """Specific main resistance [N/kN], eq. (1) in Horner form (as ``accel``: bit-identical ATO results)."""
        return self.A0 + v * (self.A1 + self.A2 * v)

    def w_slope(self, v: float) -> float:
        """W'(V) = d(resistance force)/dV [N s/m]."""
        return self.pg * (self.A1 + 2.0 * self.A2 * v)

    def hold_regen_speed(self, v_c: float) -> float:
        """V_r: V_r^2 W'(V_r) = V_c^2 W'(V_c) / (eta eta_f) (CarTraction.hold_speed_regen's
        condition, for this re-plan's resistance); inf if there is no such speed."""
        e = self.eta * self.eta_f
        a1, a2 = self.A1, self.A2
        slope = a1 + 2.0 * a2 * v_c
        if e <= 0.0 or slope <= 0.0:
            return math.inf
        target = v_c * v_c * slope / e
        if a2 <= 0.0:
            return math.sqrt(target / a1) if a1 > 0.0 else math.inf
        v = max(v_c, (target / (2.0 * a2)) ** (1.0 / 3.0))
        for _ in range(50):
            fv = v * v * (a1 + 2.0 * a2 * v) - target
            dv = fv / (2.0 * v * a1 + 6.0 * a2 * v * v)
            v -= dv
            if abs(dv) <= 1e-12 * v:
                break
        return v


def accel(car: PlanCar, v: float, g: float, kind: int) -> float:
    """dV/dt [m/s^2] under a force law: eq. (2) with the re-plan's mass and resistance."""
    # eq. (1)-(2) in this order, not models.plant.dynamics': keeps the ATO's results bit-identical
    w = car.A0 + v * (car.A1 + car.A2 * v) + g
    if kind == K_TG:
        return car.k_acc * (car.f_max(v) * car.inv_pg - w)
    if kind == K_BRAKE:
        return car.k_acc * (-car.b_service(v) * car.inv_pg_brake - w)
    return -car.k_acc * w


def free_step(car: PlanCar, q0: float, h: float, g: float, kind: int):
    """RK2 (midpoint) in distance of q = V^2 over h [m] (h < 0 integrates backward).
    Returns (q1, v_mid)."""
    v0 = math.sqrt(q0) if q0 > 0.0 else 0.0
    qm = q0 + h * accel(car, v0, g, kind)          # dq/ds = 2 a: half a step is h a
    vm = math.sqrt(qm) if qm > 0.0 else 0.0
    return q0 + 2.0 * h * accel(car, vm, g, kind), vm


def coast_step(car: PlanCar, q0: float, p0: float, h: float, g: float, k_lam: float):
    """A coasting step of (q, p): p by dp/ds = (W'(V) p - k_lam / V^2) / (m V), k_lam =
    V_c^2 W'(V_c) (the co-state equation on a coast, models/planning/trajectory.py). Returns (q1, p1)."""
    # eq. (2) inlined, not models.plant.dynamics': the innermost loop, where calling it costs +17 % per re-plan
    a0c, a1, a2, k, m, pg = car.A0 + g, car.A1, car.A2, car.k_acc, car.m_in, car.pg
    v0 = math.sqrt(q0) if q0 > 0.0 else 0.0
    qm = q0 - h * k * (a0c + v0 * (a1 + a2 * v0))
    pm = p0 + 0.5 * h * (pg * (a1 + 2.0 * a2 * v0) * p0 - k_lam / q0) / (m * v0) if v0 > 0.0 else p0
    vm = math.sqrt(qm) if qm > 0.0 else 0.0
    q1 = q0 - 2.0 * h * k * (a0c + vm * (a1 + a2 * vm))
    p1 = p0 + h * (pg * (a1 + 2.0 * a2 * vm) * pm - k_lam / qm) / (m * vm) if vm > 0.0 else pm
    return q1, p1


def hold_forces(car: PlanCar, q0: float, q1: float, h: float, g: float):
    """Forces (F, R, M) [N] that take q0 to q1 over h at constant acceleration (eq. (2) at the
    mean speed): traction if the net force is positive, else the regenerative brake up to its
    limit and the mechanical brake for the rest. Also whether traction suffices."""
    vm = 0.5 * ((math.sqrt(q0) if q0 > 0 else 0.0) + (math.sqrt(q1) if q1 > 0 else 0.0))
    net = car.pg * specific_force_eq2((q1 - q0) / (2.0 * h), car.w0(vm), g, car.k_acc)
    if net >= 0.0:
        return net, 0.0, 0.0, net <= car.f_max(vm)
    b = -net
    r = car.r_full(vm) if vm >= car.v_fade else 0.0
    r = b if b < r else r
    return 0.0, r, b - r, True


def step_time(h: float, q0: float, q1: float) -> float:
    v = (math.sqrt(q0) if q0 > 0 else 0.0) + (math.sqrt(q1) if q1 > 0 else 0.0)
    return 2.0 * h / v if v > 0.0 else math.inf


class Trace:
    """A run under construction: nodes s, q, t; per segment the mode and works [J]."""
    __slots__ = ("s", "q", "t", "mode", "wF", "wR")

    def __init__(self, s, q, t):
        self.s, self.q, self.t = [s], [q], [t]
        self.mode, self.wF, self.wR = [], [], []

    def add(self, s, q, dt, mode, wF=0.0, wR=0.0):
        self.s.append(s), self.q.append(q), self.t.append(self.t[-1] + dt)
        self.mode.append(mode), self.wF.append(wF), self.wR.append(wR)

    def cut_at(self, x: float) -> "Trace":
        """The prefix up to x, with a node at x interpolated in its segment (q, t linear)."""
        k = bisect_right(self.s, x) - 1
        k = max(0, min(k, len(self.s) - 1))
        out = Trace(self.s[0], self.q[0], self.t[0])
        out.s, out.q, out.t = self.s[:k + 1], self.q[:k + 1], self.t[:k + 1]
        out.mode, out.wF, out.wR = self.mode[:k], self.wF[:k], self.wR[:k]
        if x > self.s[k] + 1e-9 and k + 1 < len(self.s):
            w = (x - self.s[k]) / (self.s[k + 1] - self.s[k])
            out.s.append(x)
            out.q.append(self.q[k] + w * (self.q[k + 1] - self.q[k]))
            out.t.append(self.t[k] + w * (self.t[k + 1] - self.t[k]))
            out.mode.append(self.mode[k])
            out.wF.append(w * self.wF[k]), out.wR.append(w * self.wR[k])
        return out


def q_at(tr: Trace, x: float) -> float:
    """q on trace ``tr`` at x (linear in its segment, as Trace.cut_at)."""
    k = bisect_right(tr.s, x) - 1
    k = max(0, min(k, len(tr.s) - 1))
    if x > tr.s[k] + 1e-9 and k + 1 < len(tr.s):
        return tr.q[k] + (x - tr.s[k]) / (tr.s[k + 1] - tr.s[k]) * (tr.q[k + 1] - tr.q[k])
    return tr.q[k]


def resistance_margins(a0: float, a1: float, a2: float, v_lo: float, v_hi: float):
    """What the re-planner needs of a resistance w0(V) = a0 + a1 V + a2 V^2 [N/kN]: its slope at
    v_lo and at v_hi [m/s] (rising: V_r and the co-state equation divide by it) and its mean
    over [0, v_hi] (positive where the car cruises). Each must be > 0."""
    return (a1 + 2.0 * a2 * v_lo, a1 + 2.0 * a2 * v_hi,
            a0 + 0.5 * v_hi * (a1 + 0.5 * a2 * v_hi))


def _w0_variance(stated, v: float) -> float:
    """[1 V V^2] C [1 V V^2]^T: the variance of w0(V) [(N/kN)^2] from the stated stds and
    covariances (est.A0_std, est.A1_std, est.A2_std, est.cov_A0_A1, est.cov_A0_A2, est.cov_A1_A2)."""
    s0, s1, s2, c01, c02, c12 = stated
    v2 = v * v
    var = (s0 * s0 + v2 * s1 * s1 + v2 * v2 * s2 * s2
           + 2.0 * (v * c01 + v2 * c02 + v * v2 * c12))
    return var if var > 0.0 else 0.0


def blend_estimates(configured, estimated, stated, ramp: float, config_mass_std: float,
                    config_resistance_std: float, gate: float, speeds, mass_band: float,
                    gate_prev: float = 0.0, gate_step: float = math.inf):
    """The car the regulator plans with: est.* and the configured car weighed by their
    uncertainties, continuous in every input (no switching between sources: a drifting
    estimate moves the plan's car a little, it never flips it).

    configured, estimated: (mass [t], A0, A1, A2); stated: (est.mass_std, est.A0_std,
    est.A1_std, est.A2_std, est.cov_A0_A1, est.cov_A0_A2, est.cov_A1_A2); ramp in [0, 1] (the
    estimates' share grows with the samples since departure); config_mass_std [t] and
    config_resistance_std [N/kN]: the configured car's own uncertainty; speeds [m/s]: where the
    resistance is compared (the first and last bound the re-planner's speeds).

    - the weights are the inverse-variance ones: w_m = c^2 / (c^2 + est.mass_std^2), w_r the
      same with the variance of w0(V) from the stated covariance, averaged over ``speeds``;
    - a consistency gate multiplies both: d = the largest |w0_est(V) - w0_cfg(V)| over
      sqrt(var_est(V) + c_r^2); weight 1 up to gate - 1 sigmas, 0 from gate on, linear
      between. The mass has no gate of its own (a car far heavier than configured with a
      small est.mass_std is what identification is for); a resistance that is inconsistent
      with its own stated uncertainty says the joint fit is confounded (speed noise), and
      the mass comes from the same fit. The gate factor moves at most ``gate_step`` from
      ``gate_prev`` (the controller's last one): estimates that wander across the gate every
      step (speed noise) would otherwise move the plan's mass by tonnes per step;
    - w_r is then lowered so that the blended resistance keeps at least half of each of the
      configured car's resistance_margins (the re-planner needs them positive), and the
      blended mass is kept within [m_cfg / mass_band, m_cfg x mass_band].

    A negative stated std gives no weight. Returns (mass, A0, A1, A2, w_m, w_r, gate factor,
    d). Pure and scalar."""
    m_c, a0_c, a1_c, a2_c = configured
    m_e, a0_e, a1_e, a2_e = estimated
    sd_m = stated[0]
    res = stated[1:]
    if ramp <= 0.0 or sd_m < 0.0 or res[0] < 0.0 or res[1] < 0.0 or res[2] < 0.0:
        return m_c, a0_c, a1_c, a2_c, 0.0, 0.0, 0.0, math.inf
    var_c = config_resistance_std * config_resistance_std
    var_sum, d = 0.0, 0.0
    for v in speeds:
        var = _w0_variance(res, v)
        var_sum += var
        dw = (a0_e - a0_c) + v * ((a1_e - a1_c) + v * (a2_e - a2_c))
        dv = abs(dw) / math.sqrt(var + var_c)
        d = dv if dv > d else d
    var_e = var_sum / len(speeds)
    g = min(max(gate - d, 0.0), 1.0)
    g = min(max(g, gate_prev - gate_step), gate_prev + gate_step)
    w_r = ramp * g * var_c / (var_c + var_e)
    mc2 = config_mass_std * config_mass_std
    w_m = ramp * g * mc2 / (mc2 + sd_m * sd_m)
    v_lo, v_hi = speeds[0], speeds[-1]
    for f_c, f_e in zip(resistance_margins(a0_c, a1_c, a2_c, v_lo, v_hi),
                        resistance_margins(a0_e, a1_e, a2_e, v_lo, v_hi)):
        if f_c > 0.0 and f_e < 0.5 * f_c:
            w_max = 0.5 * f_c / (f_c - f_e)
            w_r = w_max if w_max < w_r else w_r
    mass = m_c + w_m * (m_e - m_c)
    mass = min(max(mass, m_c / mass_band), m_c * mass_band)
    return (mass, a0_c + w_r * (a0_e - a0_c), a1_c + w_r * (a1_e - a1_c),
            a2_c + w_r * (a2_e - a2_c), w_m, w_r, g, d)


BRAKE_MASS_STEP = 0.5   # [t] the braking mass moves in steps (no new curve per sample)


def heavier_mass(planned: float, est_mass: float, identifying: bool, configured: float,
                 mass_band: float) -> float:
    """[t] the mass to plan with: ``planned`` (the blend's), or ``est_mass`` where the estimator
    is ``identifying`` a heavier car (at most ``mass_band`` x the ``configured`` mass), even
    while the blend gives the estimates no weight: a heavier car needs the earlier brake and
    accelerates slower whichever source is right, and the mass survives speed noise where the
    resistance does not. A car 15 % heavier than configured with its passengers, planned as the
    configured 30 t on a -34 permille stop mark, could not keep its braking curve (45 kN gave
    0.8 instead of 1.2 m/s^2) and ran 9.5 m past under speed noise
    (studies/ato_generated_lines.py, combination, seed 11 span 5)."""
    if identifying and math.isfinite(est_mass) and est_mass > planned:
        return max(planned, min(est_mass, mass_band * configured))
    return planned


def braking_mass(mass: float, configured: float) -> float:
    """[t] the mass the braking curves and the supervision assume: ``mass`` (heavier_mass's), at
    least the ``configured`` car's, rounded up to BRAKE_MASS_STEP above it."""
    if mass <= configured:
        return configured
    return configured + BRAKE_MASS_STEP * math.ceil((mass - configured) / BRAKE_MASS_STEP)
