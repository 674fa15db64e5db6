"""The filter-error method and the process-noise likelihood (models/estimation/output_error/): a
Kalman filter around eq. (2) with its gains held (Maine & Iliff 1985, "Identification of dynamic
systems: theory and formulation", NASA RP-1138; Jategaonkar 2015, chapter "Filter error method"):
the gains and innovation factors (``riccati``), the whitened innovations (``filter_pass``) and
their Jacobian (``filter_jacobian``); then the process-noise density q by (restricted) maximum
likelihood pooled over several fits (``estimate_process_noise_psd``).

Units: time [s], speed [m/s], distance [m], q [m^2/s^3], Theta as in priors.py.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.optimize import minimize_scalar

from models.estimation.output_error.simulation import Segment, rk4_stages, step_derivatives
from models.plant.dynamics import acceleration_polynomial


# Its own 2x2 Kalman algebra, not models.filtering.kalman's: the likelihood needs K = P S^-1 and S's
# Cholesky factor, which the paper's (17)-(18) form (mirrored by core/filter.c) does not give.
def riccati(seg: Segment, a: np.ndarray, cx: np.ndarray, q: float):
    """Kalman gains and innovation Cholesky factors along the segment (scalar loop, 2 states).

    State (V, X), transition [[a, 0], [cx, 1]] of the RK4 step, white-acceleration process
    noise of density q [m^2/s^3] (Q = q [[h, h^2/2], [h^2/2, h^3/3]]), measurement V (and X)
    with R = diag(speed_std^2, distance_std^2). The initial state is a fitted parameter: P = 0
    at the first sample. Returns lists K11, K12, K21, K22, l11, l21, l22 and sum log det S.
    """
    n = len(seg.time)
    h = np.diff(seg.time).tolist()
    al, cl = a.tolist(), cx.tolist()
    rv = seg.speed_std ** 2
    use_x = seg.distance is not None
    rx = seg.distance_std ** 2 if use_x else 0.0
    K11, K12, K21, K22 = [0.0] * n, [0.0] * n, [0.0] * n, [0.0] * n
    l11, l21, l22 = [0.0] * n, [0.0] * n, [1.0] * n
    p11 = p12 = p22 = 0.0
    logdet = 0.0
    for j in range(n):
        if use_x:
            s11, s12, s22 = p11 + rv, p12, p22 + rx
            det = s11 * s22 - s12 * s12
            k11 = (p11 * s22 - p12 * s12) / det
            k12 = (p12 * s11 - p11 * s12) / det
            k21 = (p12 * s22 - p22 * s12) / det
            k22 = (p22 * s11 - p12 * s12) / det
            q11 = p11 - (k11 * p11 + k12 * p12)
            q12 = p12 - (k11 * p12 + k12 * p22)
            q22 = p22 - (k21 * p12 + k22 * p22)
            a11 = math.sqrt(s11)
            a21 = s12 / a11
            a22 = math.sqrt(max(s22 - a21 * a21, 1e-300))
            logdet += 2.0 * (math.log(a11) + math.log(a22))
            K11[j], K12[j], K21[j], K22[j] = k11, k12, k21, k22
            l11[j], l21[j], l22[j] = a11, a21, a22
        else:
            s11 = p11 + rv
            k11 = p11 / s11
            k21 = p12 / s11
            q11 = p11 - k11 * p11
            q12 = p12 - k11 * p12
            q22 = p22 - k21 * p12
            a11 = math.sqrt(s11)
            logdet += 2.0 * math.log(a11)
            K11[j], K21[j] = k11, k21
            l11[j] = a11
        if j < n - 1:
            hj, aj, cj = h[j], al[j], cl[j]
            p11 = aj * aj * q11 + q * hj
            p12 = aj * (cj * q11 + q12) + 0.5 * q * hj * hj
            p22 = cj * cj * q11 + 2.0 * cj * q12 + q22 + q * hj * hj * hj / 3.0
    return (K11, K12, K21, K22, l11, l21, l22), logdet


def filter_pass(theta, v0: float, x0: float, seg: Segment, gains):
    """Eq. (2) as a predictor-corrector with fixed gains (scalar loop): RK4 prediction from
    the corrected state, correction by the gains. Returns the whitened innovations e (m, n)
    (m = 2 with distances), the stage speeds W (n-1, 4), the rest flags and the corrected V."""
    K11, K12, K21, K22, l11, l21, l22 = gains
    c0, b1, b2 = acceleration_polynomial(theta, seg.fnet, seg.grade, seg.k)   # eq. (2)
    gl = c0.tolist()
    hl = np.diff(seg.time).tolist()
    vm = seg.speed.tolist()
    use_x = seg.distance is not None
    xm = seg.distance.tolist() if use_x else None
    n = len(vm)
    e1, e2 = [0.0] * n, [0.0] * n
    w_out = [0.0] * (4 * (n - 1))
    rest = [False] * (n - 1)
    vhat = [0.0] * n
    v, x = float(v0), float(x0)
    for j in range(n):
        nv = vm[j] - v
        if use_x:
            nx = xm[j] - x
            v, x = v + K11[j] * nv + K12[j] * nx, x + K21[j] * nv + K22[j] * nx
            u1 = nv / l11[j]
            e1[j] = u1
            e2[j] = (nx - l21[j] * u1) / l22[j]
        else:
            v, x = v + K11[j] * nv, x + K21[j] * nv
            e1[j] = nv / l11[j]
        vhat[j] = v
        if j == n - 1:
            break
        hj = hl[j]
        hh = 0.5 * hj
        gj = gl[j]
        w1 = v if v > 0.0 else 0.0
        k1 = gj - b1 * w1 - b2 * w1 * w1
        r = 4 * j
        if v <= 0.0 and k1 <= 0.0:
            rest[j] = True
            v = 0.0
            continue
        w2, w3, w4, k2, k3, k4 = rk4_stages(v, k1, gj, b1, b2, hh, hj)
        w_out[r], w_out[r + 1], w_out[r + 2], w_out[r + 3] = v, w2, w3, w4
        x = x + hj / 6.0 * (v + 2.0 * w2 + 2.0 * w3 + w4)
        v = v + hj / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        if v < 0.0:
            v = 0.0
            rest[j] = True
    e = np.array([e1, e2]) if use_x else np.array([e1])
    return e, np.array(w_out).reshape(n - 1, 4), np.array(rest, dtype=bool), np.array(vhat)


def filter_jacobian(theta, seg: Segment, gains, W, rest, cols, n_par: int) -> np.ndarray:
    """d e / d p (m n, n_par) of the whitened innovations, gains held (the filter-error
    method's usual simplification: here the gains depend on Theta only through the step
    derivative a = 1 - O(1e-4)). p = (Theta[cols of 0..3], V0, X0)."""
    K11, K12, K21, K22, l11, l21, l22 = (np.asarray(g) for g in gains)
    h = np.diff(seg.time)
    a, cx, Bv, Bx = step_derivatives(theta, h, seg.fnet, W, rest, seg.k)
    n = len(seg.time)
    use_x = seg.distance is not None
    # sensitivities of the predicted state: s[j+1] = A_j (I - K_j H) s[j] + B_j
    Mt = np.zeros((n - 1, 2, 2))
    if use_x:
        i11, i12, i21, i22 = 1.0 - K11[:-1], -K12[:-1], -K21[:-1], 1.0 - K22[:-1]
    else:
        i11, i12, i21, i22 = 1.0 - K11[:-1], np.zeros(n - 1), -K21[:-1], np.ones(n - 1)
    Mt[:, 0, 0] = a * i11
    Mt[:, 0, 1] = a * i12
    Mt[:, 1, 0] = cx * i11 + i21
    Mt[:, 1, 1] = cx * i12 + i22
    Bf = np.zeros((n - 1, 2, n_par))
    th_cols = [c for c in cols if c < 4]
    Bf[:, 0, :len(th_cols)] = Bv[:, th_cols]
    Bf[:, 1, :len(th_cols)] = Bx[:, th_cols]
    S = np.empty((n, 2, n_par))
    s = np.zeros((2, n_par))
    s[0, len(th_cols)] = 1.0                    # V0
    if n_par > len(th_cols) + 1:
        s[1, len(th_cols) + 1] = 1.0            # X0
    S[0] = s
    for j in range(n - 1):
        s = Mt[j] @ s + Bf[j]
        S[j + 1] = s
    de1 = -S[:, 0, :] / l11[:, None]
    if not use_x:
        return de1
    de2 = (-S[:, 1, :] - l21[:, None] * de1) / l22[:, None]
    return np.concatenate([de1, de2])


# ------------------------------------------------------------------------- process noise

def process_noise_nll(fits, q: float, restricted: bool = True) -> float:
    """-2 log-likelihood (up to a constant) of the fits' data under process noise density q
    [m^2/s^3], each fit's parameters held: the sum of log det S_k + e_k^T e_k over the
    innovations of the Kalman filter around eq. (2) (the filter-error likelihood).

    ``restricted``: plus log det(J^T J + prior information) of each fit's parameters (restricted
    / residual maximum likelihood, Patterson & Thompson 1971, Biometrika 58: the parameters'
    degrees of freedom are not charged to the noise): the fitted parameters absorb part of the
    random walk, and without this term q comes out ~13 % low on ten station-to-station runs
    (measured; with it within ~5 %).
    """
    tot = 0.0
    for f in fits:
        seg = f.segment
        gains, logdet = riccati(seg, f.diagnostics["step_a"], f.diagnostics["step_cx"], q)
        x0 = f.x0 if seg.distance is not None else 0.0
        e, W, rest, _ = filter_pass(f.theta, f.v0, x0, seg, gains)
        tot += logdet + float(np.sum(e * e))
        if restricted:
            cols = f.diagnostics["cols"]
            th_idx = [c for c in cols if c < 4]
            n_par = f.diagnostics["n_params"]
            J = filter_jacobian(f.theta, seg, gains, W, rest, cols, n_par)
            H = J.T @ J
            if f.prior is not None:
                H[:len(th_idx), :len(th_idx)] += f.prior.info[np.ix_(th_idx, th_idx)]
            d = np.sqrt(np.maximum(np.diag(H), 1e-300))
            _, ld = np.linalg.slogdet(H / np.outer(d, d))
            tot += ld + 2.0 * float(np.sum(np.log(d)))
    return tot


def estimate_process_noise_psd(fits, bounds=(1e-7, 1e-2), restricted: bool = True) -> float:
    """Process-noise density q [m^2/s^3] pooled over several fits, by (restricted) maximum
    likelihood: ``process_noise_nll`` minimised over log q in ``bounds`` (the noise-parameter
    step of the filter-error method, Maine & Iliff 1985). Measurement-noise stds are the fits'
    own (give the sensor's configured stds to ``fit_segment``: the likelihood trades q against
    R, so a few % error in an estimated R moves q by tens of %). One two-minute segment pins q
    down only to a factor ~1.5; pooling a day's runs is what makes it usable (ten runs: ~10 %).
    """
    fits = [f for f in fits if f.segment is not None]
    if not fits:
        return float("nan")
    lo, hi = math.log10(bounds[0]), math.log10(bounds[1])
    res = minimize_scalar(lambda lq: process_noise_nll(fits, 10.0 ** lq, restricted),
                          bounds=(lo, hi), method="bounded", options={"xatol": 0.01})
    return float(10.0 ** res.x)
