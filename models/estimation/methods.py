"""The estimator's strategies: how the resistance is identified (``est.method``) and where the
filter's process noise comes from (``est.sigma2_method``), one small class each, chosen once when
``OnlineEstimator`` (models/estimation/online.py) is built: ``identification_method`` and ``noise_model``
map the configured number to the class. An experiment passes objects of its own instead
(``OnlineEstimator(..., method=..., noise=...)``, ``RailCarChain(..., method=..., noise=...)``:
studies/filter_gap.py), e.g. a subclass that overrides one hook.

Identification method hooks, called by the estimator (est), per sample pair or per event:

    record_sample(est, dt, speed, position, use_v, use_x)   every measurement (after the gate)
    record_forces(traction, brake)                         every prediction's forces [N]
    identify(est, traction, brake, speed, speed_next, grade, dt, contiguous)   a pair to use
    skip(est)                                              a pair not identified
    station_stop(est)                                      a confirmed stop, before the mass restart
    resistance()                                           (A's, 3x3 covariance) replacing the LS's, or None
    variance_along(est, phi)                               phi^T cov(model Theta) phi
    filter_theta(est, theta)                               the Theta the filter predicts with

Noise model hooks: ``sigma2(est)``, ``process_noise(est, traction, brake, dt)``, and
``observe(est, speed, use_v)`` / ``predicted(est, speed_before, q, dt)`` for a model that follows
the filter (the likelihood bank). Each object belongs to one estimator (most keep its state).
"""
from __future__ import annotations

import numpy as np

from models.estimation.coast_ekf import CoastEKF, CoastEKFConfig
from models.estimation.differentiation import centred_slope_weights
from models.filtering.motion_filter import ProcessNoiseBank
from models.estimation.identification import check_method, check_sigma2_method
from models.fpmath import square
from models.units import G


# ---------------------------------------------------------------- est.method

class PaperLS:
    """est.method 0: the paper's recursive LS on differenced measured speed, eqs. (3)-(12),
    exactly (models/estimation/identification.py ParameterIdentifier); the base of the other methods."""

    @classmethod
    def from_config(cls, id_cfg, filt_cfg) -> "PaperLS":
        return cls()

    def record_sample(self, est, dt: float, speed_meas: float, position_meas: float,
                      use_v: bool, use_x: bool) -> None:
        pass

    def record_forces(self, traction: float, brake: float) -> None:
        pass

    def identify(self, est, traction: float, brake: float, speed: float, speed_next: float,
                 grade: float, dt: float, contiguous: bool) -> None:
        """The pair (speed, speed_next) [m/s], forces [N] between them, grade [permille], dt [s];
        ``contiguous``: it follows the last pair used."""
        est.ident.update(traction, brake, speed, speed_next, grade, dt, contiguous=contiguous)

    def skip(self, est) -> None:
        pass

    def station_stop(self, est) -> None:
        pass

    def resistance(self):
        """(A's, their 3x3 covariance) that replace the LS's A's, or None (the LS's own)."""
        return None

    def variance_along(self, est, phi) -> float:
        """phi^T cov(model Theta) phi: the filter's model's prediction variance."""
        return est.ident.model_variance_along(phi)

    def filter_theta(self, est, theta: np.ndarray) -> np.ndarray:
        """The Theta the filter predicts with, from the identified one (an experiment may hand
        the filter something else here)."""
        return theta

    def with_resistance(self, theta: np.ndarray) -> np.ndarray:
        """theta with the A's of ``resistance`` when there are any (in place)."""
        carried = self.resistance()
        if carried is not None:
            theta[1:] = carried[0]
        return theta

    def with_resistance_covariance(self, c: np.ndarray) -> np.ndarray:
        """The LS's covariance c with the A's block of ``resistance`` when its A's are used
        (cross terms with the mass then 0)."""
        carried = self.resistance()
        if carried is None:
            return c
        c = c.copy()
        c[1:, :] = 0.0
        c[:, 1:] = 0.0
        c[1:, 1:] = carried[1]
        return c

    def with_resistance_stds(self, sd: tuple) -> tuple:
        """The LS's four stds with the A's of ``resistance`` when its A's are used."""
        carried = self.resistance()
        if carried is None:
            return sd
        return (sd[0], *np.sqrt(np.maximum(np.diag(carried[1]), 0.0)))


