"""The identifier with exponential forgetting (est.forgetting = mu0 > 0), at the level of
ParameterIdentifier.update (models/estimation/identification.py) rather than of the kernels:

- it tracks a step in A0, where ordinary least squares (mu = 1/n) averages the two cars;
- its Theta-hat is the weighted least squares with the weights the code documents, written out
  by hand with numpy: after n pairs, pair k weighs (1 - mu0)^(n-1-k) (rls_step with a constant
  mu0, eq. (11): R(n) = (1 - mu0) R + mu0 phi phi^T), the first batch's pairs and prior all
  weigh (1 - mu0)^(n-N) (R(N) = J / N, here with N = 1 / mu0 so that R = mu0 J holds from the
  batch on, as _n_info documents);
- its covariance is the sandwich J^-1 M J^-1 of that weighted least squares: J carries the
  weights and the prior at full weight (regularised_forgetting), and the meats W and D the
  squared weights (1 - mu0)^(2(n-1-k)) of the residual covariance (accumulate_meats).

Theta = (1/(P g), A0, A1, A2) [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]; speeds [m/s], forces [N],
grade [permille], dt [s].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from models.estimation.identification import IdentifierConfig, ParameterIdentifier
from models.estimation.least_squares import regression_target, regressor, theta_from_params
from models.units import G

DT = 0.1
TRUE_BEFORE = theta_from_params(32.0, 0.89, 0.0288, 0.010498)   # Rusich resistance in m/s units
A0_AFTER = 2.0                      # [N/kN] the step: a headwind, a dragging brake
N_PAIRS, STEP_AT = 1400, 400        # 140 s, the step at 40 s
SPEED_NOISE = 1e-4                  # [m/s] process noise per sample
MU0 = 0.005                         # memory 1 / mu0 = 200 samples = 20 s


@dataclass
class Run:
    """Measured pairs of one drive: the regressors phi(k) and targets y(k) of eq. (4) too."""
    traction: np.ndarray
    brake: np.ndarray
    speed: np.ndarray               # N_PAIRS + 1 samples
    grade: np.ndarray

    @property
    def phi(self) -> np.ndarray:
        return np.array([regressor(f, b, v) for f, b, v in zip(self.traction, self.brake, self.speed)])

    @property
    def y(self) -> np.ndarray:
        return np.array([regression_target(self.speed[k], self.speed[k + 1], self.grade[k], DT)
                         for k in range(len(self.traction))])


def drive(seed: int, a0_after: float = A0_AFTER) -> Run:
    """Eq. (2) with process noise: traction to 24 m/s, braking to 3 m/s, again, with a slowly
    varying force (the A's need the whole speed range to be told apart), A0 stepping from 0.89
    to A0_AFTER at STEP_AT; grade 3 sin(t / 20 s)."""
    rng = np.random.default_rng(seed)
    speed, traction, brake, grade = [8.0], [], [], []
    accelerating = True
    for k in range(N_PAIRS):
        v = speed[-1]
        accelerating = (v < 24.0) if accelerating else (v < 3.0)
        force = (40e3 if accelerating else -30e3) * (0.6 + 0.4 * math.sin(0.05 * k))
        a0 = a0_after if k >= STEP_AT else TRUE_BEFORE[1]
        i = 3.0 * math.sin(k * DT / 20.0)
        f, b = max(force, 0.0), max(-force, 0.0)
        th = TRUE_BEFORE
        speed.append(v + G / 1000.0 * (th[0] * (f - b) - a0 - th[2] * v - th[3] * v * v - i) * DT
                     + SPEED_NOISE * rng.standard_normal())
        traction.append(f)
        brake.append(b)
        grade.append(i)
    return Run(np.array(traction), np.array(brake), np.array(speed), np.array(grade))


def identify(run: Run, cfg: IdentifierConfig) -> ParameterIdentifier:
    ident = ParameterIdentifier(cfg)
    for k in range(len(run.traction)):
        ident.update(run.traction[k], run.brake[k], run.speed[k], run.speed[k + 1], run.grade[k])
    return ident


@pytest.fixture(scope="module")
def run() -> Run:
    return drive(seed=3)


def resistance(theta, v) -> float:
    """w0(V) = A0 + A1 V + A2 V^2 [N/kN]."""
    return theta[1] + theta[2] * v + theta[3] * v * v


# ------------------------------------------------------------------ tracking

def test_a_forgetting_identifier_tracks_a_step_in_a0(run):
    """1000 samples (5 memories) after A0 steps from 0.89 to 2 N/kN, the forgetting identifier
    has the new car; the ordinary one (same data, same settings but mu0) still averages the
    two. Tolerance 0.1 N/kN: over seeds 0-19 the forgetting identifier's A0 error was at most
    0.04 and its w0 error over 3-24 m/s at most 0.076 (the old car keeps (1 - mu0)^1000 = 0.7 %
    of its weight; the rest is the process noise over the 200 samples it remembers); the
    ordinary identifier missed w0 by at least 0.29 at 12 or 24 m/s."""
    truth = [TRUE_BEFORE[0], A0_AFTER, TRUE_BEFORE[2], TRUE_BEFORE[3]]
    speeds = np.linspace(3.0, 24.0, 8)
    forgetting = identify(run, IdentifierConfig(dt=DT, forgetting=MU0, sigma2_initial=SPEED_NOISE ** 2))
    ordinary = identify(run, IdentifierConfig(dt=DT, forgetting=0.0, sigma2_initial=SPEED_NOISE ** 2))
    assert forgetting.theta[1] == pytest.approx(A0_AFTER, abs=0.1)
    w0_error = [resistance(forgetting.theta, v) - resistance(truth, v) for v in speeds]
    assert max(abs(e) for e in w0_error) < 0.1, w0_error
    missed = [resistance(ordinary.theta, v) - resistance(truth, v) for v in speeds]
    assert max(abs(e) for e in missed) > 0.2, missed      # the data do tell the cars apart
    assert forgetting.mass == pytest.approx(32.0, rel=2e-3)   # the mass, well excited, stays


# ------------------------------------------------------------------ the weighted least squares

def vague_prior(**settings) -> IdentifierConfig:
    """Prior stds 1e6 times the defaults. regularised_forgetting re-adds mu0^2 J0 to R at every
    step without moving Theta-hat, i.e. a pseudo-observation centred on that step's own estimate,
    which no closed form has; made vague, the prior's information is < 1e-12 of the data's."""
    base = IdentifierConfig(dt=DT, **settings)
    for name in ("mass_std_initial", "A0_std_initial", "A1_std_initial", "A2_std_initial"):
        setattr(base, name, getattr(base, name) * 1e6)
    return base


def weights(n: int, batch: int, mu0: float) -> np.ndarray:
    """Pair k's weight after n pairs: (1 - mu0)^(n-1-k) after the batch, (1 - mu0)^(n-batch)
    for the batch's pairs (solved together at pair ``batch``, then forgotten step by step)."""
    lam = 1.0 - mu0
    k = np.arange(n)
    return np.where(k < batch, lam ** (n - batch), lam ** (n - 1 - k))


def test_theta_is_the_exponentially_weighted_least_squares(run):
    """Theta-hat = (sum w phi phi^T + w_N J0)^-1 (sum w phi y + w_N J0 Theta0), the weights
    w above. Tolerance 1e-4 of each component's standard deviation (sqrt of the diagonal of
    that matrix's inverse times the residual variance): measured 3e-10 -- the recursion's
    rounding over 1200 steps and the vague prior's re-additions --, while a mu0 off by 1 %
    moves the reference by 1e-3 (A0) to 1.4e-2 (A2) of a std."""
    batch = round(1.0 / MU0)
    ident = identify(run, vague_prior(forgetting=MU0, batch_size=batch, sigma2_initial=SPEED_NOISE ** 2))
    phi, y = run.phi, run.y
    w = weights(len(y), batch, MU0)
    info = (phi * w[:, None]).T @ phi + w[0] * ident.J0
    theta = np.linalg.solve(info, (phi * w[:, None]).T @ y + w[0] * ident.J0 @ ident.theta0)
    residual_var = (1000.0 / (G * DT) * SPEED_NOISE) ** 2          # y's noise [(N/kN)^2]
    std = np.sqrt(np.diag(np.linalg.inv(info)) * residual_var)
    assert np.all(np.abs(ident.theta - theta) <= 1e-4 * std), (ident.theta - theta) / std
    # and the weights do matter: the unweighted least squares of the same pairs is 4-12 std away
    unweighted = np.linalg.lstsq(phi, y, rcond=None)[0]
    assert np.any(np.abs(unweighted - theta) > 3.0 * std)


def test_covariance_is_the_weighted_least_squares_sandwich(run):
    """cov(Theta-hat) = J^-1 M J^-1 with J = sum w phi phi^T + J0 (regularised_forgetting: the
    data's share forgotten, the prior's kept) and the meat M = a D + b W + a phi_n phi_n^T +
    diag(s2_prior) J0, whose W = sum w^2 phi phi^T and D = sum w^2 (phi(k) - phi(k-1))(...)^T
    (one run from phi(0): its first row alone) carry the squared weights (accumulate_meats).
    a is the identifier's noise_split; b its process share, which sigma2() reports as eq. (12).
    Tolerance: rel 1e-9 on W and D (sums of 1400 products; measured 6e-14) and 1e-6 on the
    covariance, which inverts J (cond(J) 1.6e9 across Theta's scales: two inversions may
    differ by cond eps ~ 4e-7; measured 1e-13)."""
    batch = round(1.0 / MU0)
    ident = identify(run, IdentifierConfig(dt=DT, forgetting=MU0, batch_size=batch))
    phi = run.phi
    w = weights(len(phi), batch, MU0)
    W = (phi * (w ** 2)[:, None]).T @ phi
    steps = np.vstack([phi[:1], np.diff(phi, axis=0)])
    D = (steps * (w ** 2)[:, None]).T @ steps
    np.testing.assert_allclose(ident.W, W, rtol=1e-9)
    np.testing.assert_allclose(ident.D, D, rtol=1e-9)
    J = (phi * w[:, None]).T @ phi + ident.J0
    a, _ = ident.noise_split()
    b = ident.sigma2() * 1e6 / (G * DT) ** 2
    M = a * D + b * W + a * np.outer(phi[-1], phi[-1]) + np.diag(ident.s2_prior) @ ident.J0
    Ji = np.linalg.inv(J)
    np.testing.assert_allclose(ident.covariance(), Ji @ M @ Ji, rtol=1e-6)


# ------------------------------------------------------------------ sigma^2 under forgetting

def test_the_lag_sums_behind_sigma2_forget_as_c0_and_c1_do():
    """cL, the mean square of sums of LAG consecutive residuals (sigma2's process share), takes
    the weights mu0 with forgetting, as c0 and c1 do; it used to keep the whole history, so after
    a step in A0 sigma^2 stayed high for ever (the drive above, 1000 samples after the step:
    280x the no-step run's sigma^2 before, 80x now, the rest the tracking lag's own residuals).
    Residuals of 1 for 500 samples (sums of 50: 2500), then alternating +-1 (sums 0) for 2000:
    with mu0 = 0.005 the first part keeps (1 - mu0)^2000 ~ 4e-5 of its weight (cL ~ 0.1); with
    mu = 1/n it keeps its share of the history (cL ~ 2500 x 451 / 2451 ~ 460)."""
    def fed(forgetting: float) -> float:
        ident = ParameterIdentifier(IdentifierConfig(dt=DT, forgetting=forgetting))
        errors = [1.0] * 500 + [(-1.0) ** k for k in range(2000)]
        for n, e in enumerate(errors, start=1):
            ident._residual_stats(e, True, forgetting if forgetting > 0.0 else 1.0 / n)
        return ident.cL

    assert fed(MU0) < 1.0
    assert fed(0.0) > 100.0


def test_sigma2_comes_back_after_a_step_with_forgetting(run):
    """The drive's step, with forgetting: sigma^2 1000 samples after it within 100x of the same
    drive without the step (measured 80x; 280x while cL kept the whole history)."""
    cfg = IdentifierConfig(dt=DT, forgetting=MU0, sigma2_initial=SPEED_NOISE ** 2)
    stepped = identify(run, cfg).sigma2()
    flat = identify(drive(seed=3, a0_after=TRUE_BEFORE[1]), cfg).sigma2()
    assert stepped < 100.0 * flat
