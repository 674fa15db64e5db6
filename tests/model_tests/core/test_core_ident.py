"""The C identification (models/core/ident.c, linalg4.c) against models.estimation.identification, bit for bit.

ParameterIdentifier for est.method 0 is driven in C (through tests/core_cases/ident_shim.c) and
in Python alike, and after every call the whole state (theta, S, W, D, J, q_e, s2, c0, c1, cL, the LAG window, counters, the running estimate,
the open run's regressor and residual) and every output (model theta and covariance, the
covariance, stds, mass, mass_std, sigma2, samples, the noise split) are compared by their bits.
The rows come from a simulated car (traction, coasting, braking, station stops, grades, speed
noise 0.05 m/s, dt 0.1 s) with runs broken by skipped pairs and mass restarts, and from random
rows; the rare paths (first batch, forgetting, run_forgetting, the positive-definiteness repair
at an update and at a restart) are all met.
"""
from __future__ import annotations

import ctypes
import math
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

from models import linalg4
from models.estimation.identification import IdentifierConfig, ParameterIdentifier
from models.units import G

ROOT = Path(__file__).resolve().parents[3]
CORE = ROOT / "models" / "core"
SHIM = ROOT / "tests" / "core_cases" / "ident_shim.c"
SOURCES = [CORE / "ident.c", CORE / "linalg4.c", CORE / "fpmath.c"]
FLAGS = ["-std=c99", "-O2", "-ffp-contract=off", "-Wall", "-Wextra", "-Werror", "-pedantic"]
LAG = ParameterIdentifier.LAG
N_STATE = 4 + 2 + 4 + 4 + 4 + 4 + 1 + 4 + 16 + 4 + 4 + 1 + 16 + 6 + 16 + 16 + 1 + 4 + 2 + 4 + LAG + 5 + 16 + 16
N_OUT = 4 + 16 + 1 + 16 + 4 + 4 + 2
D = ctypes.POINTER(ctypes.c_double)


def build_lib(directory: Path, sources=SOURCES):
    """The shim and ``sources`` (ident.c, linalg4.c, fpmath.c or a mutated copy) as a ctypes
    library."""
    gcc = shutil.which("gcc")
    assert gcc, "gcc is needed to build the C core"
    so = directory / "libident.so"
    subprocess.run([gcc, *FLAGS, "-fPIC", "-shared", f"-I{CORE}", str(SHIM), *map(str, sources),
                    "-o", str(so), "-lm"], check=True, capture_output=True, text=True)
    dll = ctypes.CDLL(str(so))
    dll.shim_new.argtypes = [D]
    dll.shim_new.restype = ctypes.c_void_p
    dll.shim_free.argtypes = [ctypes.c_void_p]
    dll.shim_reset.argtypes = [ctypes.c_void_p]
    dll.shim_update.argtypes = [ctypes.c_void_p] + [ctypes.c_double] * 6 + [ctypes.c_int]
    dll.shim_restart_mass.argtypes = [ctypes.c_void_p]
    dll.shim_set_theta.argtypes = [ctypes.c_void_p, D]
    dll.shim_set_S.argtypes = [ctypes.c_void_p, D]
    dll.shim_state.argtypes = [ctypes.c_void_p, D]
    dll.shim_state.restype = ctypes.c_long
    dll.shim_outputs.argtypes = [ctypes.c_void_p, D, D]
    dll.shim_outputs.restype = ctypes.c_long
    dll.shim_la_solve.argtypes = [D, D, ctypes.c_int, D]
    dll.shim_la_inverse.argtypes = [D, ctypes.c_int, D]
    dll.shim_la_is_pd.argtypes = [D, ctypes.c_int]
    dll.shim_la_eigh.argtypes = [D, ctypes.c_int, D, D]
    dll.shim_la_inverse_from_eigen.argtypes = [D, D, ctypes.c_int, D]
    dll.shim_la_gram.argtypes = [D, ctypes.c_long, ctypes.c_int, D]
    return dll