class RefitLS(PaperLS):
    """est.method 1: as 0, plus a filter-error refit of each finished run at the next station,
    the A's carried over between runs (models/estimation/output_error/across_runs.py ResistanceCarryOver)."""

    MIN_REFIT_SAMPLES = 100   # a run shorter than this (moving samples) is not refitted

    def __init__(self, id_cfg):
        from models.estimation.output_error import Prior, ResistanceCarryOver
        c = id_cfg
        self.refit = ResistanceCarryOver(Prior.from_std(
            [1.0 / (G * c.mass_initial), c.A0_initial, c.A1_initial, c.A2_initial],
            [None, c.A0_std_initial, c.A1_std_initial, c.A2_std_initial]),
            forgetting=c.run_forgetting)
        self.failures = 0                  # refits that failed (the A's learnt so far kept)
        self.run = {"t": [], "v": [], "x": [], "f": [], "b": []}   # samples of the current run
        self.t = 0.0                       # time since the run's first sample [s]

    @classmethod
    def from_config(cls, id_cfg, filt_cfg) -> "RefitLS":
        return cls(id_cfg)

    def record_sample(self, est, dt, speed_meas, position_meas, use_v, use_x) -> None:
        run = self.run
        if run["t"]:
            self.t += dt
        run["t"].append(self.t)
        # a refused measurement enters the run's record as the filter's prediction of it
        run["v"].append(speed_meas if use_v else est.filter.predicted_speed)
        run["x"].append(position_meas if use_x else est.filter.predicted_position)

    def record_forces(self, traction, brake) -> None:
        self.run["f"].append(traction)
        self.run["b"].append(brake)

    def resistance(self):
        return (self.refit.A, self.refit.cov_A) if self.refit.runs else None

    def station_stop(self, est) -> None:
        """Fit the run that just ended by filter error (the mass fresh, the A's with the weak
        base prior) and add its information on the A's to what earlier runs gave; the run's
        buffer is then cleared."""
        run = self.run
        v = np.asarray(run["v"])
        moving = np.nonzero(np.abs(v) > est.station.v_thr)[0]
        try:
            if moving.size >= self.MIN_REFIT_SAMPLES:
                a, b = max(moving[0] - 1, 0), min(moving[-1] + 2, len(v), len(run["f"]) + 1)
                sl = slice(a, b)
                q = est.sigma2() / est.dt_nominal
                self.refit.fit(np.asarray(run["t"][sl]), v[sl], np.asarray(run["f"][a:b - 1]),
                               np.asarray(run["b"][a:b - 1]), distance=np.asarray(run["x"][sl]),
                               grade_profile=est.grade_profile, length=est.length, gamma=est.gamma,
                               fit_mass=True, mass=est.ident.mass, mass_std=None,
                               speed_std=est.filter.cfg.speed_std,
                               distance_std=est.filter.cfg.position_std,
                               process_noise_psd=q, method="filter_error")
        except (ValueError, ArithmeticError, np.linalg.LinAlgError):
            self.failures += 1                # keep the A's learnt so far
        last = (run["v"][-1], run["x"][-1])   # the current sample starts the next run
        for k in run:
            run[k].clear()
        self.t = 0.0
        run["t"].append(0.0)
        run["v"].append(last[0])
        run["x"].append(last[1])


