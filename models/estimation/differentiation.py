"""Speed and acceleration from sensor samples by least-squares polynomial differentiation
(Sidorenko 1997, chapter 3; docs/estimation.md).

Sidorenko fits a polynomial X(t) = a0 + a1 t + ... + al t^l (eq. (1) there) by least squares
("Chebyshev polynomials") to the last M+1 samples X[n], ..., X[n-M] of a measured quantity and
takes the derivatives of the polynomial at the newest sample (t = 0) as the measured
derivatives: X'[n] = a1, X''[n] = 2 a2. Applied to

- distance samples [m] with order 2: speed [m/s] = first derivative, acceleration [m/s^2] = second;
- speed samples [m/s] with order 1 (Sidorenko's recommendation, M = 5, i.e. 6 samples): the
  fitted value is the smoothed speed [m/s] and its slope the acceleration [m/s^2].

Samples may be at unequal times, e.g. several axle sensors read at different, unsynchronised
instants. Such streams are time-aligned (each sample kept at its own read time, corrected for a
known read delay) and merged before the fit; the fit is then evaluated at a common instant (the
control tick): ``fuse_sensors``. ``zero_order_hold`` is the baseline Sidorenko compares with
(latest sample held; acceleration as the difference of consecutive held speeds).

Numerics: times are centred at the evaluation instant and scaled by the window's extent before
the Vandermonde matrix is built, so absolute times (e.g. 1e4 s into a run) cost no accuracy.
Units: times [s]; x in its own unit u (m or m/s); the k-th derivative in u/s^k.
"""
from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass
from typing import Sequence

import numpy as np

WINDOW = 6
"""Sidorenko's (1997) window: M + 1 = 6 samples (M = 5)."""


def _scaled_vandermonde(t: np.ndarray, t_eval, order: int):
    """tau = (t - t_eval)/s with s the largest |t - t_eval| per window; V[..., i, j] = tau_i^j."""
    d = t - np.asarray(t_eval, dtype=float)[..., None]
    s = np.max(np.abs(d), axis=-1)
    s = np.where(s > 0.0, s, 1.0)
    tau = d / s[..., None]
    return tau[..., :, None] ** np.arange(order + 1), s


def _derivative_scale(s, order: int):
    """k! / s^k for k = 0..order: from the scaled coefficients to derivatives at t_eval."""
    k = np.arange(order + 1)
    fact = np.array([math.factorial(int(i)) for i in k], dtype=float)
    return fact / np.asarray(s, dtype=float)[..., None] ** k


