"""Speed from two point track sensors a base b apart (eq. (15) of Boynik et al.,
docs/filters.md).

The car passes sensor 1 at t1 and sensor 2 at t2 = t1 + b / v (constant speed over the base);
a timer of resolution delta [s] time-stamps both passages and the speed is v_meas = b / (t2' - t1')
(Boynik et al., eq. (15), their refs. [1], [5]). The measurement is used as y = [0 1 0] z + eta
(their eq. (16)) by ``models.filtering.singer``.

Error model (first order in the timing error e of the interval t2' - t1' [s]):

- each time stamp is floor((t - phase)/delta) delta + phase for a timer free-running with
  ``phase`` [s]; over passages the phase is uniform, so each stamp's error is uniform on
  (-delta, 0] with variance delta^2/12. The two errors are NOT independent for a given
  interval T = b/v: with T/delta = k + f (f its fractional part) the measured interval is
  k delta or (k+1) delta with probabilities 1 - f and f, so the error is unbiased with variance
  delta^2 f (1 - f) (``interval_quantisation_variance``): 0 when T is a whole number of ticks,
  delta^2/4 at f = 1/2. Averaged over f (speeds spread over more than a tick of T, or a jitter
  of a tick or more that dithers the stamps) it is delta^2/6 — the variance of the triangular
  difference of two independent uniform errors, the value used below;
- an optional detection jitter [s] (std ``jitter_std``, each sensor independently) adds 2 jitter^2;
- v_meas = b/(T + e) ~ v (1 - e/T), T = b/v, so sigma_v ~ v sigma_e / T = v^2/b sigma_e:

      sigma_v ~ v^2 / b * sqrt(delta^2/6 + 2 jitter^2)          (``track_sensor_speed_std``)

  The relative error v delta / b and the absolute error v^2 delta / b grow with speed; the
  worst case of quantisation alone is b/(T - delta) - b/T = v^2 delta / (b - v delta)
  (``track_sensor_speed_error_bound``). To second order the measurement is biased high by
  v sigma_e^2/T^2 (E[1/(T+e)] > 1/T, ``track_sensor_speed_bias``) — relevant to the "never
  above the truth" requirement (Meleshin 2011; docs/estimation.md).
- With constant acceleration over the base, b/(t2 - t1) is exactly the speed at the midpoint
  time (t1 + t2)/2 (``passage_times`` with ``accel``): time-stamp the measurement there.

Units: speed [m/s], base [m], times and resolution [s], acceleration [m/s^2]. Functions accept
numpy arrays (element-wise) unless noted.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


def _out(a):
    """0-d arrays back to float."""
    a = np.asarray(a, dtype=float)
    return float(a) if a.ndim == 0 else a


def _check_base_resolution(base: float, resolution: float) -> None:
    if not (base > 0.0 and math.isfinite(base)):
        raise ValueError(f"base must be > 0 and finite [m], got {base}")
    if not (resolution >= 0.0 and math.isfinite(resolution)):
        raise ValueError(f"resolution must be >= 0 and finite [s], got {resolution}")


def passage_times(speed, base: float, t1=0.0, accel=0.0):
    """True passage times (t1, t2) [s] at sensors 1 and 2 a base [m] apart.

    ``speed`` [m/s] > 0 is the speed at sensor 1, ``accel`` [m/s^2] a constant acceleration over
    the base: T = t2 - t1 solves b = v T + accel T^2 / 2, taken in the rationalised form
    T = 2 b / (v + sqrt(v^2 + 2 accel b)) (no cancellation for small accel). The car must reach
    sensor 2 (v^2 + 2 accel b > 0).
    """
    _check_base_resolution(base, 0.0)
    v = np.asarray(speed, dtype=float)
    disc = v * v + 2.0 * np.asarray(accel, dtype=float) * base
    if np.any(v <= 0.0) or np.any(disc <= 0.0):
        raise ValueError("the car must pass both sensors: speed > 0 and v^2 + 2 a b > 0")
    T = 2.0 * base / (v + np.sqrt(disc))
    return _out(t1), _out(np.asarray(t1, dtype=float) + T)


def quantise_time(t, resolution: float, phase=0.0):
    """Time stamp [s] of a timer ticking every ``resolution`` [s] from ``phase`` [s]: the last
    tick at or before t, floor((t - phase)/resolution) resolution + phase. resolution 0: exact."""
    if resolution == 0.0:
        return _out(t)
    return _out(np.floor((np.asarray(t, dtype=float) - phase) / resolution) * resolution + phase)


def speed_from_times(t1, t2, base: float, resolution: float = 0.0, phase=0.0,
                     jitter1=0.0, jitter2=0.0):
    """Measured speed [m/s] b / (t2' - t1') from the true passage times t1, t2 [s] (Boynik
    et al., eq. (15)): each time gets its detection jitter [s] (a drawn value, not a std), then is
    quantised by the timer (``quantise_time``, resolution and phase [s]).

    Returns +inf when both stamps fall on the same tick (interval 0: the timer is too coarse
    for the speed; see ``track_sensor_speed_error_bound``).
    """
    _check_base_resolution(base, resolution)
    s1 = quantise_time(np.asarray(t1, dtype=float) + jitter1, resolution, phase)
    s2 = quantise_time(np.asarray(t2, dtype=float) + jitter2, resolution, phase)
    dt = s2 - s1
    with np.errstate(divide="ignore"):
        return _out(np.where(dt > 0.0, base / np.where(dt > 0.0, dt, 1.0), np.inf))


def track_sensor_speed(speed, base: float, resolution: float = 0.0, t1=0.0, phase=0.0,
                       jitter1=0.0, jitter2=0.0, accel=0.0):
    """Measured speed [m/s] for a true passage at ``speed`` [m/s] over sensor 1 at t1 [s].

    ``accel`` [m/s^2]: constant acceleration over the base [m]; ``resolution``/``phase`` [s]:
    the timer; ``jitter1``/``jitter2`` [s]: drawn detection-time errors (e.g.
    ``jitter_std * rng.standard_normal()``). Pure: the randomness is passed in.
    """
    t1, t2 = passage_times(speed, base, t1, accel)
    return speed_from_times(t1, t2, base, resolution, phase, jitter1, jitter2)


def interval_quantisation_variance(v, base: float, resolution: float):
    """Variance [s^2] of the quantised interval's error at the exact speed v [m/s] (no jitter,
    timer phase uniform): delta^2 f (1 - f), f = frac(b / (v delta)). Its mean over f is
    delta^2/6."""
    _check_base_resolution(base, resolution)
    if resolution == 0.0:
        return _out(np.zeros_like(np.asarray(v, dtype=float)))
    ticks = base / (np.asarray(v, dtype=float) * resolution)
    f = ticks - np.floor(ticks)
    return _out(resolution * resolution * f * (1.0 - f))


def interval_error_variance(resolution: float, jitter_std: float = 0.0) -> float:
    """Variance [s^2] of the error of t2' - t1' averaged over speeds: delta^2/6 (triangular,
    difference of two uniform stamp errors; see the module docstring for a fixed speed) +
    2 jitter^2 (resolution delta [s], jitter std [s])."""
    return resolution * resolution / 6.0 + 2.0 * jitter_std * jitter_std


def track_sensor_speed_std(v, base: float, resolution: float, jitter_std: float = 0.0):
    """First-order std [m/s] of the measured speed at true speed v [m/s]:
    sigma_v = v^2 / b * sqrt(delta^2/6 + 2 jitter^2), base b [m], resolution delta [s], jitter [s].
    Valid while sigma_e << b / v (the relative error is small); the quantisation part is the
    average over speeds (for one exact speed see ``interval_quantisation_variance``)."""
    _check_base_resolution(base, resolution)
    v = np.asarray(v, dtype=float)
    return _out(v * v / base * math.sqrt(interval_error_variance(resolution, jitter_std)))


def track_sensor_speed_bias(v, base: float, resolution: float, jitter_std: float = 0.0):
    """Second-order bias [m/s] of b/(T + e): E[v_meas] - v ~ v sigma_e^2 / T^2 = v^3 sigma_e^2 / b^2
    (zero-mean interval error e of variance sigma_e^2, ``interval_error_variance``). Positive:
    the measurement reads high on average."""
    _check_base_resolution(base, resolution)
    v = np.asarray(v, dtype=float)
    return _out(v * v * v * interval_error_variance(resolution, jitter_std) / (base * base))


def track_sensor_speed_error_bound(v, base: float, resolution: float):
    """Worst-case |v_meas - v| [m/s] from quantisation alone: v^2 delta / (b - v delta)
    (the interval measured short by up to delta). Infinite when v delta >= b."""
    _check_base_resolution(base, resolution)
    v = np.asarray(v, dtype=float)
    margin = base - v * resolution
    with np.errstate(divide="ignore"):
        return _out(np.where(margin > 0.0, v * v * resolution / np.where(margin > 0.0, margin, 1.0),
                             np.inf))


@dataclass(frozen=True)
class TrackSensorPair:
    """Two point track sensors: base [m], timer resolution [s], detection jitter std [s]."""
    base: float
    resolution: float
    jitter_std: float = 0.0

    def __post_init__(self):
        _check_base_resolution(self.base, self.resolution)
        if not (self.jitter_std >= 0.0 and math.isfinite(self.jitter_std)):
            raise ValueError(f"jitter_std must be >= 0 and finite [s], got {self.jitter_std}")

    def speed_std(self, v):
        """First-order std [m/s] of the measurement at speed v [m/s] (``track_sensor_speed_std``);
        use its square as R of ``models.filtering.singer.H_SPEED``."""
        return track_sensor_speed_std(v, self.base, self.resolution, self.jitter_std)

    def measure(self, speed, rng: np.random.Generator, t1=0.0, accel=0.0):
        """Measured speed [m/s] and its time stamp [s] for a passage at ``speed`` [m/s] over
        sensor 1 at t1 [s]; the timer phase is uniform and the jitter normal, both drawn from
        ``rng``. The time stamp is the midpoint of the two stamps plus delta/2 (a floor stamp is
        delta/2 early on average), where the speed b/(t2 - t1) is exact for constant
        acceleration."""
        v = np.asarray(speed, dtype=float)
        shape = v.shape
        phase = rng.uniform(0.0, self.resolution, size=shape) if self.resolution > 0 else 0.0
        j1 = self.jitter_std * rng.standard_normal(shape)
        j2 = self.jitter_std * rng.standard_normal(shape)
        t1, t2 = passage_times(v, self.base, t1, accel)
        s1 = quantise_time(t1 + j1, self.resolution, phase)
        s2 = quantise_time(t2 + j2, self.resolution, phase)
        with np.errstate(divide="ignore"):
            v_meas = np.where(s2 > s1, self.base / np.where(s2 > s1, s2 - s1, 1.0), np.inf)
        return _out(v_meas), _out(0.5 * (s1 + s2) + 0.5 * self.resolution)
