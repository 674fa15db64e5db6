"""Input supervision of the ATO (models/ato/controller.py): are the estimator's outputs the
controller reads physics, and do they agree with each other and with time?

``InputSupervisor.check(t, values)`` takes the call's time [s] and the finite input values in
``models.ato.interface.INPUTS`` order and returns ``None`` (sane) or ``(name, reason)``: the first
input found bad and why, with its value. The controller answers a problem with the safe brake
and a warning naming the input; the safe brake *latches*: it is held until the inputs have been
sane for ``RECOVERY_TIME`` (a sensor that flickers between good and bad must not flicker the
traction with it). What is checked, in this order (the bounds and why):

- time: each call later than the previous one, by at most ``MAX_CALL_GAP`` (longer: the
  inputs cannot be checked against each other, and the plan's timetable has jumped);
- standard deviations: finite, >= 0 and at most the speed or distance bounds below; 0 only
  while filter.speed is exactly 0 (RailCar's filter starts from the known standstill at the
  station with zero covariance; once the car moves, a filter is never exact);
- filter.speed: not below -NOISE_SIGMA x filter.speed_std (the filter is not clamped
  everywhere: a little negative is noise, more is a car running backwards or a sign error),
  at most MAX_SPEED (no rail car is that fast);
- filter.position: not below -NOISE_SIGMA x filter.position_std (behind the departure station),
  at most MAX_DISTANCE;
- est.*: est.mass within a factor MASS_FACTOR of the configured car.mass, |est.A0| <= A0_MAX,
  |est.A1| <= A1_MAX, |est.A2| <= A2_MAX, est.status one of the estimator's four codes,
  0 <= est.samples <= MAX_SAMPLES (bounds beside the constants);
- consistency: over windows of CONSISTENCY_WINDOW, the advance of filter.position must match
  the filter's speeds integrated over the window (trapezoid) within NOISE_SIGMA x
  (filter.position_std at both ends + filter.speed_std x the window) + CONSISTENCY_SLACK. A
  speed of ~0 while the position advances (a speed input stuck or cut), or a position that
  stays put while the speed says the car moves (a position input stuck), fails it within a
  window or two;
- response: traction commanded for RESPONSE_TIME while filter.speed stays at 0 and
  filter.position does not move at all (``note_command`` tells the supervisor the command): the
  inputs do not follow the car, most likely not connected (their start values are a car at
  rest, which every other check accepts).

NOISE_SIGMA is 6: a Gaussian error of 6 sigma happens once in ~1e9 samples, 3 years at 10 Hz;
the library's runs stay far inside every bound (docs/ato.md, Input supervision, gives the
margins measured). Units: V [m/s], s [m], t [s], mass [t], A0 [N/kN], A1 [N/kN/(m/s)],
A2 [N/kN/(m/s)^2].
"""
from __future__ import annotations

NOISE_SIGMA = 6.0           # an input may be this many of its own stds outside physics
RECOVERY_TIME = 1.0         # [s] of sane inputs before the safe brake is released
MAX_CALL_GAP = 10.0         # [s] between two calls (the controller runs at 0.1-1 s steps)
MAX_SPEED = 200.0           # [m/s] |filter.speed| (720 km/h; RailCarEstimator's sensor bound)
MAX_DISTANCE = 1e7          # [m] filter.position (10,000 km; RailCarEstimator's bound)
MASS_FACTOR = 10.0          # est.mass within [car.mass / 10, 10 car.mass]. The estimator reports
#                             est.mass within a factor 5 of its own start value (OnlineEstimator.
#                             MASS_RANGE; under the worst speed noise of studies/ato_closed_loop.py
#                             it reaches 149 t for a 30 t car); twice that leaves room for an
#                             estimator started at up to twice or half car.mass, and catches 0, a
#                             negative mass, kg for t
A0_MAX = 1000.0             # [N/kN] the weight itself (1 g); the identification under the worst
#                             speed noise of studies/ato_closed_loop.py reaches 185 N/kN
A1_MAX = 100.0              # [N/kN/(m/s)] (Rusich: 0.03; that noise: 2.0)
A2_MAX = 10.0               # [N/kN/(m/s)^2] (Rusich: 0.01; that noise: 0.57)
EST_STATUS_CODES = (0, 1, 2, 3)   # prior, identifying, holding, degraded (models.estimation.online)
MAX_SAMPLES = 1e9           # est.samples: 3 years of samples at 10 Hz (2^31 - 1 is an overflow)
RESPONSE_TIME = 3.0         # [s] a car under traction moves within a sample (0.1 s) or two
CONSISTENCY_WINDOW = 2.0    # [s] the position-speed comparison's window
CONSISTENCY_SLACK = 1.0     # [m] on top of the stds: the filter's corrections at a stop (its
#                             distance catching up with the car: ~0.3 m, sd 0.3 m at the worst
#                             speed noise, docs/ato.md) and the host's step; the library's runs
#                             reach 0.31 m in 2 s

