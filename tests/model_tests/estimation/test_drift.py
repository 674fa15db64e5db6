"""The carried A's drift per station stop (est.A0_drift_std, est.A1_drift_std): what it means.

At each mass restart the carried A0, A1 are taken to have moved by eps ~ N(0, diag(q0^2, q1^2))
since their data were taken (a wind change between runs moves A0 by A2 Vw^2, A1 by 2 A2 Vw), in
the stated covariance only: the drift meat Dq gains Jc Q Jc (Jc the data's information on the
A's as carried) and the covariance J^-1 Dq J^-1 (J^-1 symmetrised). Checked here: the algebra
against numpy's, the meaning (with data that dominate the prior the A's variance grows by q^2
exactly, Theta-hat untouched), no bit changes with both stds 0, and the refusals by name. The C
twin: tests/model_tests/core/test_core_ident.py and test_core_chain.py (bit for bit).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from fmu_src.adapter import chain_config
from fmu_src.variables import RAILCAR, variables_for
from models.estimation.identification import IdentifierConfig, ParameterIdentifier
from models.units import G

DT = 0.1
Q0, Q1 = 0.05, 0.03          # [N/kN], [N/kN/(m/s)] per stop: studies/service_day.py's figures


def runs(n_runs: int, seed: int = 3):
    """Events of a car running n_runs runs (traction 60 s, coasting 30 s, speed noise 0.05 m/s),
    a mass restart after each: ("update", args) or ("restart",)."""
    rng = np.random.default_rng(seed)
    mass, a0, a1, a2 = 42.0, 1.3, 0.025, 0.009
    events = []
    for _ in range(n_runs):
        v, vm, contiguous = 1.0, 1.0, False
        for k in range(900):
            F = 35e3 if k < 600 else 0.0
            resist = F / (mass * G) - a0 - a1 * v - a2 * v * v
            v_next = v + G * DT / 1000.0 * resist + 0.003 * rng.standard_normal()
            vm_next = v_next + 0.05 * rng.standard_normal()
            events.append(("update", (F, 0.0, vm, vm_next, 0.0, DT), contiguous))
            v, vm, contiguous = v_next, vm_next, True
        events.append(("restart",))
        mass = float(rng.uniform(35.0, 55.0))
    return events


def play(ident: ParameterIdentifier, events) -> ParameterIdentifier:
    for ev in events:
        if ev[0] == "update":
            ident.update(*ev[1], contiguous=ev[2])
        else:
            ident.restart_mass()
    return ident


def pair(events, **kw):
    """The same data through an identifier without and one with the drift."""
    plain = play(ParameterIdentifier(IdentifierConfig(speed_std=0.05, **kw)), events)
    drift = play(ParameterIdentifier(IdentifierConfig(speed_std=0.05, A0_drift_std=Q0, A1_drift_std=Q1,
                                                      **kw)), events)
    return plain, drift


@pytest.mark.parametrize("method", [0, 2])
@pytest.mark.parametrize("run_forgetting", [0.0, 0.3])
def test_a_restart_adds_jc_q_jc_to_the_meat_and_its_sandwich_to_the_covariance(method, run_forgetting):
    """Against numpy: Dq after a restart is T Dq T^T lam (marginalised, forgotten) + Jc Q Jc with
    Jc = lam (n sym(R_AA - R_A0 R_0A / R_00) - diag(j0_A)); the covariance gains Js Dq Js, Js the
    symmetrised J^-1 = S / n. Theta-hat is the no-drift identifier's, bit for bit."""
    events = runs(3)
    lam = 1.0 - run_forgetting
    plain, drift = pair(events[:-1], method=method, run_forgetting=run_forgetting)   # before the 3rd restart
    Dq0, R, n, j0 = drift.Dq, np.linalg.inv(drift.S), drift.n, np.array(drift._j0)
    assert np.any(Dq0 != 0.0)                                    # two restarts' drift in it
    plain.restart_mass()
    drift.restart_mass()
    t = R[1:, 0] / R[0, 0]
    T = np.hstack([-t[:, None], np.eye(3)])
    RA = R[1:, 1:] - np.outer(R[1:, 0], R[0, 1:]) / R[0, 0]
    Jc = lam * (0.5 * (RA + RA.T) * n - np.diag(j0[1:]))
    want = np.zeros((4, 4))
    want[1:, 1:] = T @ Dq0 @ T.T * lam + Jc @ np.diag([Q0 * Q0, Q1 * Q1, 0.0]) @ Jc
    np.testing.assert_allclose(drift.Dq, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)))
    Js = 0.5 * (drift.S + drift.S.T) / n
    added = drift.covariance() - plain.covariance()
    np.testing.assert_allclose(added, Js @ drift.Dq @ Js, rtol=1e-9, atol=1e-12 * np.max(np.abs(added)))
    assert np.array_equal(drift.theta, plain.theta) and drift.mass == plain.mass
    assert drift.mass_std() == pytest.approx(
        math.sqrt(plain.covariance()[0, 0] + added[0, 0]) / (G * drift.theta[0] ** 2), rel=1e-12)