@pytest.fixture(scope="module")
def lib(tmp_path_factory):
    return build_lib(tmp_path_factory.mktemp("core"))


def arr(values):
    values = [float(x) for x in values]
    return (ctypes.c_double * max(len(values), 1))(*values)


def bits(values) -> np.ndarray:
    return np.array([float(x) for x in values], dtype=float).view(np.uint64)


class CIdent:
    def __init__(self, lib, cfg: IdentifierConfig):
        self.lib = lib
        c = [cfg.dt, cfg.batch_size, cfg.forgetting, cfg.gamma, cfg.mass_initial, cfg.mass_std_initial,
             cfg.A0_initial, cfg.A1_initial, cfg.A2_initial, cfg.A0_std_initial, cfg.A1_std_initial,
             cfg.A2_std_initial, cfg.sigma2_initial, cfg.speed_std, float(cfg.frozen), cfg.run_forgetting,
             cfg.speed_std_rel, cfg.A0_drift_std, cfg.A1_drift_std]
        self.ptr = lib.shim_new(arr(c))
        assert self.ptr

    def __del__(self):
        if getattr(self, "ptr", None):
            self.lib.shim_free(self.ptr)

    def state(self) -> list[float]:
        out = (ctypes.c_double * N_STATE)()
        assert self.lib.shim_state(self.ptr, out) == N_STATE
        return list(out)

    def outputs(self, phi) -> list[float]:
        out = (ctypes.c_double * N_OUT)()
        assert self.lib.shim_outputs(self.ptr, arr(phi), out) == N_OUT
        return list(out)


def opt(values, n):
    return [0.0] * n if values is None else [float(x) for x in values]


def py_state(p: ParameterIdentifier) -> list[float]:
    """The Python object's state in the shim's layout (shim_state)."""
    s = [float(x) for x in p.theta0] + [p._scale, p.s2_ref] + list(p.s2_prior) + list(p._j0)
    s += list(p._theta) + list(p._prior_mean)
    s += [p._running_theta is not None] + opt(p._running_theta, 4) + opt(p._batch_info_inv, 16)
    bp = p._batch_prior
    s += opt(bp and bp[0], 4) + opt(bp and bp[1], 4)
    s += [p._S is not None] + opt(p._S, 16)
    s += [p.n, p.q_e, p.s2, len(p._batch_y), p.mass_restarts, p.repairs] + list(p._W) + list(p._D)
    s += [p._last_phi is not None] + opt(p._last_phi, 4)
    s += [p._last_err is not None, 0.0 if p._last_err is None else p._last_err]
    s += [p.c0, p.c1, p._n_c1, len(p._window)] + list(p._window) + [0.0] * (LAG - len(p._window))
    s += [p._window_sum, p.cL is not None, 0.0 if p.cL is None else p.cL, p._n_cL]
    s += [p._J is not None] + opt(p._J, 16)
    s += list(p._Dq)
    assert len(s) == N_STATE
    return [float(x) for x in s]


def py_outputs(p: ParameterIdentifier, phi) -> list[float]:
    out = list(p.model_theta) + list(p.model_covariance().ravel()) + [p.model_variance_along(phi)]
    out += list(p.covariance().ravel()) + list(p.stds()) + [p.mass, p.mass_std(), p.sigma2(), p.samples]
    out += list(p.noise_split())
    return [float(x) for x in out]


# ---------------------------------------------------------------- the rows

