"""Output-error (trajectory) identification of the resistance and the mass from one segment.

The paper's least squares (Gorbachev et al. 2015, eqs. (3)-(12),
``models.estimation.identification``) regresses the *differenced measured* speed: its target y(n)
carries ~sqrt(2) sigma_V 1000/(g dt) of noise and the regressors V, V^2 are noisy too
(docs/model.md, Identification), so the A's are lost. Output-error fitting instead simulates eq. (2)
deterministically from a fitted initial state and fits the *simulated* trajectory to the measured
one: measurement noise enters only the residuals, never the regressors, and the estimator is
consistent.

Method (cited): the output-error method, Maine & Iliff (1986), "Application of parameter
estimation to aircraft stability and control: the output-error approach", NASA RP-1168;
Jategaonkar (2015), "Flight Vehicle System Identification", 2nd ed., AIAA, chapter "Output error
method" (Gauss-Newton / Levenberg-Marquardt on simulated-minus-measured outputs, sensitivities
of the simulated states, Cramer-Rao covariance (J^T J)^-1 s^2). The model is eq. (2) of the paper
in continuous time with Meleshin's (2011) rotating-mass factor gamma (as ``models.plant.dynamics``):

    dV/dt = g/1000 / (1 + gamma) * ( Theta1 (F - B) - A0 - A1 V - A2 V^2 - i )     [m/s^2]
    dX/dt = V                                                                    [m/s]
    Theta = (1/(P g), A0, A1, A2)          [1/kN, N/kN, N/kN/(m/s), N/kN/(m/s)^2]

with the applied forces F, B [N] held between samples (their mean over the interval, what
``models.chain`` gives the estimator) and the grade i [permille] known. Integrated by one
classical RK4 step per sample interval (the plant ``models.plant.dynamics.rk4_step`` uses the same
scheme); the Jacobian is the exact derivative of that RK4 recursion (forward sensitivities,
vectorised from the stored stage speeds; a 2000-sample segment fits in ~20 ms).

Grade: a known input held per sample interval: its mean over the distance covered in the
interval, along a reference track built from the measurements (the trapezoid integral of the
measured speed anchored to the measured distances by least squares, error ~0.1 m over minutes),
averaged over the car ``length`` as ``GradeProfile.average`` does. The fitted trajectory
therefore depends on Theta only through V, as in eq. (2) where i[n] is a known input.

Fitted parameters: Theta (or only the A's when the segment has no force excitation, F = B = 0,
e.g. a coast: 1/(Pg) is then unobservable and held, its value irrelevant), the initial speed
V0 [m/s] and, when distances are fitted, the initial distance X0 [m]. Gaussian priors on Theta
(``Prior``: mean and information) enter as extra whitened residuals (maximum a posteriori),
which keeps A0, A2 physical on short or narrow-speed-range segments (``physical_prior``).

Process noise, and why the white covariance is not enough. The brief's premise "measurement
noise is white in output-error form" holds for the measurement noise, but a real car (and our
plant, ``car.process_noise_psd``: white acceleration noise of density q [m^2/s^3]) also has
process noise: the true speed random-walks away from any deterministic trajectory, residuals
are correlated over the whole segment, and (J^T J)^-1 s^2 (``cov_white``) is 4-14 times too
small in std on a station-to-station run (measured). Two honest options, both given q:

- ``method="output_error"``, ``process_noise_psd=q``: the same estimate, covariance the sandwich
  H^-1 (H + M_q) H^-1 (Huber 1967, White 1982), M_q = sum_m q h_m u_m u_m^T the random walk's
  share of the normal equations (u_m by one backward recursion through the linearised
  dynamics, ``_process_noise_meat``).
- ``method="filter_error"``: the filter-error method (Maine & Iliff 1985, "Identification of
  dynamic systems: theory and formulation", NASA RP-1138; Jategaonkar 2015, chapter "Filter
  error method"): the residuals are the whitened innovations of a Kalman filter around eq. (2)
  (gains at the output-error solution, then held), i.e. maximum likelihood under process plus
  measurement noise. Residuals are white again, so (J^T J)^-1 s^2 is honest, and it is
  efficient: on a station-to-station run the std of w0 at 2 m/s is 0.22 N/kN against output
  error's 0.40 (the generalised-least-squares Cramer-Rao bound is 0.23, measured).

q itself is estimated by restricted maximum likelihood over several fits
(``estimate_process_noise_psd``), given the sensors' configured noise stds.

Across station stops (Gorbachev et al.: "P is constant between two stations; A0..A2 drift slowly"):
each fit exports its data information on the A's with the mass and initial state integrated out
(``OutputErrorFit.A_data_information``); ``fuse_estimates`` adds them up information-weighted
with optional forgetting between runs, ``ResistanceCarryOver`` does it run by run: the A's carry
over while the mass restarts at each stop.

Units: time [s], speed [m/s], distance [m], force [N], mass [t], grade [permille],
Theta as above. Pure numpy/scipy, no I/O.

Modules, in the order they build on each other: ``priors`` (Prior, physical_prior),
``simulation`` (the segment's inputs, eq. (2) simulated with its sensitivities), ``filter_error``
(the filter-error residuals, the process-noise likelihood), ``fit`` (fit_segment, OutputErrorFit,
fit_initial_state), ``across_runs`` (fuse_estimates, ResistanceCarryOver). The public names are
re-exported here: ``from models.estimation.output_error import fit_segment``.
"""
from models.estimation.output_error.across_runs import ResistanceCarryOver, fuse_estimates
from models.estimation.output_error.filter_error import estimate_process_noise_psd, process_noise_nll
from models.estimation.output_error.fit import OutputErrorFit, fit_initial_state, fit_segment
from models.estimation.output_error.priors import (
    DEFAULT_THETA, THETA_NAMES, Prior, mass_prior_std_theta1, physical_prior,
)
from models.estimation.output_error.simulation import (
    Segment, Trajectory, grade_per_interval, net_force_per_interval, noise_std_from_differences,
    reference_track, simulate,
)

__all__ = [
    "DEFAULT_THETA", "THETA_NAMES", "OutputErrorFit", "Prior", "ResistanceCarryOver", "Segment",
    "Trajectory", "estimate_process_noise_psd", "fit_initial_state", "fit_segment", "fuse_estimates",
    "grade_per_interval", "mass_prior_std_theta1", "net_force_per_interval",
    "noise_std_from_differences", "physical_prior", "process_noise_nll", "reference_track", "simulate",
]
