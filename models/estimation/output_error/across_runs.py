"""Across station stops (models/estimation/output_error/): the A's of several fits fused by their
data information (``fuse_estimates``), and run by run with the mass restarting at each stop
(``ResistanceCarryOver``; Gorbachev et al. 2015: "P is constant between two stations; A0..A2
drift slowly").

Units: A0 [N/kN], A1 [N/kN/(m/s)], A2 [N/kN/(m/s)^2], mass [t].
"""
from __future__ import annotations

import numpy as np

from models.estimation.output_error.fit import OutputErrorFit, fit_segment
from models.estimation.output_error.priors import Prior, mass_prior_std_theta1, physical_prior
from models.units import G


def fuse_estimates(fits, forgetting: float = 0.0, prior: Prior | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Information-weighted fusion of several segments' (A0, A1, A2): returns (A, cov_A).

    ``fits``: OutputErrorFit objects (their own priors are removed first, so a prior common
    to all fits is not counted n times: ``A_data_information``) or (A, cov_A) pairs (taken as
    pure data). Runs are taken in order; before each run the information so far is multiplied
    by (1 - forgetting) (exponential forgetting, the constant-mu0 forgetting of Gorbachev et
    al.'s eq. (8)-(11) applied per run instead of per sample), so slowly drifting A's are followed.
    ``prior``: added once at the start (its A-block, mass integrated out).
    """
    J = np.zeros((3, 3))
    hv = np.zeros(3)
    if prior is not None:
        J = prior.A_info()
        hv = J @ prior.mean[1:]
    lam = 1.0 - forgetting
    for f in fits:
        if isinstance(f, OutputErrorFit):
            Jd, hd = f.A_data_information()
        else:
            A, C = f
            Jd = np.linalg.inv(np.asarray(C, dtype=float))
            hd = Jd @ np.asarray(A, dtype=float)
        J = lam * J + Jd
        hv = lam * hv + hd
    cov = np.linalg.inv(0.5 * (J + J.T))
    return cov @ hv, cov


class ResistanceCarryOver:
    """Sequential identification across station stops (thin stateful wrapper).

    The A's carry over from run to run while the mass restarts at each stop (Gorbachev et al.: "P is
    constant between two stations; A0..A2 drift slowly"). Each run is fitted on its own, with
    only the weak ``base_prior`` (physical A's, a fresh mass prior), and its *data*
    information on the A's (``OutputErrorFit.A_data_information``: the mass and the initial
    state integrated out, the base prior removed) is added to the state, whose information is
    first multiplied by (1 - forgetting) per run.

    Why not use the A's learnt so far as the next fit's prior: under process noise an
    output-error fit weighs its data by J^T J (white residuals assumed), several times their
    true information (the sandwich ``cov``); the carried prior would be drowned and the state
    would follow the last run (measured on ten station-to-station runs: w0 error 6-31 % against
    1-3.5 % with this fusion). Information fusion with the honest covariance weighs every run
    correctly. (With method="filter_error" both ways agree: its residuals are white.) So with
    output error and q given, the state after one run is not the fit's own (prior-weighted)
    estimate but the better-weighted combination of the same data and prior.
    """

    def __init__(self, base_prior: Prior | None = None, forgetting: float = 0.0):
        self.base_prior = base_prior if base_prior is not None else physical_prior()
        self.forgetting = float(forgetting)
        self._J = self.base_prior.A_info()
        self._h = self._J @ self.base_prior.mean[1:]
        self.runs = 0
        self.fits: list[OutputErrorFit] = []

    @property
    def A(self) -> np.ndarray:
        """(A0, A1, A2) learnt so far [N/kN, N/kN/(m/s), N/kN/(m/s)^2]."""
        return self.cov_A @ self._h

    @property
    def cov_A(self) -> np.ndarray:
        """Their covariance (3x3)."""
        return np.linalg.inv(0.5 * (self._J + self._J.T))

    def prior(self, mass: float | None = None, mass_std: float | None = None) -> Prior:
        """The weak prior each run is fitted with: the base prior's A's and a fresh mass prior
        mass [t] +- mass_std [t] (none if not given)."""
        bp = self.base_prior
        mean = bp.mean.copy()
        info = bp.info.copy()
        info[0, :] = 0.0
        info[:, 0] = 0.0
        if mass:
            mean[0] = 1.0 / (G * mass)
            if mass_std:
                info[0, 0] = 1.0 / mass_prior_std_theta1(mass, mass_std) ** 2
        return Prior(mean, info)

    def fit(self, *args, mass: float | None = None, mass_std: float | None = None,
            **kwargs) -> OutputErrorFit:
        """``fit_segment(*args, prior=self.prior(mass, mass_std), mass=mass, **kwargs)``, then
        ``update`` with it; returns the run's fit (its own A's, not the fused ones)."""
        f = fit_segment(*args, prior=self.prior(mass, mass_std), mass=mass, **kwargs)
        self.update(f)
        return f

    def update(self, f: OutputErrorFit) -> None:
        """Add one run's data information on the A's (forgetting the old by 1 - forgetting)."""
        Jd, hd = f.A_data_information()
        lam = 1.0 - self.forgetting if self.runs else 1.0
        J0 = self.base_prior.A_info()
        h0 = J0 @ self.base_prior.mean[1:]
        # forgetting acts on the data information only: the base prior is never forgotten
        # (regularised forgetting, as models.estimation.identification does against wind-up)
        self._J = J0 + lam * (self._J - J0) + Jd
        self._h = h0 + lam * (self._h - h0) + hd
        self.runs += 1
        self.fits.append(f)
