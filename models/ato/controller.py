"""The automatic train operation (ATO) for one span, closed around the estimator's outputs:
a running-time regulator that re-plans Meleshin's (2011) energy-efficient run, targeted stopping
with Sidorenko's (1997) relay-controlled electro-pneumatic brake, and a speed supervisor.

``AtoController(span, car, tuning)`` is built once per span; each communication step
``demands(t, outputs)`` takes the time [s] and the RailCar (or RailCarEstimator) FMU's outputs
by name and returns an ``AtoCommand``: traction and brake demands [N], the mode code
(``AtoMode``) and the planned speed [m/s]. It holds no loop; a host steps it.

What it reads (and nothing else: not the truth car.*, whose grade it knows from the span):
filter.speed, filter.position, filter.speed_std, filter.position_std (the motion filter),
est.mass, est.A0..A2, est.status, est.samples (the identification).

**Running-time regulator** (Meleshin 2011, ch. 4, uses a fuzzy regulator with predictive traction
calculation; ours is its model-predictive form). Every ``replan_period`` seconds the rest of
the span is re-planned from the filter's speed and position, with the car of
``blend_estimates`` (the identified and the configured mass and resistance weighed by their
uncertainties, continuous: no switching between sources; the estimates' stated uncertainty,
STATED_INPUTS, is read where the host gives it), by models/ato/planner.py: Meleshin's
maximum-principle structure solved for the holding speed V_c that arrives on schedule
(milliseconds; the full synthesis takes seconds), aiming ``time_reserve`` x (time left)^2 /
schedule early while the estimates and the configured car disagree. Between re-plans the
controller executes the plan's *policy*, not its timetable: full traction below V_c, holding
V_c by traction, coasting on a descent up to V_r and holding V_r by the regenerative brake,
coasting from each planned coast point, following the envelope U(s) (limits less a margin and
the braking curves) where the car reaches it. With ``replan=False`` and
``use_estimates=False`` the same policy is planned once from the configured coefficients: the
fixed plan the regulator is measured against. Estimates get weight once est.status is 1 or 2
and est.samples has grown by min_samples since departure (it runs on over station stops, where
the mass identification restarts); braking curves are planned for the heavier of the blended
and the configured mass (an identified mass that is too low must not make them late).

**Targeted stopping**: models/ato/stopping.py (the braking curve, then the relay stages of the
electro-pneumatic brake below 7 km/h at ``ep_deceleration``, then the holding brake). The whole
final braking curve ends at an aim point ``aim_sigma`` x filter.speed_std x (the EP stage's
duration) short of the mark. Under speed-sensor noise the filter's position lags the car by
more than it claims (at 0.444 m/s noise est.mass is ~8 % low and the lag at the stop 0.34 m on
average, sd 0.32 m, while filter.position_std says 0.19 m). So where filter.position_std exceeds
``settle_std`` when the final braking curve starts, the stop is in two parts: a short stop
``settle_sigma`` x filter.position_std short (at most ``settle_aim_max``), ``settle_time``
standing (mode SETTLE) while the filter's distance catches up with the car, then a creep on to
the mark within ``settle_window`` (~11 s in all); else one stop.

**Safety**: bad construction inputs raise ValueError naming the value (an infeasible schedule, a
stop mark beyond the span (models.planning.span.Span), a limit the brakes cannot keep, a limit
the margin leaves nothing of, bad tuning). At run time nothing raises: an output that is missing
or not finite, outside physics or inconsistent with the others (models/ato/supervision.py) gives
a safe brake (``car.brake_force_max`` x ``safe_brake``) with the reason logged (logger
``models.ato.controller`` and ``AtoController.events``), held until the outputs have been sane
for ``RECOVERY_TIME`` (1 s). The supervisor brakes with the full brake whenever filter.speed +
k_sigma filter.speed_std exceeds the supervision curve read at filter.position + k_sigma
filter.position_std: V_lim(s) and the full-brake curves (``mass_reserve`` more mass) to every
lower limit ahead and to 1 m past the stop mark; the controller keeps a ``supervisor_gap`` +
``gap_sigma`` filter.speed_std below it. (A filter wrong by more than k_sigma of its own stds, as
the lagging one above, can still take the car past the line: the controller cannot see that.)

Units: s [m], V [m/s], t [s], force [N], mass [t], grade [permille].
"""
from __future__ import annotations