class SlopeLS(PaperLS):
    """est.method 2: the LS fed with Sidorenko's (1997) speed and acceleration: a first-order
    least-squares fit over the last est.slope_window contiguous samples (docs/estimation.md),
    at the window's mean time, with the forces and grade weighted as the slope weights the
    intervals (differentiation.centred_slope_weights). The value and the slope of that fit are
    uncorrelated, so the errors-in-variables bias of V in phi and in y goes away. Sidorenko's
    M + 1 = 6 is at a sampling period the source does not state; 10 by default: at 0.1 s, w0
    after ten runs 2.13 % -> 1.90 % RMS over 100 days, measured with the A's prior
    white-weighted, before it took the process-noise weight (README)."""

    def __init__(self, window: int):
        self.size = int(window)
        self.v: list = []             # the window's speeds [m/s]
        self.i: list = []             # and its intervals' (F, B, grade, dt)
        self.contiguous = False       # the last row fed follows the one before
        self.dts = None               # the intervals the weights are for
        self.weights = None

    @classmethod
    def from_config(cls, id_cfg, filt_cfg) -> "SlopeLS":
        return cls(id_cfg.slope_window)

    def identify(self, est, traction, brake, speed, speed_next, grade, dt, contiguous) -> None:
        """One regression row per new sample, once the window is full: phi's V is the fit's
        value V_c, y the slope a_c (passed as the pair V_c, V_c + a_c dt_nominal), forces [N]
        and grade [permille] the slope's weighted means over the window's intervals."""
        if not contiguous:            # a new contiguous stretch starts at the previous sample
            self.v = [speed]
            self.i = []
            self.contiguous = False
        self.v.append(speed_next)
        self.i.append((traction, brake, grade, dt))
        if len(self.v) > self.size:
            del self.v[0], self.i[0]
        if len(self.v) < self.size:
            return
        dts = [x[3] for x in self.i]
        if dts != self.dts:           # constant at a fixed sampling period: computed once
            self.dts, self.weights = dts, centred_slope_weights(dts)
        slope_w, c = self.weights
        v_c = sum(self.v) / self.size
        a_c = sum(k * v for k, v in zip(slope_w, self.v))
        f = sum(cj * x[0] for cj, x in zip(c, self.i))
        b = sum(cj * x[1] for cj, x in zip(c, self.i))
        g = sum(cj * x[2] for cj, x in zip(c, self.i))
        step = est.dt_nominal
        est.ident.update(f, b, v_c, v_c + a_c * step, g, step, contiguous=self.contiguous)
        self.contiguous = True


class CoastLS(PaperLS):
    """est.method 3: LS for the mass, Meleshin's (2011) coasting EKF (state [V, A0, A1, A2], docs/estimation.md; models/estimation/coast_ekf.py) for the A's: it runs over every coasting interval
    (F = B = 0) and carries its A's and their covariance from coast to coast and run to run."""

    MIN_COAST_SAMPLES = 50   # coasting samples before the EKF's A's are reported

    def __init__(self, id_cfg, speed_std: float, speed_std_rel: float = 0.0):
        c = id_cfg
        self.ekf = CoastEKF(CoastEKFConfig(
            A0=c.A0_initial, A1=c.A1_initial, A2=c.A2_initial, A0_std=c.A0_std_initial,
            A1_std=c.A1_std_initial, A2_std=c.A2_std_initial, speed_std=max(speed_std, 1e-6),
            process_noise_psd=c.sigma2_initial / c.dt, gamma=c.gamma, speed_std_rel=speed_std_rel))
        self.coasting = False         # the last pair used was a coasting one

    @classmethod
    def from_config(cls, id_cfg, filt_cfg) -> "CoastLS":
        return cls(id_cfg, filt_cfg.speed_std, filt_cfg.speed_std_rel)

    def ready(self) -> bool:
        """The EKF has seen MIN_COAST_SAMPLES coasting samples."""
        return self.ekf.samples >= self.MIN_COAST_SAMPLES

    def identify(self, est, traction, brake, speed, speed_next, grade, dt, contiguous) -> None:
        """The LS, then a coasting interval (no force applied) goes to the EKF. A new coast
        restarts its speed from the measurement and keeps the A's and their covariance
        (CoastEKF.carry_over); its process noise is the identified sigma^2 per second."""
        super().identify(est, traction, brake, speed, speed_next, grade, dt, contiguous)
        if traction != 0.0 or brake != 0.0:
            self.coasting = False
            return
        ekf = self.ekf
        ekf.cfg.process_noise_psd = est.sigma2() / est.dt_nominal
        if not self.coasting:
            ekf.carry_over(speed)
            self.coasting = True
        ekf.step(dt, speed_next, grade)

    def skip(self, est) -> None:
        self.coasting = False

    def station_stop(self, est) -> None:
        """The EKF's A covariance grows by 1 / (1 - f) per stop, f = est.run_forgetting (it keeps
        no separate prior, so the whole of it is forgotten alike)."""
        f = est.ident.cfg.run_forgetting
        if f > 0.0 and self.ekf.x is not None:
            self.ekf.P[1:, 1:] /= 1.0 - f

    def resistance(self):
        return (self.ekf.A, self.ekf.cov_A) if self.ready() else None

    def variance_along(self, est, phi) -> float:
        """Once the EKF is ready: the mass's variance from the LS, the A's from the EKF."""
        if not self.ready():
            return est.ident.model_variance_along(phi)
        c = self.with_resistance_covariance(est.ident.model_covariance())
        return float(np.dot(phi, c @ phi))


