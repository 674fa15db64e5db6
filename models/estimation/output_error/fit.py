"""Fitting one segment (models/estimation/output_error/): ``fit_segment`` by output error or by
filter error (Levenberg-Marquardt on the whitened residuals, priors as extra residuals), its
result ``OutputErrorFit`` (the estimate, an honest covariance under process noise, the data's
information on the A's) and ``fit_initial_state`` (V0, X0 with Theta held).

Units: time [s], speed [m/s], distance [m], force [N], mass [t], grade [permille], Theta as in
priors.py. The method and its sources: the package docstring (models/estimation/output_error/__init__.py).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from scipy.optimize import least_squares

from models.estimation.output_error.filter_error import filter_jacobian, filter_pass, riccati
from models.estimation.output_error.priors import DEFAULT_THETA, Prior
from models.estimation.output_error.simulation import (
    Segment, Trajectory, grade_per_interval, linear_recurrence, net_force_per_interval,
    noise_std_from_differences, reference_track, simulate,
)
from models.plant.dynamics import resistance_eq1
from models.plant.track import GradeProfile
from models.units import G


@dataclass
class OutputErrorFit:
    """Result of ``fit_segment``. Units: Theta as THETA_NAMES, speed [m/s], distance [m]."""
    theta: np.ndarray              # (4,) Theta-hat (Theta1 held if not fit_mass)
    cov: np.ndarray                # (4, 4) covariance of Theta-hat: output error with q: the
    #                                sandwich; filter error, or no q given: (J^T J)^-1 s^2
    cov_white: np.ndarray          # (4, 4) (J^T J)^-1 s^2 of the method's own residuals
    v0: float                      # fitted initial speed [m/s]
    v0_std: float
    x0: float                      # fitted initial distance [m] (nan if distances not fitted)
    fit_mass: bool
    n: int                         # samples
    speed_std: float               # measurement-noise std used for the speed residuals [m/s]
    distance_std: float            # ... for the distance residuals [m] (nan if not fitted)
    process_noise_psd: float       # q used in ``cov`` [m^2/s^3] (nan: white covariance)
    s2: float                      # residual variance of the whitened data residuals [-]
    speed_rms: float               # RMS of simulated - measured speed [m/s]
    distance_rms: float            # ... distance [m]
    speed_sim: np.ndarray          # simulated speed at the samples [m/s]
    distance_sim: np.ndarray       # simulated distance [m]
    speed_residual: np.ndarray     # measured - simulated speed [m/s]
    time: np.ndarray               # sample times [s]
    prior: Prior | None
    nfev: int
    success: bool
    message: str
    method: str = "output_error"   # or "filter_error"
    segment: "Segment | None" = None   # the data as fitted (for estimate_process_noise_psd)
    diagnostics: dict = field(default_factory=dict)

    @property
    def A(self) -> np.ndarray:
        """(A0, A1, A2) [N/kN, N/kN/(m/s), N/kN/(m/s)^2]."""
        return self.theta[1:].copy()

    @property
    def cov_A(self) -> np.ndarray:
        """Covariance of (A0, A1, A2): the mass and the initial state integrated out (3x3)."""
        return self.cov[1:, 1:].copy()

    @property
    def mass(self) -> float:
        """P-hat [t] (the effective mass P (1 + gamma) if gamma is set to 0 for a car with
        rotating masses, docs/model.md, Forces on the car)."""
        return 1.0 / (G * self.theta[0]) if self.theta[0] > 0 else float("inf")

    @property
    def mass_std(self) -> float:
        """Std of P-hat [t], delta method: std(Theta1) / (g Theta1^2); 0 when the mass is held."""
        return math.sqrt(max(self.cov[0, 0], 0.0)) / (G * self.theta[0] ** 2)

    def w0(self, v) -> np.ndarray:
        """Identified w0(V) [N/kN] at speeds v [m/s], eq. (1)."""
        return resistance_eq1(np.asarray(v, dtype=float), *self.theta[1:])

    def w0_std(self, v) -> np.ndarray:
        """Std of the identified w0(V) [N/kN] at speeds v [m/s]."""
        v = np.atleast_1d(np.asarray(v, dtype=float))
        phi = np.column_stack([np.ones_like(v), v, v * v])
        return np.sqrt(np.einsum("ij,jk,ik->i", phi, self.cov_A, phi))

    def A_data_information(self) -> tuple[np.ndarray, np.ndarray]:
        """(J_d, h_d): the information on the A's that this segment's data (with its own
        mass prior) carries, without the prior on the A's, and the matching information vector
        (h_d = J_d A_d for the data-only estimate A_d): what ``fuse_estimates`` adds up, so a
        prior common to several fits is not counted several times.

        Computed in ``fit_segment`` from the honest (sandwich) covariance of the estimator
        without the A-prior, J_loc = H (H + M)^-1 H (H the local Gauss-Newton information, M
        the process-noise meat), then the mass and the initial state marginalised out (Schur
        complement): positive semi-definite by construction.
        """
        return self.diagnostics["A_info_data"].copy(), self.diagnostics["A_h_data"].copy()


def _remember_last(fn):
    """fn(p) for a parameter vector p, kept for the last p only: least_squares asks for the
    residuals and the Jacobian at the same p, and both need the same trajectory."""
    last: dict = {}

    def remembered(p):
        key = p.tobytes()
        if key not in last:
            last.clear()
            last[key] = fn(p)
        return last[key]
    return remembered


def _theta_start(prior: Prior | None, theta0, mass: float | None) -> np.ndarray:
    th = DEFAULT_THETA.copy()
    if prior is not None:
        has = np.diag(prior.info) > 0.0
        th[has] = prior.mean[has]
    if mass:
        th[0] = 1.0 / (G * mass)
    if theta0 is not None:
        th = np.asarray(theta0, dtype=float).copy()
    return th


def fit_segment(time, speed, traction=None, brake=None, *, distance=None,
                grade_profile: GradeProfile | None = None, grade=None, length: float = 0.0,
                gamma: float = 0.0, fit_mass: bool | None = None, mass: float | None = None,
                prior: Prior | None = None, use_distance: bool = True,
                speed_std: float | None = None, distance_std: float | None = None,
                process_noise_psd: float | None = None, method: str = "output_error",
                theta0=None, max_nfev: int = 50) -> OutputErrorFit:
    """Fit Theta (and V0, X0) to one segment of samples by output error (or filter error).

    time [s] (n,) sample instants; speed [m/s] (n,) measured; traction, brake [N] applied over
    each interval [t_k, t_k+1] (n-1 values, or n with the last ignored; None = 0); distance [m]
    (n,) measured, or None; grade: a ``grade_profile`` evaluated along the reference track
    (``reference_track``) averaged over ``length`` [m], or ``grade`` (n-1,) [permille] per
    interval, or neither (level); gamma the rotating-mass factor [-].

    fit_mass: None = automatic (fitted iff some interval has F - B != 0); when not fitted,
    Theta1 is held at 1/(g mass) (or the prior's / default value; irrelevant when F = B = 0).
    prior: Gaussian prior on Theta (``Prior``). speed_std [m/s], distance_std [m]: measurement
    noise; None = estimated from second differences (``noise_std_from_differences``).
    process_noise_psd q [m^2/s^3]: for method "output_error", None = ``cov`` is the white
    formula (J^T J)^-1 s^2, a number >= 0 = the sandwich with that random-walk process noise.

    method: "output_error" (deterministic simulation, the default) or "filter_error" (needs
    q > 0): the output-error solution refined by the filter-error method, Maine & Iliff (1986)
    NASA RP-1168 / Jategaonkar (2015) ch. 5: the residuals are the whitened innovations of a
    Kalman filter around eq. (2) (gains at the output-error solution, then held), i.e. the
    maximum-likelihood estimate under process plus measurement noise. Its residuals are white,
    so (J^T J)^-1 s^2 is honest; it does not chase the process noise's random walk (about 1.7
    times smaller std of w0 at low speed on a station-to-station run), but its A's therefore
    reproduce one particular coast less closely than output error's.
    """
    if method not in ("output_error", "filter_error"):
        raise ValueError(f"method must be 'output_error' or 'filter_error', got {method!r}")
    if method == "filter_error" and not (process_noise_psd and process_noise_psd > 0.0):
        raise ValueError("method 'filter_error' needs process_noise_psd > 0 [m^2/s^3]")
    t = np.asarray(time, dtype=float)
    v_meas = np.asarray(speed, dtype=float)
    n = len(t)
    if n < 3 or v_meas.shape != (n,):
        raise ValueError("fit_segment needs >= 3 samples and one speed per sample time")
    if np.any(np.diff(t) <= 0.0):
        raise ValueError("sample times must increase")
    fnet = net_force_per_interval(traction, brake, n - 1)
    x_meas = None if distance is None else np.asarray(distance, dtype=float)
    if x_meas is not None and x_meas.shape != (n,):
        raise ValueError("distance needs one value per sample time")
    if grade is not None:
        grade_iv = np.asarray(grade, dtype=float)[: n - 1]
        if grade_iv.shape != (n - 1,):
            raise ValueError(f"grade needs {n - 1} values, one per sample interval")
    else:
        track = reference_track(t, v_meas, x_meas)
        grade_iv = grade_per_interval(track, grade_profile, length)
    if fit_mass is None:
        fit_mass = bool(np.any(fnet != 0.0))
    use_x = use_distance and x_meas is not None
    sv = speed_std if speed_std is not None else noise_std_from_differences(v_meas)
    sv = max(float(sv), 1e-9)
    sx = float("nan")
    if use_x:
        sx = distance_std if distance_std is not None else noise_std_from_differences(x_meas)
        sx = max(float(sx), 1e-9)
    seg = Segment(t, v_meas, x_meas if use_x else None, fnet, grade_iv, float(gamma), sv, sx)

    th_start = _theta_start(prior, theta0, mass)
    th_idx = [0, 1, 2, 3] if fit_mass else [1, 2, 3]
    n_th = len(th_idx)
    L_pr, mu_pr = prior.whitener(th_idx) if prior is not None else (np.zeros((0, n_th)), np.zeros(n_th))
    # parameter vector p = (Theta[th_idx], V0[, X0])
    p0 = np.concatenate([th_start[th_idx], [float(np.mean(v_meas[:3]))]])
    if use_x:
        p0 = np.concatenate([p0, [float(x_meas[0])]])
    n_par = len(p0)
    cols = th_idx + [4]                                   # columns of Trajectory.dv / dx used

    def unpack(p):
        th = th_start.copy()
        th[th_idx] = p[:n_th]
        v0 = p[n_th]
        x0 = p[n_th + 1] if use_x else 0.0
        return th, v0, x0

    def prior_jac():
        Jp = np.zeros((L_pr.shape[0], n_par))
        Jp[:, :n_th] = L_pr
        return Jp

    # ---- output error
    traj = _remember_last(lambda p: simulate(*unpack(p), t, fnet, grade_iv, gamma))

    def residuals(p):
        tr = traj(p)
        parts = [(tr.speed - v_meas) / sv]
        if use_x:
            parts.append((tr.distance - x_meas) / sx)
        parts.append(L_pr @ (p[:n_th] - mu_pr))
        return np.concatenate(parts)

    def jacobian(p):
        tr = traj(p)
        Jv = tr.dv[:, cols] / sv
        if use_x:
            Jv = np.concatenate([Jv, np.zeros((n, 1))], axis=1)
            Jx = np.concatenate([tr.dx[:, cols], np.ones((n, 1))], axis=1) / sx
            blocks = [Jv, Jx]
        else:
            blocks = [Jv]
        blocks.append(prior_jac())
        return np.concatenate(blocks, axis=0)

    scale = np.concatenate([np.array([DEFAULT_THETA[0], 1.0, 0.03, 0.01])[th_idx], [0.1],
                            [1.0] if use_x else []])
    sol = least_squares(residuals, p0, jac=jacobian, method="lm", x_scale=scale,
                        xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
    nfev = int(sol.nfev)
    p = sol.x
    th, v0, x0 = unpack(p)
    tr = traj(p)
    m_data = n * (2 if use_x else 1)
    M = None
    diag = {}
    if method == "output_error":
        J = jacobian(p)
        r = residuals(p)
        q = float("nan") if process_noise_psd is None else float(process_noise_psd)
    else:
        # ---- filter error, starting from the output-error solution
        q = float(process_noise_psd)
        gains, _ = riccati(seg, tr.a, tr.cx, q)
        def _fpass(pp):
            thp, v0p, x0p = unpack(pp)
            return filter_pass(thp, v0p, x0p if use_x else 0.0, seg, gains)
        fpass = _remember_last(_fpass)

        def f_residuals(pp):
            e = fpass(pp)[0]
            return np.concatenate([e.ravel(), L_pr @ (pp[:n_th] - mu_pr)])

        def f_jacobian(pp):
            _, W, rest, _ = fpass(pp)
            thp = unpack(pp)[0]
            Je = filter_jacobian(thp, seg, gains, W, rest, cols, n_par)
            return np.concatenate([Je, prior_jac()])

        sol = least_squares(f_residuals, p, jac=f_jacobian, method="lm", x_scale=scale,
                            xtol=1e-10, ftol=1e-10, gtol=1e-10, max_nfev=max_nfev)
        nfev += int(sol.nfev)
        p = sol.x
        th, v0, x0 = unpack(p)
        tr = traj(p)
        J = f_jacobian(p)
        r = f_residuals(p)
        diag["innovations"] = fpass(p)[0]
    Jd, Jp = J[:m_data], J[m_data:]
    rd = r[:m_data]
    dof = max(m_data - n_par, 1)
    s2 = float(rd @ rd) / dof
    H = Jd.T @ Jd + Jp.T @ Jp
    Hw = Jd.T @ Jd / s2 + Jp.T @ Jp
    cov_w_p = np.linalg.inv(Hw)
    if method == "output_error" and process_noise_psd is not None:
        Hi = np.linalg.inv(H)
        M = _process_noise_meat(tr, Jd, n, use_x, q, t, sv, sx)
        cov_p = Hi @ (H + M) @ Hi
    else:
        cov_p = cov_w_p
    A_info, A_h = _data_information(Jd, Jp, s2, M, p, prior, th_idx, fit_mass)
    cov4 = np.zeros((4, 4))
    cov4w = np.zeros((4, 4))
    cov4[np.ix_(th_idx, th_idx)] = cov_p[:n_th, :n_th]
    cov4w[np.ix_(th_idx, th_idx)] = cov_w_p[:n_th, :n_th]
    res_v = v_meas - tr.speed
    diag.update({"cost": float(sol.cost), "optimality": float(sol.optimality),
                 "cov_params": cov_p, "grade_mean": float(grade_iv.mean()),
                 "A_info_data": A_info, "A_h_data": A_h, "step_a": tr.a, "step_cx": tr.cx,
                 "cols": cols, "n_params": n_par})
    return OutputErrorFit(
        theta=th, cov=cov4, cov_white=cov4w, v0=float(v0),
        v0_std=math.sqrt(max(cov_p[n_th, n_th], 0.0)),
        x0=float(x0) if use_x else float("nan"), fit_mass=fit_mass, n=n, speed_std=sv,
        distance_std=sx, process_noise_psd=q, s2=s2,
        speed_rms=float(np.sqrt(np.mean(res_v ** 2))),
        distance_rms=float(np.sqrt(np.mean((x_meas - tr.distance) ** 2))) if use_x else float("nan"),
        speed_sim=tr.speed, distance_sim=tr.distance, speed_residual=res_v, time=t, prior=prior,
        nfev=nfev, success=bool(sol.success), message=str(sol.message), method=method,
        segment=seg, diagnostics=diag)


def fit_initial_state(theta, time, speed, traction=None, brake=None, *, distance=None,
                      grade_profile: GradeProfile | None = None, grade=None, length: float = 0.0,
                      gamma: float = 0.0, speed_std: float | None = None,
                      distance_std: float | None = None) -> tuple[float, float]:
    """(V0 [m/s], X0 [m]) that best fit the segment with Theta held: the initial state of the
    recomputed run of a given model (Meleshin (2011) re-runs each coast with the identified
    coefficients; this is the start that run needs). Arguments as ``fit_segment``; X0 is nan
    without distances."""
    t = np.asarray(time, dtype=float)
    v_meas = np.asarray(speed, dtype=float)
    n = len(t)
    fnet = net_force_per_interval(traction, brake, n - 1)
    x_meas = None if distance is None else np.asarray(distance, dtype=float)
    if grade is not None:
        grade_iv = np.asarray(grade, dtype=float)[: n - 1]
    else:
        grade_iv = grade_per_interval(reference_track(t, v_meas, x_meas), grade_profile, length)
    sv = max(float(speed_std if speed_std is not None else noise_std_from_differences(v_meas)), 1e-9)
    sx = float("nan")
    if x_meas is not None:
        sx = max(float(distance_std if distance_std is not None
                       else noise_std_from_differences(x_meas)), 1e-9)
    theta = np.asarray(theta, dtype=float)

    def res_jac(p):
        tr = simulate(theta, p[0], p[1] if x_meas is not None else 0.0, t, fnet, grade_iv, gamma)
        r = [(tr.speed - v_meas) / sv]
        J = [np.column_stack([tr.dv[:, 4], np.zeros(n)])[:, :len(p)] / sv]
        if x_meas is not None:
            r.append((tr.distance - x_meas) / sx)
            J.append(np.column_stack([tr.dx[:, 4], np.ones(n)]) / sx)
        return np.concatenate(r), np.concatenate(J)

    p0 = [float(np.mean(v_meas[:3]))] + ([float(x_meas[0])] if x_meas is not None else [])
    sol = least_squares(lambda p: res_jac(p)[0], np.array(p0), jac=lambda p: res_jac(p)[1],
                        method="lm", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    return float(sol.x[0]), (float(sol.x[1]) if x_meas is not None else float("nan"))


def _data_information(Jd, Jp, s2, M, p, prior, th_idx, fit_mass):
    """(J_A, h_A) of the segment's data without the A-prior (see A_data_information).

    Linearised at the optimum p: with H_loc = Jd^T Jd + (the prior's mass block) and the prior
    on the A's J_pA, the local estimate satisfies H_loc p_loc = H p - J_pA mu (H the full
    Gauss-Newton information); its robust covariance is H_loc^-1 (H_loc + M) H_loc^-1, so its
    information is H_loc (H_loc + M)^-1 H_loc. Without process noise M = (s2 - 1) Jd^T Jd
    (the white formula (J^T J)^-1 s2).
    """
    n_p = len(p)
    Hd = Jd.T @ Jd
    Jpr = Jp.T @ Jp
    a_idx = [1, 2, 3] if fit_mass else [0, 1, 2]
    JpA = np.zeros((n_p, n_p))
    JpA[np.ix_(a_idx, a_idx)] = Jpr[np.ix_(a_idx, a_idx)]
    Jpn = Jpr - JpA                  # the mass prior (and any mass-A cross term) stays local
    mu = np.zeros(n_p)
    if prior is not None:
        mu[:len(th_idx)] = prior.mean[th_idx]
    H = Hd + Jpr
    H_loc = Hd + Jpn
    if M is None:
        M = (s2 - 1.0) * Hd
    G_ = np.linalg.solve(H_loc + M, H_loc)           # (H_loc + M)^-1 H_loc
    I_loc = H_loc @ G_
    I_loc = 0.5 * (I_loc + I_loc.T)
    h_loc = G_.T @ (H @ p - JpA @ mu)
    n_idx = [j for j in range(n_p) if j not in a_idx]
    Inn = I_loc[np.ix_(n_idx, n_idx)]
    IAn = I_loc[np.ix_(a_idx, n_idx)]
    K = np.linalg.solve(Inn, IAn.T).T                 # I_An I_nn^-1
    J_A = I_loc[np.ix_(a_idx, a_idx)] - K @ IAn.T
    h_A = h_loc[a_idx] - K @ h_loc[n_idx]
    return 0.5 * (J_A + J_A.T), h_A


def _process_noise_meat(tr: Trajectory, Jd: np.ndarray, n: int, use_x: bool, q: float,
                        t: np.ndarray, sv: float, sx: float) -> np.ndarray:
    """M_q = sum_m q h_m u_m u_m^T: Jd^T W Sigma_q W Jd for the random-walk residual part.

    A process-noise kick w_m ~ N(0, q h_m) at the end of interval m moves the true speed at
    every later sample k > m by Phi(k, m+1) w_m (Phi the product of the RK4 step derivatives
    a) and the distance by sum_j cx_j Phi(j, m+1) w_m. So u_m = sum_{k > m} dV_k/dw_m Jv_k +
    dX_k/dw_m Jx_k, computed backwards: U_k = z_k + a_k U_{k+1} with z_k = Jv_k + cx_k T_{k+1},
    T_k = sum_{j >= k} Jx_j, and u_m = U_{m+1}.
    """
    h = np.diff(t)
    Jv = Jd[:n]
    T = np.zeros_like(Jv)
    if use_x:
        Jx = Jd[n:2 * n]
        T = np.cumsum(Jx[::-1], axis=0)[::-1]              # T_k = sum_{j >= k} Jx_j
        T = np.concatenate([T, np.zeros((1, Jv.shape[1]))])
    z = Jv / sv                                            # k = 0..n-1
    if use_x:
        z[:-1] += tr.cx[:, None] * T[1:n] / sx
    # backward: U_{n-1} = z_{n-1}; U_k = z_k + a_k U_{k+1}
    a = tr.a
    rev = linear_recurrence(a[::-1], z[-2::-1], z[-1])    # rev[j] = U_{n-1-j}
    U = rev[::-1]                                          # U[k], k = 0..n-1
    u = U[1:]                                              # u_m = U_{m+1}, m = 0..n-2
    return q * (u * h[:, None]).T @ u