import logging
import math
import time as _time
from typing import Mapping

# the host's side (inputs, command, modes, tuning) is models/ato/interface.py; also importable from here
from models.ato.interface import INPUTS, STATED_INPUTS, AtoCommand, AtoMode, AtoTuning
from models.ato.motion import PlanCar, blend_estimates, braking_mass, heavier_mass
from models.ato.planner import ReducedPlan, plan_setup
from models.ato.stopping import RelayBrake, track_force
from models.ato.supervision import RECOVERY_TIME, InputSupervisor
from models.fpmath import square
from models.planning.span import CarTraction, Span, check_span_for_car
from models.plant.dynamics import acceleration_gain
from models.units import G

LOG = logging.getLogger(__name__)

MAX_GRID_NODES = 10_000  # the re-planner's grid: ~0.5 s to initialise, a re-plan ~0.05 s, ~8 MB
#                          (measured alone: 0.43 s and 0.05 s; 100 km at the 10 m default)
GATE_RATE = 0.2         # [1/s] the blend's gate factor moves at most this fast (0 to 1 in 5 s)
EST_USABLE = (1, 2)     # est.status: identifying, holding (0 prior only, 3 degraded: not used)
RUN, BRAKE, STOP_EP, SETTLE, HOLD = "run", "brake", "ep", "settle", "hold"


