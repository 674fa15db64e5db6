"""Priors on Theta for the output-error fit (models/estimation/output_error/): Gaussian priors in
information form (``Prior``), the weak prior that keeps the A's physical (``physical_prior``) and a
mass prior's std in Theta units.

Theta = (1/(P g), A0, A1, A2) [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2], the paper's parameters
(Gorbachev et al. 2015, eq. (2)); mass [t].
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from models.units import G

THETA_NAMES = ("theta1", "A0", "A1", "A2")
"""Names of Theta's components: 1/(P g) [1/kN], A0 [N/kN], A1 [N/kN/(m/s)], A2 [N/kN/(m/s)^2]."""

DEFAULT_THETA = np.array([1.0 / (G * 30.0), 1.0, 0.03, 0.01])
"""Starting point when no prior is given: 30 t and the estimator's default est.A*_initial."""


@dataclass(frozen=True)
class Prior:
    """Gaussian prior on Theta = (1/(P g), A0, A1, A2) in information form.

    ``mean`` (4,) in Theta units; ``info`` (4, 4) the inverse covariance, with zero rows and
    columns for components that have no prior (e.g. the mass of a fresh run).
    """
    mean: np.ndarray
    info: np.ndarray

    @classmethod
    def from_std(cls, mean, std) -> "Prior":
        """Independent priors: std[j] = inf, nan or None means no prior on component j."""
        mean = np.asarray(mean, dtype=float).reshape(4)
        info = np.zeros((4, 4))
        for j, s in enumerate(std):
            if s is not None and math.isfinite(s) and s > 0.0:
                info[j, j] = 1.0 / (s * s)
        return cls(mean, info)

    @classmethod
    def from_A(cls, A, cov_A, mass: float | None = None, mass_std: float | None = None) -> "Prior":
        """Prior with A = (A0, A1, A2) of covariance ``cov_A`` (3x3, correlations kept) and an
        optional independent mass prior mass [t] +- mass_std [t] (delta method on 1/(P g))."""
        mean = np.empty(4)
        info = np.zeros((4, 4))
        mean[1:] = np.asarray(A, dtype=float)
        info[1:, 1:] = np.linalg.inv(np.asarray(cov_A, dtype=float))
        mean[0] = 1.0 / (G * mass) if mass else DEFAULT_THETA[0]
        if mass and mass_std and math.isfinite(mass_std) and mass_std > 0.0:
            th1_std = mass_std / (G * mass * mass)
            info[0, 0] = 1.0 / th1_std ** 2
        return cls(mean, 0.5 * (info + info.T))

    def A_info(self) -> np.ndarray:
        """Marginal information of (A0, A1, A2) (the mass integrated out) (3x3)."""
        I = self.info
        if I[0, 0] > 0.0:
            return I[1:, 1:] - np.outer(I[1:, 0], I[0, 1:]) / I[0, 0]
        return I[1:, 1:].copy()

    def whitener(self, idx: list[int]) -> tuple[np.ndarray, np.ndarray]:
        """(L, mean) with L^T L = info restricted to Theta components ``idx`` (rows of zero
        information dropped): the prior residual is L (theta - mean)."""
        I = self.info[np.ix_(idx, idx)]
        w, U = np.linalg.eigh(0.5 * (I + I.T))
        keep = w > 1e-12 * max(float(w.max()), 1e-300) if w.size else np.zeros(0, bool)
        L = (np.sqrt(w[keep])[:, None] * U[:, keep].T) if keep.any() else np.zeros((0, len(idx)))
        return L, self.mean[idx]


def mass_prior_std_theta1(mass: float, mass_std: float) -> float:
    """Std of Theta1 = 1/(P g) [1/kN] for a mass prior mass +- mass_std [t] (delta method)."""
    return mass_std / (G * mass * mass)


def physical_prior(mass: float | None = None, mass_std: float | None = None) -> Prior:
    """A weak prior that keeps the A's physical: A0 = 1 +- 1 N/kN, A1 = 0.03 +- 0.03
    N/kN/(m/s), A2 = 0.01 +- 0.01 N/kN/(m/s)^2 (1 sigma), independent.

    Centred on the estimator's default est.A*_initial; one sigma spans the resistance of metro
    and suburban cars in m/s units (Meleshin's (2011) Table 1: A0 0.11-0.89, A1 0.004-0.029, A2
    0.004-0.012), so the truth lies within 1-2 sigma for all four rows. Plus an optional mass
    prior mass [t] +- mass_std [t].
    """
    std = [None, 1.0, 0.03, 0.01]
    mean = [DEFAULT_THETA[0], 1.0, 0.03, 0.01]
    if mass:
        mean[0] = 1.0 / (G * mass)
        if mass_std:
            std[0] = mass_prior_std_theta1(mass, mass_std)
    return Prior.from_std(mean, std)