def test_with_data_that_dominate_the_prior_the_as_variance_grows_by_q_squared():
    """The meaning: when the data's information on the A's is all there is (a prior 100-1000x
    wider than the defaults), J^-1 Jc is the identity on the A's and a restart adds
    diag(q0^2, q1^2, 0) to their stated covariance (to the prior's small share); A2 does not drift."""
    wide = dict(A0_std_initial=1e3, A1_std_initial=1e2, A2_std_initial=10.0)
    plain, drift = pair(runs(1), **wide)
    added = (drift.covariance() - plain.covariance())[1:, 1:]
    np.testing.assert_allclose(np.diag(added), [Q0 * Q0, Q1 * Q1, 0.0], rtol=2e-3, atol=1e-9)
    assert abs(added[0, 1]) < 1e-2 * Q0 * Q1 and abs(added[1, 2]) < 1e-6


def test_the_stated_as_widen_at_each_restart_the_mass_with_them_and_the_estimates_stay():
    """est.method 2 over five runs: after each restart the stated A0, A1 stds exceed the
    no-drift identifier's, 30 s into the next run est.mass_std does too, and Theta-hat is the
    no-drift identifier's throughout."""
    cfg = dict(speed_std=0.05, run_forgetting=0.3, method=2)
    plain = ParameterIdentifier(IdentifierConfig(**cfg))
    drift = ParameterIdentifier(IdentifierConfig(**cfg, A0_drift_std=Q0, A1_drift_std=Q1))
    for ev in runs(5) + runs(1, seed=9)[:300]:
        play(plain, [ev])
        play(drift, [ev])
        assert np.array_equal(drift.theta, plain.theta)
        if ev[0] == "restart":
            assert drift.stds()[1] > plain.stds()[1] and drift.stds()[2] > plain.stds()[2]
    assert drift.mass_std() > 1.001 * plain.mass_std()


def test_zero_drift_changes_no_bit():
    """Both stds 0 (the default), or -0.0: every state and output is the default identifier's,
    bit for bit (the drift's code is not entered)."""
    events = runs(3)
    configs = [IdentifierConfig(speed_std=0.05, run_forgetting=0.3),
               IdentifierConfig(speed_std=0.05, run_forgetting=0.3, A0_drift_std=0.0, A1_drift_std=-0.0)]
    a, b = (ParameterIdentifier(c) for c in configs)
    for ev in events:
        play(a, [ev])
        play(b, [ev])
        assert (a.S is None) == (b.S is None)
        for x, y in ((a.theta, b.theta), (a.covariance(), b.covariance()), (a.W, b.W), (a.D, b.D),
                     *(((a.S, b.S),) if a.S is not None else ())):
            assert np.array_equal(np.asarray(x).view(np.uint64), np.asarray(y).view(np.uint64))
    assert not np.any(b.Dq) and a.mass_restarts == 3


@pytest.mark.parametrize("name,value,rule", [
    ("A0_drift_std", -0.01, r"\[0, 10\] N/kN per stop"), ("A0_drift_std", math.nan, r"\[0, 10\]"),
    ("A0_drift_std", 10.5, r"\[0, 10\]"), ("A1_drift_std", math.inf, r"\[0, 1\] N/kN/\(m/s\) per stop"),
    ("A1_drift_std", -1e-300, r"\[0, 1\]")])
def test_a_bad_drift_is_refused_by_name(name, value, rule):
    with pytest.raises(ValueError, match=rf"^est\.{name} must be in {rule}"):
        IdentifierConfig(**{name: value}).validate()


@pytest.mark.parametrize("method", [1, 3])
def test_a_method_that_carries_its_own_as_refuses_a_drift_naming_both(method):
    IdentifierConfig(method=method).validate()
    for drift in ({"A0_drift_std": 0.05}, {"A1_drift_std": 0.03}):
        with pytest.raises(ValueError, match=rf"^est\.A0_drift_std and est\.A1_drift_std apply to est\.method 0 "
                                             rf"and 2 .* with est\.method {method}$"):
            IdentifierConfig(method=method, **drift).validate()


def test_the_fmu_parameters_reach_the_identifier():
    values = {v.name: v.start for v in variables_for(RAILCAR) if v.causality == "parameter"}
    assert values["est.A0_drift_std"] == 0.0 and values["est.A1_drift_std"] == 0.0
    ident = chain_config({**values, "est.A0_drift_std": 0.05, "est.A1_drift_std": 0.03}).identifier
    assert (ident.A0_drift_std, ident.A1_drift_std) == (0.05, 0.03)