class AtoController:
    """The ATO for one span (module docstring). ``finished``: the car stands at the stop mark."""

    def __init__(self, span: Span, car: CarTraction, tuning: AtoTuning | None = None):
        if not isinstance(span, Span):
            raise ValueError(f"span must be a models.planning.span.Span, got {type(span).__name__}")
        if not isinstance(car, CarTraction):
            raise ValueError(f"car must be a models.planning.span.CarTraction, got {type(car).__name__}")
        tuning = AtoTuning() if tuning is None else tuning
        if not isinstance(tuning, AtoTuning):
            raise ValueError(f"tuning must be an AtoTuning, got {type(tuning).__name__}")
        self.span, self.car, self.tuning = span, car, tuning
        check_span_for_car(span, car)          # a start on the grade, limits the brakes keep
        self._check_grid(span, car, tuning)
        self.course, self.planner, self.configured = plan_setup(span, car, tuning)
        self.a_ep = self.course.a_ep
        qU = self.planner.envelope(self.configured)
        t_min = self.planner.min_time(self.configured, qU)
        if span.schedule < t_min - tuning.time_tol:
            raise ValueError(f"span.schedule = {span.schedule:.2f} s is infeasible: the fastest "
                             f"run the controller plans (limits less {tuning.limit_margin} m/s) "
                             f"takes {t_min:.2f} s")
        # a schedule beyond the slowest run (holding the planner's lowest speed all the way) is
        # refused before planning: 1e20 s left the planner's solve flat at its first guess
        t_slowest = t_min + span.stop / self.planner.v_min
        shown = f"{span.schedule:.2f}" if span.schedule < 1e9 else f"{span.schedule:.6g}"
        if span.schedule > t_slowest:
            raise ValueError(f"span.schedule = {shown} s is too long: even holding "
                             f"{self.planner.v_min:g} m/s over the span.stop = {span.stop:g} m "
                             f"arrives within {t_slowest:.1f} s")
        self._check_ep(span, car, tuning)
        t0 = _time.perf_counter()
        plan = self.planner.plan(self.configured, 0.0, 0.0, 0.0, span.schedule, qU)
        self.replan_seconds = [_time.perf_counter() - t0]
        if plan.status == "early":
            raise ValueError(f"span.schedule = {shown} s is too long: holding "
                             f"{plan.hold_speed:.2f} m/s still arrives after {plan.arrival:.2f} s")
        self.plan: ReducedPlan = plan
        self.initial_plan = plan
        stage_force = car.mech_force_max / tuning.ep_stages
        self.relay = RelayBrake(span.stop, self.a_ep, stage_force, tuning.ep_stages,
                                tuning.relay_hysteresis, tuning.relay_stage_speed,
                                tuning.relay_dwell, tuning.creep_speed, tuning.creep_accel,
                                tuning.stop_window)
        self._final_start = self._final_stretch_start(plan.qU)
        self._sup_q = self._supervision(self.configured.brake_mass)
        self.phase = RUN
        self.t_departure = None
        self._samples0 = 0.0                 # est.samples at departure
        self._last_replan = -math.inf
        self._using_estimates = False
        self._car_now = self.configured
        self._last_key = None
        self.events: list[tuple[float, str]] = []
        self._episodes: set = set()
        self._last_status = "ok"
        self._last_brake = 0.0
        self._stand_since = None
        self.weights = (0.0, 0.0)           # blend_estimates' weights of est.mass, est.A0..A2
        self._gate, self._t_gate = 0.0, None  # its gate factor (rate-limited) and when set [s]
        self._used = False                  # est.* have had weight in this span
        v_lo, v_hi = self.course.v_relay, max(span.limit_speeds)
        self._blend_speeds = (v_lo, 0.5 * (v_lo + v_hi), v_hi)
        self.replans = 0
        self.aim_offset = 0.0
        self._brake_int, self._t_last = 0.0, None
        self._psd = 0.0                     # filter.position_std at this step [m]
        self.supervisor = InputSupervisor(car.mass)
        self._latched = False               # a bad input was seen: the safe brake holds
        self._sane_since = None             # [s] first sane call since (the release timer)
        self._settle = None                 # None: not decided; True: stop short and settle
        self._settle_since = None
        self.settled = False                # the settle stand is over
        self._crept = False                 # ... and the creep after it has begun
        self.first_stop = None              # (t, filter.position) of the first standstill

    # ----------------------------------------------------------------- construction checks
    @staticmethod
    def _check_grid(span: Span, car: CarTraction, tuning: AtoTuning):
        """The re-planner's grid: at most MAX_GRID_NODES nodes (its cost is linear in them)."""
        cells = span.stop / tuning.grid_step
        breaks = len(span.breakpoints(car.length))
        if cells + breaks > MAX_GRID_NODES:
            raise ValueError(
                f"tuning.grid_step = {tuning.grid_step:g} m puts {cells + breaks:.4g} nodes on the "
                f"re-planner's grid to the stop mark (span.stop = {span.stop:g} m, {breaks} grade "
                f"and limit changes); at most {MAX_GRID_NODES} (initialisation ~40 us and a "
                f"re-plan ~5 us per node): make tuning.grid_step >= "
                f"{span.stop / max(MAX_GRID_NODES - breaks, 1):.4g} m or the span shorter")

    @staticmethod
    def _check_ep(span: Span, car: CarTraction, tuning: AtoTuning):
        """The EP stage must be able to give a_ep at the stop mark on its grade."""
        g = span.grade.average(span.stop, car.length)
        need = 1000.0 * car.mass * (1.0 + car.gamma) * tuning.a_ep - car.mass * G * (car.A0 + g)
        if need > car.mech_force_max:
            raise ValueError(f"tuning.a_ep = {tuning.a_ep} m/s^2 needs {need:.0f} N of "
                             f"electro-pneumatic brake at the stop mark, car.mech_force_max is "
                             f"{car.mech_force_max:.0f} N")

    def _final_stretch_start(self, qU) -> float:
        """Where the falling braking curve that ends at the stop mark starts [m]."""
        s = self.course.s
        j = len(qU) - 1
        while j > 0 and qU[j - 1] > qU[j] * (1.0 + 1e-12):
            j -= 1
        return s[j]

    def _supervision(self, mass: float) -> list:
        """The supervision curve's V^2 on the course nodes: V_lim (no margin) and the full-brake
        curves (brake_force_max, no resistance, (1 + mass_reserve) x mass) to every lower limit
        ahead and to 1 m past the stop mark (Sidorenko's (1997) 'never past +1 m' as a hard
        line)."""
        c, car, span = self.course, self.car, self.span
        self._sup_mass = mass
        m = 1000.0 * mass * (1.0 + self.tuning.mass_reserve) * (1.0 + car.gamma)
        s = c.s
        q = [0.0] * c.n
        q_end = 2.0 * (car.brake_force_max / m) * 1.0          # at the stop: 1 m to rest
        q[-1] = q_end
        for i in range(c.n - 2, -1, -1):
            b = min(car.brake_force_max, car.brake_total_max(math.sqrt(q[i + 1])))
            a = b / m - acceleration_gain(car.gamma) * (-c.g[i])    # deceleration [m/s^2], eq. (2)
            qb = q[i + 1] + 2.0 * max(a, 0.0) * (s[i + 1] - s[i])
            q[i] = min(qb, square(span.v_lim_at_node(s[i])))
        return q

    # ----------------------------------------------------------------- helpers
    @property
    def using_estimates(self) -> bool:
        """True while the plan and the feed-forward use est.* (else the configured car)."""
        return self._using_estimates

    @property
    def plan_car(self) -> PlanCar:
        """The car the plan and the feed-forward use now (blend_estimates' result)."""
        return self._car_now

    @property
    def finished(self) -> bool:
        """True once the car stands within tuning.stop_window of the stop mark (or past it)."""
        return self.phase == HOLD

    def _log(self, t: float, reason: str, key: str):
        """Record and log ``reason`` once per episode of ``key`` (a NaN held for 100 steps or a
        supervisor intervention is one event, not 100); _clear(key) ends the episode."""
        if key not in self._episodes:
            self._episodes.add(key)
            self.events.append((t, reason))
            LOG.warning("ATO at t = %.2f s: %s", t, reason)

    def _clear(self, key: str):
        self._episodes.discard(key)

    def _clear_inputs(self):
        if self._episodes:
            self._episodes = {k for k in self._episodes if not k.startswith("input:")}

    def _interp(self, q, x: float) -> tuple[float, float]:
        """q(x) on the course nodes (linear) and its slope dq/ds [m/s^2]."""
        s = self.course.s
        i = self.course.cell(x)
        h = s[i + 1] - s[i]
        slope = (q[i + 1] - q[i]) / h
        w = min(max(x - s[i], 0.0), h)
        return q[i] + w * slope, slope

    def _grade(self, x: float) -> float:
        return self.span.grade.average(x, self.car.length)

    def _bad_input(self, t, reason, name) -> AtoCommand:
        """A bad input: the safe brake, latched (released once the inputs have been sane for
        RECOVERY_TIME), the reason logged once per episode of that input."""
        self._latched, self._sane_since = True, None
        return self._safe(t, reason, "input:" + name)

    def _safe(self, t, reason, key) -> AtoCommand:
        self._log(t, reason, key)
        self.supervisor.note_command(0.0)
        return AtoCommand(0.0, self.tuning.safe_brake * self.car.brake_force_max, int(AtoMode.SAFE),
                          0.0)

    def _estimates_usable(self, est) -> str | None:
        """Why est.* cannot be used at all now, or None (then blend_estimates weighs them)."""
        if int(est[4]) not in EST_USABLE:
            return f"est.status = {int(est[4])}"
        samples = est[5]
        if samples - self._samples0 < self.tuning.min_samples:
            return (f"est.samples = {int(samples)}: {int(samples - self._samples0)} since departure "
                    f"< {self.tuning.min_samples}")
        return None

    # ----------------------------------------------------------------- the step
    def demands(self, t: float, outputs: Mapping[str, float]) -> AtoCommand:
        """The command for the step starting at ``t`` [s] from the outputs at ``t``. Never
        raises: a bad input (missing, not a number, not finite, or refused by the supervisor:
        models/ato/supervision.py) gives the safe brake, with the reason in ``events`` and the
        log (once per episode), until the inputs have been sane for RECOVERY_TIME."""
        try:
            t_in = t
            try:
                t = float(t)
            except (TypeError, ValueError):
                t = math.nan
            if not math.isfinite(t):
                return self._bad_input(t, f"time t = {t_in!r} is not a finite number: safe brake",
                                       "t")
            vals = []
            for name in INPUTS:
                x = outputs.get(name) if hasattr(outputs, "get") else None
                if x is None:
                    return self._bad_input(t, f"{name} is missing: safe brake", name)
                try:
                    x = float(x)
                except (TypeError, ValueError):
                    return self._bad_input(t, f"{name} = {x!r} is not a number: safe brake", name)
                if not math.isfinite(x):
                    return self._bad_input(t, f"{name} = {x} is not finite: safe brake", name)
                vals.append(x)
            for name, prior in STATED_INPUTS:      # optional: the prior where absent or bad
                x = outputs.get(name) if hasattr(outputs, "get") else None
                try:
                    x = float(x) if x is not None else prior
                except (TypeError, ValueError):
                    x = prior
                vals.append(x if math.isfinite(x) else prior)
            problem = self.supervisor.check(t, vals)
            if problem is not None:
                return self._bad_input(t, f"{problem[1]}: safe brake", problem[0])
            self._clear_inputs()
            if self._latched:                    # sane again: hold until sane for RECOVERY_TIME
                if self._sane_since is None:
                    self._sane_since = t
                if t - self._sane_since < RECOVERY_TIME - 1e-9:
                    return self._safe(t, f"inputs sane again: the safe brake is held until they "
                                         f"have been sane for {RECOVERY_TIME:g} s", "recovery")
                self._latched, self._sane_since = False, None
                self._clear("recovery")
                self.events.append((t, f"inputs sane for {RECOVERY_TIME:g} s: the safe brake "
                                       f"is released"))
            cmd = self._step(t, vals)
            self._last_brake = cmd.brake
            self.supervisor.note_command(cmd.traction)
            return cmd
        except Exception as e:      # a bug must not stop the host's loop: brake and say why
            return self._safe(math.nan, f"internal error {type(e).__name__}: {e}: safe brake",
                              "internal")

    def _params(self, t: float, est, stated) -> PlanCar:
        """The car to plan and feed forward with: blend_estimates of est.* and the configured
        car, weighted by est.*'s stated uncertainty (none while est.* is not usable at all)."""
        tn = self.tuning
        why = self._estimates_usable(est) if tn.use_estimates else "use_estimates off"
        if why is not None:
            w_m = w_r = 0.0
            key = None
            if self._using_estimates:
                self._log(t, f"estimates not usable ({why}): configured values", "estimates")
        else:
            c = self.configured
            ramp = min(max((est[5] - self._samples0 - tn.min_samples) / tn.min_samples, 0.0), 1.0)
            dt = t - self._t_gate if self._t_gate is not None else 0.0
            b = blend_estimates((c.mass, c.A0, c.A1, c.A2), tuple(est[:4]), stated, ramp,
                                tn.config_mass_std * c.mass, tn.config_resistance_std,
                                tn.est_gate, self._blend_speeds, tn.mass_band,
                                self._gate, GATE_RATE * dt)
            key, w_m, w_r = b[:4], b[4], b[5]
            self._gate, self._t_gate = b[6], t
            if b[6] <= 0.0 and ramp > 0.0:       # logged once until the gate opens fully
                self._log(t, f"est.A0..A2 lie {b[7]:.1f} stated sigmas from the configured "
                             f"resistance: no weight for est.*", "estimates")
            elif b[6] >= 1.0:
                self._clear("estimates")
        using = w_m > 0.0 or w_r > 0.0
        if using and not self._using_estimates and not self._used:
            self._used = True
            self._last_replan = -math.inf              # re-plan now with the estimates
            self.events.append((t, "est.* usable: planning with the identified values weighed "
                                   "against the configured car"))
        self._using_estimates = using
        self.weights = (w_m, w_r)
        c = self.configured
        plan = key if (key is not None and using) else (c.mass, c.A0, c.A1, c.A2)
        if tn.use_estimates:         # off: the configured car alone, as the tuning says
            plan = (heavier_mass(plan[0], est[0], int(est[4]) in EST_USABLE, c.mass, tn.mass_band), *plan[1:])
        brake_mass = braking_mass(plan[0], c.mass)
        if plan == (c.mass, c.A0, c.A1, c.A2) and brake_mass == c.brake_mass:
            self._car_now = c
        elif (plan, brake_mass) != self._last_key:
            self._car_now = PlanCar(self.car, *plan, tn.brake_share, brake_mass=brake_mass)
        self._last_key = (plan, brake_mass)
        return self._car_now

    def _replan(self, t: float, tau: float, s: float, v: float, car: PlanCar):   # tau: since departure
        t0 = _time.perf_counter()
        try:
            # while est.* and the configured car disagree (one is wrong: the error may show
            # only on the last coast) aim time_reserve x left^2 / schedule early (a quarter
            # half-way: still ~1 s at the final braking curve cost 3.5 % energy)
            left = max(self.span.schedule - tau, 0.0)
            reserve = (self.tuning.time_reserve * (1.0 - self._gate)
                       * left * left / self.span.schedule)
            plan = self.planner.plan(car, s, v, tau, self.span.schedule - reserve)
        except ValueError as e:
            return self._log(t, f"re-plan failed ({e}): the last plan is kept", "replan")
        self._clear("replan")
        self.replan_seconds.append(_time.perf_counter() - t0)
        self.replans += 1
        if plan.status != self._last_status:
            self.events.append((t, f"re-plan status {plan.status}: arrival planned "
                                   f"{plan.arrival - self.span.schedule:+.2f} s off schedule"))
            self._last_status = plan.status
        self.plan = plan
        self._final_start = self._final_stretch_start(plan.qU)
        if abs(car.brake_mass - self._sup_mass) > 1e-3 * self._sup_mass:   # else unchanged
            self._sup_q = self._supervision(car.brake_mass)

    def _step(self, t: float, vals) -> AtoCommand:
        v, s, sd = max(vals[0], 0.0), vals[1], vals[2]
        est = vals[3:9]
        self._psd = max(vals[9], 0.0)
        stated = vals[10:17]
        if self.t_departure is None:
            self.t_departure = t
            self._samples0 = est[5]   # est.samples runs on over station stops: count from here
        tau = t - self.t_departure
        car = self._params(t, est, stated)
        tn = self.tuning
        if self.phase == HOLD:
            return self._hold()
        if self.phase == SETTLE:
            return self._settle_step(t, s)
        g = self._grade(s)
        if self.phase == BRAKE:
            self._set_aim(sd)
        d = self.relay.stop - s             # to the aim point (the mark until BRAKE)
        if self.phase in (RUN, BRAKE) and (d <= self.course.d_relay or
                                           (self.phase == BRAKE and v <= self.course.v_relay)):
            self.phase = STOP_EP
            if self.aim_offset == 0.0:     # straight into the EP stage (no braking curve)
                self._set_aim(sd)
            else:                          # the low speeds may have settled the filter: the aim
                self._refine_aim(t, sd)    # moves towards the mark (less braking), never away
        if self.phase == STOP_EP:
            return self._stop_ep(t, s, v, sd, self.relay.stop - s, car, g)
        if self.phase == RUN and tn.replan and tau - self._last_replan >= tn.replan_period - 1e-9:
            self._last_replan = tau
            self._replan(t, tau, s, v, car)
        plan = self.plan
        # on the final braking curve, the curve ends at the aim point: U is read aim_offset on
        u, a_u = self._ceiling(s, sd, self.aim_offset if self.phase == BRAKE else 0.0)
        f_ceil = track_force(car, v, u, a_u, g, tn.approach_gain)
        if self.phase == BRAKE:
            # PI on the braking curve: the integral takes out what the feed-forward's mass and
            # resistance get wrong (a 20 % heavier car than planned lags ~0.2 m/s with P alone)
            dt = t - self._t_last if self._t_last is not None else 0.0
            lim = tn.brake_integral_max
            self._brake_int = min(max(self._brake_int + tn.brake_integral_gain * (u - v) * dt,
                                      -lim), lim)
            f = min(f_ceil + car.m_in * self._brake_int, 0.0)
            self._t_last = t
            return self._supervised(t, s, v, sd, self._command(car, v, f, a_u, u))
        f_want = 0.0
        if not any(x <= s < y for x, y in plan.coasts):
            f_c = track_force(car, v, plan.hold_speed, 0.0, g, tn.approach_gain)
            if f_c > 0.0:
                f_want = f_c
            elif v > plan.regen_speed:
                f_want = track_force(car, v, plan.regen_speed, 0.0, g, tn.approach_gain)
        on_ceiling = f_ceil < f_want
        f = f_ceil if on_ceiling else f_want
        if on_ceiling and f < 0.0 and s >= self._final_start - 1e-9:
            self.phase = BRAKE                 # on the braking curve to the stop mark
            self._brake_int, self._t_last = 0.0, t
            self._set_aim(sd)
        return self._supervised(t, s, v, sd, self._command(car, v, f, a_u if on_ceiling else 0.0,
                                                           plan.speed_at(s)))

    def _set_aim(self, sd: float):
        """The aim point: short of the mark by the way a speed error of aim_sigma x
        filter.speed_std covers over the EP stage, at most aim_max (a filter that lags errs to
        the short side). Set from the start of the final braking curve on, so that the whole
        curve ends there (set only at the EP stage, it asked that stage for more than a_ep).
        Where filter.position_std is above settle_std when that curve starts, the stop is a
        short one instead: settle_sigma x filter.position_std short, at most settle_aim_max;
        the car then stands settle_time and creeps on to the mark (_settle_step)."""
        tn = self.tuning
        if self._settle is None:
            self._settle = tn.settle_time > 0.0 and self._psd > tn.settle_std
        if self._settle and not self.settled:
            self.aim_offset = min(tn.settle_sigma * self._psd, tn.settle_aim_max)
        else:
            t_ep = self.course.v_relay / self.a_ep
            self.aim_offset = min(tn.aim_sigma * sd * t_ep, tn.aim_max)
        self.relay.stop = self.span.stop - self.aim_offset

    def _refine_aim(self, t: float, sd: float):
        """At the EP stage's start: where filter.position_std has fallen to settle_std (a speed
        sensor whose noise falls with the speed), no short stop after all; and the aim from the
        filter.speed_std now, where that is closer to the mark. Only ever towards the mark, so
        the relay never needs more than the curve's deceleration."""
        tn = self.tuning
        if self._settle and not self.settled and self._psd <= tn.settle_std:
            self._settle = False
            self.events.append((t, f"filter.position_std {self._psd:.3f} m at the "
                                                  f"EP stage: one stop, no settling"))
        if not (self._settle and not self.settled):
            t_ep = self.course.v_relay / self.a_ep
            self.aim_offset = min(self.aim_offset, tn.aim_sigma * sd * t_ep, tn.aim_max)
            self.relay.stop = self.span.stop - self.aim_offset

    def _settle_step(self, t: float, s: float) -> AtoCommand:
        """Standing short of the mark (the holding brake) for settle_time while the filter's
        distance catches up with the car; then creep on to the mark (STOP_EP's relay), or
        finish if the filter now puts the car within stop_window of it."""
        tn = self.tuning
        if t - self._settle_since < tn.settle_time - 1e-9:
            b = max(self._last_brake, tn.hold_brake * self.car.brake_force_max)
            return AtoCommand(0.0, b, int(AtoMode.SETTLE), 0.0)
        self.settled = True
        self.aim_offset = tn.creep_aim
        self.relay.stop = self.span.stop - tn.creep_aim
        self.relay.stop_window = min(tn.settle_window, tn.stop_window)
        self._stand_since = None
        self.events.append((t, f"settled: {self.span.stop - s:+.3f} m short of the mark "
                               f"(filter)"))
        self.phase = STOP_EP            # the relay creeps on from the next step, or it stands
        return AtoCommand(0.0, max(self._last_brake, tn.hold_brake * self.car.brake_force_max),
                          int(AtoMode.SETTLE), 0.0)

    def _ceiling(self, s: float, sd: float, shift: float = 0.0) -> tuple[float, float]:
        """The speed the car must stay under at s [m/s] and its rate dV/dt along s [m/s^2]: the
        plan's envelope U, or the supervision curve less k_sigma filter.speed_std and the gap
        where that is lower (a noisy filter would otherwise wake the supervisor)."""
        qu, dq = self._interp(self.plan.qU, s + shift)
        u = math.sqrt(qu) if qu > 0.0 else 0.0
        a_u = 0.5 * dq                          # dV/dt along U at speed u: V dV/ds = dq/ds / 2
        qs, dqs = self._interp(self._sup_q, s + self.tuning.k_sigma * self._psd)
        vs = math.sqrt(qs) if qs > 0.0 else 0.0
        tn = self.tuning
        w = vs - (tn.k_sigma + tn.gap_sigma) * sd - tn.supervisor_gap
        if w < u:
            return max(w, 0.0), 0.5 * dqs
        return u, a_u

    def _stop_ep(self, t, s, v, sd, d, car, g) -> AtoCommand:  # d: to the aim point
        """Below v_relay: Sidorenko's (1997) relay stages; the holding brake once the car stands."""
        tn = self.tuning
        settle = self._settle and not self.settled
        # after the stand, one creep: once it has crept and the relay braked, the car stands
        # where it stops (the filter's distance at rest wanders ~filter.position_std: a second
        # creep on that noise overran the mark by 0.5 m)
        done = self._crept and (self.relay.stage or 0) > 0
        if v <= tn.stand_speed and (d <= self.relay.stop_window or settle or done):
            if self._stand_since is None:
                self._stand_since = t
            if t - self._stand_since >= tn.stand_time - 1e-9 and settle:
                self.phase, self._settle_since = SETTLE, t
                self.first_stop = (t, s)
                self.events.append((t, f"stopped {self.span.stop - s:+.3f} m short of the mark "
                                       f"(filter; aimed {self.aim_offset:.3f} m short): "
                                       f"standing {tn.settle_time:g} s"))
                return self._settle_step(t, s)
            if t - self._stand_since >= tn.stand_time - 1e-9:
                if self.first_stop is None:
                    self.first_stop = (t, s)
                self.phase = HOLD
                self.events.append((t, f"stopped {self.span.stop - s:+.3f} m short of the "
                                       f"mark (filter; aimed {self.aim_offset:.3f} m short)"))
                return self._hold()
            return AtoCommand(0.0, max(self._last_brake, tn.hold_brake * self.car.brake_force_max),
                              int(AtoMode.EP), 0.0, self.relay.n_stages)
        self._stand_since = None
        f, b, stage, v_p = self.relay.command(t, s, v, car, g)
        self._crept = self._crept or (self.settled and stage < 0)
        mode = AtoMode.CREEP if stage < 0 else AtoMode.EP
        return self._supervised(t, s, v, sd, AtoCommand(f, b, int(mode), v_p, max(stage, 0)))

    def _hold(self) -> AtoCommand:
        b = max(self._last_brake, self.tuning.hold_brake * self.car.brake_force_max)
        return AtoCommand(0.0, b, int(AtoMode.HOLD), 0.0)

    def _command(self, car: PlanCar, v: float, f: float, a_ref: float,
                 planned: float) -> AtoCommand:
        """Split a net force into demands and name the mode (Table 2's reading)."""
        if f > 0.0:
            fm = car.f_max(v)
            mode = AtoMode.TG if f >= fm else AtoMode.C
            return AtoCommand(min(f, self.car.traction_force_max), 0.0, int(mode), planned)
        if f == 0.0:
            return AtoCommand(0.0, 0.0, int(AtoMode.VB), planned)
        b = -f
        regen = car.r_full(v) if v >= car.v_fade else 0.0
        decel = a_ref < 0.0
        if b <= regen:
            mode = AtoMode.RK if decel else AtoMode.SR
        else:
            mode = AtoMode.TM if decel else AtoMode.ST
        return AtoCommand(0.0, min(b, self.car.brake_force_max), int(mode), planned)

    def _supervised(self, t, s, v, sd, cmd: AtoCommand) -> AtoCommand:
        """The speed supervisor: full brake above the supervision curve, read k_sigma x
        filter.position_std further on than filter.position (where the car may be)."""
        k = self.tuning.k_sigma
        s_hi = s + k * self._psd
        q, _ = self._interp(self._sup_q, s_hi)
        v_hi = v + k * sd
        if v_hi * v_hi > q:
            self._log(t, f"speed {v:.3f} m/s + {k:g} x {sd:.3f} m/s above the supervision curve "
                         f"{math.sqrt(max(q, 0.0)):.3f} m/s at s = {s:.1f} m + {k:g} x "
                         f"{self._psd:.3f} m: full brake", "overspeed")
            return AtoCommand(0.0, self.car.brake_force_max, int(AtoMode.OVERSPEED),
                              cmd.planned_speed, cmd.ep_stage)
        self._clear("overspeed")
        return cmd