SPEED, POSITION, SPEED_STD, MASS, A0, A1, A2, STATUS, SAMPLES, POSITION_STD = range(10)


class InputSupervisor:
    """The checks of the module docstring for a car configured with ``mass`` [t]; keeps the
    state the time, consistency and response checks need (the previous call, the window's
    start, the traction commanded at rest: ``note_command`` after each command)."""

    def __init__(self, mass: float):
        self.mass = mass
        self.t_last: float | None = None
        self._anchor: tuple | None = None       # (t, s, filter.position_std) at the window start
        self._travel = 0.0                      # speeds integrated since the anchor [m]
        self._v_last = 0.0
        self._sd_max = 0.0                      # largest filter.speed_std in the window
        self._pushing: tuple | None = None      # (t, s) of the first traction command at rest
        self._dead: tuple | None = None         # (problem, s): inputs found not to follow the car
        self._at_rest: tuple | None = None      # (t, s) of the last sane call with V = 0

    def check(self, t: float, x) -> tuple[str, str] | None:
        """``None`` if the inputs ``x`` (INPUTS order, finite) at time ``t`` [s] are sane, else
        (input name, reason with its value)."""
        problem = self._check_time(t)
        if self.t_last is None or t > self.t_last:
            self.t_last = t
        problem = problem or self._check_stds(x) or self._check_motion(x) or self._check_estimates(x)
        if problem is None:
            problem = self._check_consistency(t, x)
        else:
            self._anchor = None      # a window spans sane calls only: no trapezoid over a bad episode
        self._at_rest = (t, x[POSITION]) if problem is None and x[SPEED] == 0.0 else None
        return problem or self._check_response(t, x)

    def note_command(self, traction: float) -> None:
        """The traction [N] commanded after the last call: the response check's clock runs from
        the first traction commanded while the inputs said the car stands."""
        if traction <= 0.0:
            self._pushing = None
        elif self._pushing is None and self._at_rest is not None:
            self._pushing = self._at_rest

    def _check_response(self, t: float, x):
        """Traction at rest for RESPONSE_TIME and the inputs not moving at all: refused, and
        refused on until they move (no other sign says they are back)."""
        if self._dead is not None:
            if x[SPEED] == 0.0 and x[POSITION] == self._dead[1]:
                return self._dead[0]
            self._dead = None
        if self._pushing is None:
            return None
        t0, s0 = self._pushing
        if x[SPEED] != 0.0 or x[POSITION] != s0:
            self._pushing = None                 # the car responds
            return None
        if t - t0 >= RESPONSE_TIME - 1e-9:
            self._pushing = None
            problem = ("filter.speed", f"filter.speed = 0 m/s and filter.position = {s0!r} m have "
                                       f"not moved in {t - t0:.3g} s of traction: the inputs do not "
                                       f"follow the car (not connected?)")
            self._dead = (problem, s0)
            return problem
        return None

    # ------------------------------------------------------------------ single values
    def _check_time(self, t: float):
        last = self.t_last
        if last is None:
            return None
        if not t > last:
            self._anchor = None
            return "t", (f"time t = {t!r} s does not continue: the previous call was at "
                         f"t = {last!r} s")
        if t - last > MAX_CALL_GAP:
            self._anchor = None
            return "t", (f"time t = {t!r} s is {t - last:.6g} s after the previous call (at most "
                         f"{MAX_CALL_GAP:g} s: the inputs cannot be checked against each other)")
        return None

    @staticmethod
    def _check_stds(x):
        for i, name, unit, bound in ((SPEED_STD, "filter.speed_std", "m/s", MAX_SPEED),
                                     (POSITION_STD, "filter.position_std", "m", MAX_DISTANCE)):
            sd = x[i]
            if sd < 0.0:
                return name, f"{name} = {sd!r} {unit}: a standard deviation is never negative"
            if sd == 0.0 and x[SPEED] != 0.0:
                return name, (f"{name} = 0 {unit} while filter.speed = {x[SPEED]!r} m/s: a filter "
                              f"is exact only at its known start at rest")
            if sd > bound:
                return name, f"{name} = {sd!r} {unit} is beyond {bound:g} {unit} (not physics)"
        return None

    @staticmethod
    def _check_motion(x):
        v, sd = x[SPEED], x[SPEED_STD]
        if v < -NOISE_SIGMA * sd:
            return "filter.speed", (f"filter.speed = {v!r} m/s is below -{NOISE_SIGMA:g} x "
                                    f"filter.speed_std ({-NOISE_SIGMA * sd:.4g} m/s): the car "
                                    f"does not run backwards")
        if v > MAX_SPEED:
            return "filter.speed", (f"filter.speed = {v!r} m/s is beyond {MAX_SPEED:g} m/s (no rail "
                                    f"car is that fast)")
        s, psd = x[POSITION], x[POSITION_STD]
        if s < -NOISE_SIGMA * psd:
            return "filter.position", (f"filter.position = {s!r} m is below -{NOISE_SIGMA:g} x "
                                       f"filter.position_std ({-NOISE_SIGMA * psd:.4g} m): behind "
                                       f"the departure station")
        if s > MAX_DISTANCE:
            return "filter.position", (f"filter.position = {s!r} m is beyond {MAX_DISTANCE:g} m (no "
                                       f"line is that long)")
        return None

    def _check_estimates(self, x):
        m = x[MASS]
        lo, hi = self.mass / MASS_FACTOR, self.mass * MASS_FACTOR
        if not lo <= m <= hi:
            return "est.mass", (f"est.mass = {m!r} t is outside [{lo:.4g}, {hi:.4g}] t (a factor "
                                f"{MASS_FACTOR:g} of car.mass = {self.mass:g} t)")
        for i, name, bound, unit in ((A0, "est.A0", A0_MAX, "N/kN"),
                                     (A1, "est.A1", A1_MAX, "N/kN/(m/s)"),
                                     (A2, "est.A2", A2_MAX, "N/kN/(m/s)^2")):
            if abs(x[i]) > bound:
                return name, (f"{name} = {x[i]!r} {unit} is beyond +-{bound:g} {unit} (no "
                              f"resistance is that large)")
        if x[STATUS] not in EST_STATUS_CODES:
            return "est.status", f"est.status = {x[STATUS]:g} is not one of the estimator's codes 0..3"
        if not 0.0 <= x[SAMPLES] <= MAX_SAMPLES:
            return "est.samples", (f"est.samples = {x[SAMPLES]:.0f} is outside [0, {MAX_SAMPLES:.0e}] "
                                   f"(a count of samples; 1e9 is 3 years at 10 Hz)")
        return None

    # ------------------------------------------------------------------ consistency
    def _check_consistency(self, t: float, x):
        """filter.position's advance against the speeds integrated over the window."""
        s, v, sd, psd = x[POSITION], x[SPEED], x[SPEED_STD], x[POSITION_STD]
        if self._anchor is None:
            self._restart(t, s, v, sd, psd)
            return None
        t0, s0, psd0 = self._anchor
        self._travel += 0.5 * (self._v_last + v) * (t - self._t_prev)
        self._v_last, self._t_prev = v, t
        self._sd_max = max(self._sd_max, sd)
        advance = s - s0
        tol = NOISE_SIGMA * (psd0 + psd + self._sd_max * (t - t0)) + CONSISTENCY_SLACK
        if abs(advance - self._travel) > tol:
            problem = "filter.speed vs filter.position", (
                f"filter.speed and filter.position disagree: filter.position advanced "
                f"{advance:.3f} m in {t - t0:.3g} s, filter.speed (now {v!r} m/s) accounts for "
                f"{self._travel:.3f} m (tolerance {tol:.3f} m)")
            self._restart(t, s, v, sd, psd)
            return problem
        if t - t0 >= CONSISTENCY_WINDOW - 1e-9:
            self._restart(t, s, v, sd, psd)
        return None

    def _restart(self, t, s, v, sd, psd):
        self._anchor = (t, s, psd)
        self._t_prev, self._v_last = t, v
        self._travel, self._sd_max = 0.0, sd