METHODS = {0: PaperLS, 1: RefitLS, 2: SlopeLS, 3: CoastLS}


def identification_method(id_cfg, filt_cfg) -> PaperLS:
    """A new method object for ``id_cfg.method``; ValueError (IdentifierConfig's) for a bad one."""
    return METHODS[check_method(id_cfg.method)].from_config(id_cfg, filt_cfg)


# ---------------------------------------------------------------- est.sigma2_method

class ResidualNoise:
    """est.sigma2_method 0: sigma^2 from the LS's residuals (eq. (12) on LAG sums,
    ParameterIdentifier.sigma2); the base of the other noise models."""

    @classmethod
    def from_config(cls, id_cfg, filt_cfg) -> "ResidualNoise":
        return cls()

    def sigma2(self, est) -> float:
        """Process-noise variance per sample [(m/s)^2]."""
        return est.ident.sigma2()

    def process_noise(self, est, traction: float, brake: float, dt: float) -> float:
        """The filter's process noise over dt [(m/s)^2]: sigma^2 per sample scaled to dt, plus
        the parameter-uncertainty term (OnlineEstimator.parameter_noise)."""
        parameters = est.parameter_noise(traction, brake, dt)
        return self.sigma2(est) * dt / est.dt_nominal + parameters

    def observe(self, est, speed_meas: float, use_v: bool) -> None:
        pass

    def predicted(self, est, speed_before: float, q: float, dt: float) -> None:
        pass


class LikelihoodNoise(ResidualNoise):
    """est.sigma2_method 1: sigma^2 from the innovation likelihood of a bank of speed filters
    (filters.ProcessNoiseBank) that follows the learning filter while the car moves."""

    def __init__(self, q0: float, speed_variance: float, variance_at=None):
        self.bank = ProcessNoiseBank(q0, speed_variance, variance_at=variance_at)

    @classmethod
    def from_config(cls, id_cfg, filt_cfg) -> "LikelihoodNoise":
        variance_at = (lambda z: square(filt_cfg.speed_noise_std(z))) if filt_cfg.speed_std_rel else None
        return cls(id_cfg.sigma2_initial, square(filt_cfg.speed_std), variance_at)

    def sigma2(self, est) -> float:
        return self.bank.estimate()

    def observe(self, est, speed_meas: float, use_v: bool) -> None:
        """A measured speed [m/s] the gate took (use_v); the bank stops while the car stands."""
        if not est.station.moving:
            self.bank.stand()
        elif use_v:
            self.bank.update(speed_meas)

    def predicted(self, est, speed_before: float, q: float, dt: float) -> None:
        """The filter predicted from speed_before [m/s] with process noise q [(m/s)^2]: the
        members move with it, with its parameter term."""
        if est.station.moving:
            self.bank.predict(est.filter.predicted_speed - speed_before,
                              q - self.sigma2(est) * dt / est.dt_nominal)


class KnownNoise(ResidualNoise):
    """sigma^2 given [(m/s)^2 per sample], e.g. the truth for an oracle or a study; without
    ``parameter_term`` the process noise is sigma^2 alone (a filter that knows Theta)."""

    def __init__(self, sigma2: float, parameter_term: bool = True):
        self.value = sigma2
        self.parameter_term = parameter_term

    def sigma2(self, est) -> float:
        return self.value

    def process_noise(self, est, traction: float, brake: float, dt: float) -> float:
        if self.parameter_term:
            return super().process_noise(est, traction, brake, dt)
        return self.value * dt / est.dt_nominal


NOISE_MODELS = {0: ResidualNoise, 1: LikelihoodNoise}


def noise_model(id_cfg, filt_cfg) -> ResidualNoise:
    """A new noise model for ``id_cfg.sigma2_method``; ValueError (IdentifierConfig's) for a
    bad one."""
    return NOISE_MODELS[check_sigma2_method(id_cfg.sigma2_method)].from_config(id_cfg, filt_cfg)
