"""Targeted stopping for the ATO (models/ato.py): the braking curve to the stop mark and seed 004's
multi-stage relay control of the electro-pneumatic brake at the end of it.

Seed 004 (Sidorenko 1997, ch. 4): braking follows a programmed speed-vs-distance curve to the
stop mark; the electro-pneumatic stage at the end used to run open-loop; switching that brake on
and off in several stages by comparing the actual and the programmed speed reaches a stop within
0.3 m without longer braking. Seed 003 (Meleshin 2011, ch. 2): the electric brake works above
~7 km/h, the electro-pneumatic brake from 0 to 7 km/h.

Our reading, in three parts:

1. above ``v_relay`` (7 km/h, CarTraction.regen_fade_speed) the car follows the re-planner's
   braking curve U(s) (the service brake, models/ato_planner.py) with a continuous force:
   ``track_force`` (feed-forward of the curve's deceleration, the resistance and the grade with
   the identified mass, plus a proportional speed term);
2. below it, the programmed curve is V_p(s) = sqrt(2 a_ep (stop - s)) (constant deceleration
   a_ep, the curve the re-planner ends with) and the brake force is a whole number of stages of
   car.mech_force_max / n_stages: the stage that the feed-forward needs, rounded down, plus one
   while the relay is on. The relay switches on when V - V_p > +hysteresis and off when
   V - V_p < -hysteresis (a two-point relay with hysteresis on the speed error, as seed 004's
   "on and off by comparing actual and programmed speed"); every further ``stage_speed`` of
   speed error adds (or takes away) one more stage. Seed 004 does not give the number of
   stages or the thresholds: ours are tuning values (models/ato.py AtoTuning);
3. at rest within ``stop_window`` of the mark: the holding brake. A car that stops short of
   that window creeps on (a small traction at most ``creep_speed``), which seed 004 does not
   describe: without it a car stopped 0.5 m short would stay there.

Units: s [m], V [m/s], force [N], mass [t].
"""
from __future__ import annotations

import math

from .ato_motion import PlanCar


def track_force(car: PlanCar, v: float, v_ref: float, a_ref: float, grade: float,
                gain: float) -> float:
    """Net force [N] (traction > 0, brake < 0) that gives the car the acceleration a_ref [m/s^2]
    of a reference plus ``gain`` [1/s] times the speed error v_ref - v [m/s], against the
    resistance w0(v) and the grade [permille] (eq. (2) solved for F - B)."""
    return car.m_in * (a_ref + gain * (v_ref - v)) + car.pg * (car.w0(v) + grade)


class RelayBrake:
    """Seed 004's multi-stage relay control of the electro-pneumatic brake (module docstring,
    part 2 and 3) for one stop mark ``stop`` [m].

    ``command(s, v, car, grade)`` -> (traction [N], brake [N], stage, programmed speed [m/s]);
    stage -1 means creeping (traction)."""

    def __init__(self, stop: float, a_ep: float, stage_force: float, n_stages: int,
                 hysteresis: float, stage_speed: float, creep_speed: float, creep_accel: float,
                 stop_window: float):
        self.stop, self.a_ep = stop, a_ep
        self.stage_force, self.n_stages = stage_force, n_stages
        self.hysteresis, self.stage_speed = hysteresis, stage_speed
        self.creep_speed, self.creep_accel = creep_speed, creep_accel
        self.stop_window = stop_window
        self.on = False          # the relay's extra stage

    def programmed_speed(self, s: float) -> float:
        """V_p(s) = sqrt(2 a_ep (stop - s)), 0 at and past the mark [m/s]."""
        d = self.stop - s
        return math.sqrt(2.0 * self.a_ep * d) if d > 0.0 else 0.0

    def command(self, s: float, v: float, car: PlanCar, grade: float):
        d = self.stop - s
        v_p = self.programmed_speed(s)
        if d <= 0.0:
            return 0.0, self.n_stages * self.stage_force, self.n_stages, 0.0
        err = v - v_p
        if err > self.hysteresis:
            self.on = True
        elif err < -self.hysteresis:
            self.on = False
        need = car.m_in * self.a_ep - car.pg * (car.w0(v) + grade)     # brake force for a_ep [N]
        base = int(math.floor(need / self.stage_force)) if need > 0.0 else 0
        extra = 0
        if abs(err) > self.hysteresis:
            extra = int((abs(err) - self.hysteresis) / self.stage_speed)
            extra = extra if err > 0.0 else -extra
        stage = min(max(base + (1 if self.on else 0) + extra, 0), self.n_stages)
        if (stage == 0 and err < -self.hysteresis and v < self.creep_speed
                and d > self.stop_window):
            # short of the mark and too slow: creep on, at most creep_speed
            target = min(v_p, self.creep_speed)
            gain = self.creep_accel / self.creep_speed           # creep_accel from rest [1/s]
            f = track_force(car, v, target, 0.0, grade, gain)
            return max(f, 0.0), 0.0, -1, v_p
        return 0.0, stage * self.stage_force, stage, v_p