def ls_weights(t, order: int = 1, t_eval: float | None = None) -> np.ndarray:
    """Linear weights W, shape (order+1, n): derivatives at t_eval = W @ x (Sidorenko, eq. (1)).

    Row k gives the k-th derivative [u/s^k] at ``t_eval`` [s] (default: the newest time,
    max(t)) of the least-squares polynomial of degree ``order`` through the samples at times
    ``t`` [s]. For white noise of std sigma on x, the k-th derivative has std sigma ||W[k]||.
    Needs at least order + 1 distinct times.
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    if order < 0:
        raise ValueError(f"order must be >= 0, got {order}")
    if not np.all(np.isfinite(t)):
        raise ValueError("sample times must be finite")
    if np.unique(t).size < order + 1:
        raise ValueError(f"a fit of order {order} needs {order + 1} distinct times, got "
                         f"{np.unique(t).size}")
    te = float(np.max(t)) if t_eval is None else float(t_eval)
    V, s = _scaled_vandermonde(t, te, order)
    return np.linalg.pinv(V) * _derivative_scale(s, order)[:, None]


def ls_derivatives(t, x, order: int = 1, t_eval: float | None = None) -> np.ndarray:
    """[x^(0), x^(1), ..., x^(order)] at ``t_eval`` [s] (default: newest sample time) of the
    least-squares polynomial of degree ``order`` through (t [s], x [u]) (Sidorenko, eq. (1)):
    value [u], first derivative [u/s], second [u/s^2] ... Exact for polynomials of degree
    <= order (noise-free), up to rounding.
    """
    x = np.asarray(x, dtype=float).reshape(-1)
    W = ls_weights(t, order, t_eval)
    if W.shape[1] != x.size:
        raise ValueError(f"t and x differ in length: {W.shape[1]} vs {x.size}")
    return W @ x


def ls_noise_std(t, order: int, noise_std: float, t_eval: float | None = None) -> np.ndarray:
    """Std of each derivative [u/s^k] caused by white noise of std ``noise_std`` [u] on x:
    noise_std * ||W[k]|| (``ls_weights``)."""
    W = ls_weights(t, order, t_eval)
    return noise_std * np.sqrt(np.sum(W * W, axis=1))


def centred_slope_weights(dts: Sequence[float]) -> tuple[list[float], list[float]]:
    """Sidorenko's (1997) first-order fit over the samples that close the intervals ``dts`` [s], at
    the window's mean time: (w, c) with slope = sum_k w[k] x[k] [u/s] over the len(dts) + 1 samples,
    and c[j] = dt_j sum_{i>j} w[i] (sum c = 1) the weight the slope gives interval j's mean
    derivative: slope = sum_j c[j] (x[j+1] - x[j]) / dt_j exactly.

    At the mean time the fitted value (the samples' mean) and the slope are uncorrelated for
    white noise on x, which is what takes the errors-in-variables bias out of a regression whose
    regressor is the value and whose target is the slope (models.estimation.online, est.method 2).
    The measurement noise of a sum of consecutive slopes telescopes to its two ends:
    var = 2 sum_j c[j]^2 sigma^2 (0.42 sigma^2 for six equally spaced samples, against the
    2 sigma^2 of a sum of plain differences). Pure Python: it runs once per sample.
    """
    t = [0.0]
    for d in dts:
        if not (d > 0.0 and math.isfinite(d)):
            raise ValueError(f"sample spacing must be > 0, got {d}")
        t.append(t[-1] + d)
    mean = sum(t) / len(t)
    tau = [x - mean for x in t]
    ss = sum(x * x for x in tau)
    w = [x / ss for x in tau]
    c, tail = [], 0.0
    for j in range(len(dts) - 1, -1, -1):
        tail += w[j + 1]
        c.append(dts[j] * tail)
    c.reverse()
    return w, c


class LSDifferentiator:
    """Streaming seed-004 differentiator over the last ``window`` samples (default M + 1 = 6).

    ``push(t, x)`` adds a sample (times non-decreasing [s]) and returns the derivatives
    [value, first, ...] at the newest time, or None until order + 1 distinct times are held.
    ``at(t_eval)`` evaluates the current fit at another instant (e.g. the control tick).
    """

    def __init__(self, order: int = 1, window: int = WINDOW):
        if order < 0 or window < order + 1:
            raise ValueError(f"need order >= 0 and window >= order + 1, got {order}, {window}")
        self.order = order
        self.window = window
        self._t: deque[float] = deque(maxlen=window)
        self._x: deque[float] = deque(maxlen=window)

    def reset(self) -> None:
        self._t.clear()
        self._x.clear()

    def push(self, t: float, x: float) -> np.ndarray | None:
        t, x = float(t), float(x)
        if not (math.isfinite(t) and math.isfinite(x)):
            raise ValueError(f"sample must be finite, got t={t}, x={x}")
        if self._t and t < self._t[-1]:
            raise ValueError(f"sample times must not decrease: {t} after {self._t[-1]}")
        self._t.append(t)
        self._x.append(x)
        return self.at(None) if self.ready else None

    @property
    def ready(self) -> bool:
        return len(set(self._t)) >= self.order + 1

    def at(self, t_eval: float | None) -> np.ndarray:
        """Derivatives of the current fit at ``t_eval`` [s] (None: newest sample time)."""
        if not self.ready:
            raise ValueError("not enough distinct samples yet")
        return ls_derivatives(np.fromiter(self._t, float), np.fromiter(self._x, float),
                              self.order, t_eval)


# ------------------------------------------------------------------- several sensors

def merge_streams(times: Sequence, values: Sequence, delays: Sequence[float] | None = None):
    """Time-align and merge K sensor streams.

    ``times[k]`` [s] are the instants sensor k was read, ``values[k]`` its readings [u];
    ``delays[k]`` [s] a known latency (the reading describes the instant time - delay). Returns
    (t, x, source): all samples sorted by their aligned time (stable: ties keep sensor order),
    and the index of the sensor of each.
    """
    if len(times) != len(values):
        raise ValueError("times and values must list the same sensors")
    delays = [0.0] * len(times) if delays is None else list(delays)
    if len(delays) != len(times):
        raise ValueError("one delay per sensor")
    ts, xs, ks = [], [], []
    for k, (tk, xk, dk) in enumerate(zip(times, values, delays)):
        tk = np.asarray(tk, dtype=float).reshape(-1)
        xk = np.asarray(xk, dtype=float).reshape(-1)
        if tk.size != xk.size:
            raise ValueError(f"sensor {k}: {tk.size} times but {xk.size} values")
        ts.append(tk - float(dk))
        xs.append(xk)
        ks.append(np.full(tk.size, k))
    t = np.concatenate(ts)
    order = np.argsort(t, kind="stable")
    return t[order], np.concatenate(xs)[order], np.concatenate(ks)[order]


@dataclass(frozen=True)
class FusedEstimate:
    """Estimates at the common instants ``t`` [s]: value [u] (speed [m/s] for speed sensors)
    and its rate [u/s] (acceleration [m/s^2]); NaN where fewer than order + 1 samples were in."""
    t: np.ndarray
    value: np.ndarray
    rate: np.ndarray


def fuse_sensors(times: Sequence, values: Sequence, t_out, window: int = WINDOW,
                 order: int = 1, delays: Sequence[float] | None = None,
                 extrapolate: bool = True) -> FusedEstimate:
    """Sidorenko's (1997) recommended speed channel: merge the (time-aligned) streams of several
    sensors, fit a polynomial of ``order`` (1) to the last ``window`` (6) merged samples read
    at or before each common instant t_out [s], and evaluate it there: value [u] and first
    derivative [u/s] (for axle speed sensors: speed [m/s] and acceleration [m/s^2]).

    Only samples with aligned time <= t_out are used (causal). Vectorised over t_out.
    ``extrapolate=False`` evaluates the fit at the newest sample of the window instead (seed
    004 literally: t = 0 at the newest sample), i.e. without aligning to t_out.
    """
    t, x, _ = merge_streams(times, values, delays)
    t_out = np.asarray(t_out, dtype=float).reshape(-1)
    if window < order + 1:
        raise ValueError(f"window must be >= order + 1, got {window}")
    n_in = np.searchsorted(t, t_out, side="right")          # samples available at each tick
    value = np.full(t_out.size, np.nan)
    rate = np.full(t_out.size, np.nan)
    ok = n_in >= window
    idx = np.maximum(n_in[:, None] - window, 0) + np.arange(window)   # (n_out, window)
    idx = np.minimum(idx, max(t.size - 1, 0))
    if t.size:                           # a fit needs order + 1 distinct times in its window
        distinct = 1 + np.count_nonzero(np.diff(np.sort(t[idx], axis=1), axis=1) > 0.0, axis=1)
        ok &= distinct >= order + 1
    if np.any(ok):
        idx = idx[ok]
        tw, xw = t[idx], x[idx]
        t_eval = t_out[ok] if extrapolate else tw[:, -1]
        V, s = _scaled_vandermonde(tw, t_eval, order)
        coef = np.einsum("nij,nj->ni", np.linalg.pinv(V), xw) * _derivative_scale(s, order)
        value[ok] = coef[:, 0]
        if order >= 1:
            rate[ok] = coef[:, 1]
        else:
            rate[ok] = 0.0
    return FusedEstimate(t_out, value, rate)


def zero_order_hold(times: Sequence, values: Sequence, t_out,
                    delays: Sequence[float] | None = None) -> FusedEstimate:
    """Sidorenko's (1997) baseline: the latest merged sample at or before each t_out [s] (value
    [u]) and, as rate [u/s], the difference of consecutive held values over the tick
    (x_hold[j] - x_hold[j-1]) / (t_out[j] - t_out[j-1]); NaN before the first sample / tick."""
    t, x, _ = merge_streams(times, values, delays)
    t_out = np.asarray(t_out, dtype=float).reshape(-1)
    n_in = np.searchsorted(t, t_out, side="right")
    value = np.where(n_in > 0, x[np.maximum(n_in - 1, 0)], np.nan)
    rate = np.full(t_out.size, np.nan)
    if t_out.size > 1:
        rate[1:] = np.diff(value) / np.diff(t_out)
    return FusedEstimate(t_out, value, rate)