def car_events(seed: int, steps: int, gamma: float = 0.0, dt: float = 0.1) -> list[tuple]:
    """A simulated car: traction to ~18 m/s, coasting, braking to a stop, 10 s at the station
    (a mass restart, the payload changes), on grades changing every 40 s; measured speed with
    0.05 m/s noise; about 1 % of the pairs skipped (the next one is not contiguous)."""
    rng = np.random.default_rng(seed)
    mass, a0, a1, a2 = 42.0, 1.3, 0.025, 0.009
    grades = (-4.0, 0.0, 3.0, 6.0, -1.5)
    v, phase, t_phase = 0.0, "traction", 0
    vm = v + 0.05 * rng.standard_normal()
    events, contiguous = [], False
    for k in range(steps):
        grade = grades[(k // 400) % len(grades)]
        F = B = 0.0
        if phase == "traction":
            F = 35e3 + 2e3 * math.sin(0.05 * k)
            if v > 18.0:
                phase, t_phase = "coast", 0
        elif phase == "coast":
            t_phase += 1
            if t_phase > 200:
                phase = "brake"
        elif phase == "brake":
            B = 45e3
            if v < 0.3:
                phase, t_phase = "stand", 0
        else:
            t_phase += 1
            if t_phase == 1:
                events.append(("restart",))
                mass = float(rng.uniform(35.0, 55.0))
            if t_phase > 100:
                phase = "traction"
        resist = (F - B) / (mass * G) - a0 - a1 * v - a2 * v * v - grade
        v_next = v + G * dt / (1000.0 * (1.0 + gamma)) * resist + 0.003 * rng.standard_normal()
        if phase == "stand" or v_next < 0.0:
            v_next = 0.0
        vm_next = v_next + 0.05 * rng.standard_normal()
        if v > 0.5 and v_next > 0.5 and rng.uniform() > 0.01:
            dt_arg = dt if k % 7 else None                # None: the configured period
            events.append(("update", F, B, vm, vm_next, grade, dt_arg, contiguous))
            contiguous = True
        else:
            contiguous = False
        v, vm = v_next, vm_next
    return events


def random_events(seed: int, steps: int) -> list[tuple]:
    rng = np.random.default_rng(seed)
    events = []
    for k in range(steps):
        if rng.uniform() < 0.01:
            events.append(("restart",))
        F = float(rng.choice([0.0, rng.uniform(0, 5e4)]))
        B = float(rng.choice([0.0, 0.0, rng.uniform(0, 5e4)]))
        v = float(rng.uniform(1.0, 30.0))
        events.append(("update", F, B, v, v + float(rng.normal(0, 0.1)), float(rng.normal(0, 3)),
                       float(rng.choice([0.1, 0.1, 0.05, 0.2])), bool(rng.uniform() > 0.05)))
    return events


# ---------------------------------------------------------------- the comparison

def make_pair(lib, cfg: IdentifierConfig):
    return ParameterIdentifier(cfg), CIdent(lib, cfg)


def apply(p, c, ev) -> None:
    kind = ev[0]
    if kind == "update":
        _, F, B, v, vn, grade, dt, contiguous = ev
        p.update(F, B, v, vn, grade, dt, contiguous=contiguous)
        c.lib.shim_update(c.ptr, F, B, v, vn, grade, 0.0 if dt is None else dt, int(contiguous))
    elif kind == "restart":
        p.restart_mass()
        c.lib.shim_restart_mass(c.ptr)
    elif kind == "theta":
        p.theta = ev[1]
        c.lib.shim_set_theta(c.ptr, arr(ev[1]))
    elif kind == "S":                                    # ident._S = ..., nothing else
        p._S = [float(x) for x in ev[1]]
        c.lib.shim_set_S(c.ptr, arr(ev[1]))
    elif kind == "reset":
        p.reset()
        c.lib.shim_reset(c.ptr)
    else:
        raise ValueError(kind)


def assert_same(p, c, step, phi) -> None:
    ps, cs = bits(py_state(p)), bits(c.state())
    if not np.array_equal(ps, cs):
        i = int(np.flatnonzero(ps != cs)[0])
        raise AssertionError(f"state differs after event {step} at index {i}: "
                             f"python {py_state(p)[i]!r}, C {c.state()[i]!r}")
    po, co = bits(py_outputs(p, phi)), bits(c.outputs(phi))
    if not np.array_equal(po, co):
        i = int(np.flatnonzero(po != co)[0])
        raise AssertionError(f"outputs differ after event {step} at index {i}: "
                             f"python {py_outputs(p, phi)[i]!r}, C {c.outputs(phi)[i]!r}")


def run_pair(lib, cfg, events, check_every=1):
    p, c = make_pair(lib, cfg)
    assert_same(p, c, -1, (1e4, -1.0, -10.0, -100.0))
    for k, ev in enumerate(events):
        apply(p, c, ev)
        if k % check_every == 0 or k == len(events) - 1:
            phi = (ev[1] - ev[2], -1.0, -ev[3], -ev[3] * ev[3]) if ev[0] == "update" else (2e4, -1.0, -5.0, -25.0)
            assert_same(p, c, k, phi)
    return p, c


CASES = {
    "paper LS": dict(),
    "run_forgetting 0.3": dict(run_forgetting=0.3),
    "batch 4": dict(batch_size=4),
    "forgetting 0.002": dict(forgetting=0.002),
    "forgetting 0.002, run_forgetting 0.3": dict(forgetting=0.002, run_forgetting=0.3),
    "gamma 0.1": dict(gamma=0.1),
    "frozen": dict(frozen=True),
    "no speed noise stated": dict(speed_std=0.0, batch_size=20, sigma2_initial=3e-5),
    "relative speed noise": dict(speed_std=0.01, speed_std_rel=0.01),
    "drift": dict(A0_drift_std=0.05, A1_drift_std=0.03),
    "drift, run_forgetting 0.3": dict(A0_drift_std=0.05, A1_drift_std=0.03, run_forgetting=0.3),
    "A1 drift alone, forgetting 0.002": dict(A1_drift_std=0.03, forgetting=0.002, run_forgetting=0.3),
    "A0 drift alone at its bound": dict(A0_drift_std=10.0),
}


@pytest.mark.parametrize("name", list(CASES))
def test_the_simulated_car_gives_the_same_bits_in_c(lib, name):
    kw = {"speed_std": 0.05, **CASES[name]}
    cfg = IdentifierConfig(**kw)
    events = car_events(seed=len(name), steps=4000, gamma=kw.get("gamma", 0.0))
    assert sum(e[0] == "restart" for e in events) >= 2
    p, _ = run_pair(lib, cfg, events)
    if not cfg.frozen:
        assert p.samples > 1000 and p._n_cL > 0
        assert p.mass_restarts >= 2 and 30.0 < p.mass < 60.0


DRIFT = {"no drift": {}, "drift": dict(A0_drift_std=0.05, A1_drift_std=0.03)}
"""est.A0_drift_std, est.A1_drift_std off and on (the drift meat at each restart)."""


@pytest.mark.parametrize("drift", list(DRIFT))
@pytest.mark.parametrize("forgetting", [0.0, 0.002])
def test_random_rows(lib, forgetting, drift):
    """Random rows (dt None and others, skipped pairs, restarts) after a prior centre moved
    before any data, and a simulated car checked every third event."""
    cfg = IdentifierConfig(speed_std=0.05, forgetting=forgetting, run_forgetting=0.2, batch_size=30,
                           **DRIFT[drift])
    events = [("theta", [1.0 / (G * 40.0), 1.1, 0.02, 0.008])] + random_events(7, 1500)
    run_pair(lib, cfg, events)
    run_pair(lib, cfg, car_events(3, 2500), check_every=3)


def negative_S(p) -> list[float]:
    """S with one direction lost, as the 10 h service day met it: R's smallest eigenvalue made
    negative (computed here with numpy, then handed to both objects alike)."""
    R = np.linalg.inv(p.S)
    w, V = np.linalg.eigh(0.5 * (R + R.T))
    w[0] = -abs(w[-1]) * 1e-6
    return [float(x) for x in np.linalg.inv((V * w) @ V.T).ravel()]


@pytest.mark.parametrize("drift", list(DRIFT))
@pytest.mark.parametrize("forgetting", [0.0, 0.002])
def test_the_positive_definiteness_repair(lib, forgetting, drift):
    cfg = IdentifierConfig(speed_std=0.05, forgetting=forgetting, run_forgetting=0.3, **DRIFT[drift])
    events = car_events(11, 1500)
    p, c = run_pair(lib, cfg, events, check_every=10)
    # at an update: an indefinite S that the next regressor meets with phi^T S phi <= 0
    v = 10.0
    phi = np.array([0.0, -1.0, -v, -v * v])
    S = negative_S(p)
    if phi @ np.array(S).reshape(4, 4) @ phi > 0.0:
        S = [-x for x in S]
    for ev in [("S", S), ("update", 0.0, 0.0, v, v - 0.001, 0.0, 0.1, True)]:
        apply(p, c, ev)
        assert_same(p, c, ev[0], phi)
    assert p.repairs == 1
    # at a restart: an S that is not positive definite (Cholesky fails)
    for ev in [("S", negative_S(p)), ("restart",)]:
        apply(p, c, ev)
        assert_same(p, c, ev[0], phi)
    assert p.repairs == 2
    for k, ev in enumerate(car_events(12, 600)):
        apply(p, c, ev)
        assert_same(p, c, k, phi)
    assert all(math.isfinite(x) for x in p.theta)


def test_reset_and_a_new_batch(lib):
    cfg = IdentifierConfig(speed_std=0.05, batch_size=10)
    events = car_events(5, 800) + [("reset",)] + car_events(6, 800)
    run_pair(lib, cfg, events, check_every=2)


def test_one_ulp_in_one_speed_shows(lib):
    """The comparison is not blind: one speed one ulp off, in C only, shows in the state."""
    cfg = IdentifierConfig(speed_std=0.05)
    events = [e for e in car_events(2, 1500)]
    k = [i for i, e in enumerate(events) if e[0] == "update"][300]
    p, c = make_pair(lib, cfg)
    for ev in events[:k]:
        apply(p, c, ev)
    assert_same(p, c, k - 1, (1e4, -1.0, -10.0, -100.0))          # equal up to here
    ev = events[k]
    p.update(*ev[1:7], contiguous=ev[7])
    v = math.nextafter(ev[3], math.inf)
    c.lib.shim_update(c.ptr, ev[1], ev[2], v, ev[4], ev[5], ev[6] or 0.0, int(ev[7]))
    with pytest.raises(AssertionError, match="differs"):
        assert_same(p, c, k, (1e4, -1.0, -10.0, -100.0))


ONE_ULP = "(1.0 + 2.220446049250313e-16)"
DRIFT_MUTATIONS = {
    # drift_meat: the data's information on the carried A's, one ulp larger
    "drift_meat_Jc": ("0.5 * (info[4 * i + j] + info[4 * j + i]) * info_scale - d;",
                      f"0.5 * (info[4 * i + j] + info[4 * j + i]) * info_scale * {ONE_ULP} - d;"),
    # drift_meat: the A1 term one ulp larger
    "drift_meat_A1": ("(Jc[3 * i] * Jc[3 * j]) * v0 + (Jc[3 * i + 1] * Jc[3 * j + 1]) * v1;",
                      f"(Jc[3 * i] * Jc[3 * j]) * v0 + (Jc[3 * i + 1] * Jc[3 * j + 1]) * v1 * {ONE_ULP};"),
    # drift_covariance: J^-1 symmetrised, one ulp off
    "drift_covariance_Js": ("Js[4 * i + j] = 0.5 * (Ji[4 * i + j] + Ji[4 * j + i]);",
                            f"Js[4 * i + j] = 0.5 * (Ji[4 * i + j] + Ji[4 * j + i]) * {ONE_ULP};"),
    # the drift meat's forgetting per step (est.forgetting)
    "drift_forgetting": ("id->Dq[i] *= l2;", f"id->Dq[i] *= l2 * {ONE_ULP};"),
}


@pytest.mark.parametrize("mutation", DRIFT_MUTATIONS)
def test_a_one_ulp_mutation_of_the_drift_shows(mutation, tmp_path):
    """The drift's C code (ident.c: drift_meat, the covariance's drift term, the meat's
    forgetting) is compared for real: one ulp in one of its expressions, in a copy of ident.c,
    makes the simulated car's state or outputs differ from Python's."""
    target, replacement = DRIFT_MUTATIONS[mutation]
    text = (CORE / "ident.c").read_text()
    assert text.count(target) == 1, f"ident.c: the mutation's target occurs {text.count(target)} times"
    mutant = tmp_path / "ident.c"
    mutant.write_text(text.replace(target, replacement))
    mutated = build_lib(tmp_path, [mutant, *SOURCES[1:]])
    cfg = IdentifierConfig(speed_std=0.05, forgetting=0.002 if mutation == "drift_forgetting" else 0.0,
                           run_forgetting=0.3, A0_drift_std=0.05, A1_drift_std=0.03)
    with pytest.raises(AssertionError, match="differ"):
        run_pair(mutated, cfg, car_events(4, 4000))


def test_no_drift_adds_nothing(lib):
    """With both drift stds 0 the drift meat stays 0 and the C state's Dq with it; with drift it
    grows at each restart (the comparison above is not of zeros)."""
    events = car_events(4, 4000)
    p, _ = run_pair(lib, IdentifierConfig(speed_std=0.05), events, check_every=50)
    assert p.mass_restarts >= 2 and not any(p._Dq)
    p, _ = run_pair(lib, IdentifierConfig(speed_std=0.05, A0_drift_std=0.05, A1_drift_std=0.03), events,
                    check_every=50)
    assert p._Dq[5] > 0.0 and p._Dq[10] > 0.0 and p._Dq[0] == 0.0


# ---------------------------------------------------------------- linalg4.c alone

def test_linalg4_in_c_is_linalg4_py(lib):
    rng = np.random.default_rng(21)
    for trial in range(400):
        n = 4 if trial % 4 else int(rng.integers(1, 8))
        B = rng.standard_normal((n, n)) * 10 ** rng.uniform(-3, 6, (n, n))
        A = [float(x) for x in (B if trial % 2 else B + B.T).ravel()]
        b = [float(x) for x in rng.standard_normal(n)]
        out, w, V = (ctypes.c_double * (n * n))(), (ctypes.c_double * n)(), (ctypes.c_double * (n * n))()
        assert lib.shim_la_solve(arr(A), arr(b), n, out) == 0
        assert bits(out[:n]).tolist() == bits(linalg4.solve(A, b, n)).tolist()
        assert lib.shim_la_inverse(arr(A), n, out) == 0
        assert bits(out[:]).tolist() == bits(linalg4.inverse(A, n)).tolist()
        assert lib.shim_la_is_pd(arr(A), n) == linalg4.is_positive_definite(A, n)
        Asym = [float(x) for x in (B + B.T).ravel()]
        lib.shim_la_eigh(arr(Asym), n, w, V)
        pw, pV = linalg4.eigh(Asym, n)
        assert bits(w[:]).tolist() == bits(pw).tolist() and bits(V[:]).tolist() == bits(pV).tolist()
        lib.shim_la_inverse_from_eigen(arr(pw), arr(pV), n, out)
        assert bits(out[:]).tolist() == bits(linalg4.inverse_from_eigen(pw, pV, n)).tolist()
        rows = rng.standard_normal((7, n))
        lib.shim_la_gram(arr(rows.ravel()), 7, n, out)
        assert bits(out[:]).tolist() == bits(linalg4.gram([tuple(r) for r in rows], n)).tolist()
    singular = [1.0, 2.0, 3.0, 4.0, 2.0, 4.0, 6.0, 8.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0]
    out = (ctypes.c_double * 16)()
    with pytest.raises(linalg4.SingularMatrixError):
        linalg4.inverse(singular)
    assert lib.shim_la_inverse(arr(singular), 4, out) == -1         # Python raises, C says so
    assert lib.shim_la_solve(arr(singular), arr([1.0] * 4), 4, out) == -1


# ---------------------------------------------------------------- sanitizers

SANITIZED_MAIN = r"""
#include <stdio.h>
#include <stdlib.h>
#include "ident.h"

static unsigned long long st = 88172645463325252ULL;
static double uni(void) { st ^= st << 13; st ^= st >> 7; st ^= st << 17; return (double)(st >> 11) / 9007199254740992.0; }

int main(void)
{
    double sum = 0.0;
    for (int c = 0; c < 6; c++) {
        rc_ident_config cfg = {0.1, c == 1 ? 4 : 50, c >= 2 && c <= 3 ? 0.002 : 0.0, c == 4 ? 0.1 : 0.0,
                               30.0, 10.0, 1.0, 0.03, 0.01, 5.0, 0.1, 0.02, 1e-4, 0.05, c == 5,
                               c == 3 ? 0.3 : 0.0, c == 2 ? 0.01 : 0.0, c >= 3 ? 0.05 : 0.0,
                               c == 0 || c >= 3 ? 0.03 : 0.0};
        rc_ident id;
        if (rc_ident_init(&id, &cfg)) return 2;
        double phi[4] = {1e4, -1.0, -10.0, -100.0}, out[4];
        for (int k = 0; k < 3000; k++) {
            double v = 1.0 + 25.0 * uni();
            rc_ident_update(&id, uni() < 0.5 ? 4e4 * uni() : 0.0, uni() < 0.3 ? 4e4 * uni() : 0.0, v,
                            v + 0.1 * (uni() - 0.5), 4.0 * (uni() - 0.5), k % 5 ? 0.1 : 0.0, uni() > 0.05);
            if (k % 500 == 499) {
                if (id.has_S) for (int i = 0; i < 16; i++) id.S[i] = -id.S[i];   /* the repair */
                rc_ident_restart_mass(&id);
            }
            if (k == 2000 && id.has_S) {
                for (int i = 0; i < 16; i++) id.S[i] = -id.S[i];
                rc_ident_update(&id, 0.0, 0.0, 10.0, 9.99, 0.0, 0.1, 1);
            }
            rc_ident_model_theta(&id, out);
            sum += out[0] + rc_ident_model_variance_along(&id, phi) + rc_ident_mass_std(&id)
                   + rc_ident_sigma2(&id) + rc_ident_covariance(&id)[5] + rc_ident_model_covariance(&id)[10];
            rc_ident_stds(&id, out);
            sum += out[3] + (double)rc_ident_samples(&id);
        }
        if (id.repairs < 1 && !cfg.frozen) return 3;
        rc_ident_reset(&id);
        rc_ident_free(&id);
    }
    printf("%.17g\n", sum);
    return 0;
}
"""


def test_clean_under_address_and_undefined_behaviour_sanitizers(tmp_path):
    gcc = shutil.which("gcc")
    main = tmp_path / "main.c"
    main.write_text(SANITIZED_MAIN)
    exe = tmp_path / "ident_sanitized"
    subprocess.run([gcc, *FLAGS, "-g", "-fsanitize=address,undefined", "-fno-sanitize-recover=all",
                    f"-I{CORE}", str(main), *map(str, SOURCES), "-o", str(exe), "-lm"],
                   check=True, capture_output=True, text=True)
    proc = subprocess.run([str(exe)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "runtime error" not in proc.stderr and "AddressSanitizer" not in proc.stderr
    assert math.isfinite(float(proc.stdout))
