"""models/linalg4.py against numpy/LAPACK.

linalg4 is the identifier's reference for the rare paths (its C twin models/core/linalg4.c
repeats it bit for bit, tests/model_tests/core/test_core_ident.py). Here it is checked to compute what numpy
computes, within the error bounds of the algorithms, on random and on the identifier's own
ill-conditioned matrices, and to refuse singular matrices where numpy does.

Tolerances, eps = 2^-52 (unit roundoff u = eps / 2):
- sums of m products (gram, matvec, dot): |fl(s) - s| <= gamma_m sum |terms|, gamma_m ~ m u,
  for ours and numpy's alike, so the two differ by at most 2 m u sum |terms| <= m eps sum |terms|.
- solve: Gaussian elimination with partial pivoting is backward stable, so the residual is
  small whatever the condition: ||A x - b|| <= c n eps ||A|| ||x|| (c = 10, growth factors of
  these sizes are tiny); the forward error against numpy is bounded by cond(A) times that.
- inverse (Gauss-Jordan): ||X - X_np|| <= c n eps cond(A) ||X_np|| (forward error bound).
- eigh (Jacobi, backward stable): eigenvalues within c n eps ||A||_2 of numpy's (Weyl), V
  orthogonal within c n eps, V diag(w) V^T = A within c n eps ||A||.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from models import linalg4

EPS = np.finfo(float).eps


def flat(A) -> list[float]:
    return [float(x) for x in np.asarray(A, dtype=float).ravel()]


def mat(a, n=4) -> np.ndarray:
    return np.array(a).reshape(n, n)


def spd(rng, n=4, cond=1e3) -> np.ndarray:
    Q, _ = np.linalg.qr(rng.standard_normal((n, n)))
    w = np.geomspace(1.0, cond, n) * rng.uniform(0.5, 2.0)
    return (Q * w) @ Q.T


def identifier_info(rng, n_rows=50) -> np.ndarray:
    """Phi^T Phi + J0 of the identifier's rows: F - B ~ 1e4, V ~ 10, V^2 ~ 100 (cond ~ 1e9+)."""
    v = rng.uniform(2.0, 25.0, n_rows)
    f = np.where(rng.uniform(size=n_rows) < 0.5, rng.uniform(0, 4e4, n_rows), 0.0)
    phi = np.column_stack([f, -np.ones(n_rows), -v, -v * v])
    return phi.T @ phi + np.diag([3e-3, 0.5, 1e3, 3e4])


# ---------------------------------------------------------------- sums

def test_gram_and_products_equal_numpy_within_the_summation_bound():
    rng = np.random.default_rng(1)
    for _ in range(50):
        m = int(rng.integers(1, 60))
        rows = rng.standard_normal((m, 4)) * np.array([1e4, 1.0, 10.0, 100.0])
        y = rng.standard_normal(m)
        G = mat(linalg4.gram([tuple(r) for r in rows]))
        bound = m * EPS * (np.abs(rows).T @ np.abs(rows))
        assert np.all(np.abs(G - rows.T @ rows) <= bound)
        g = np.array(linalg4.gram_t_vec([tuple(r) for r in rows], list(y)))
        assert np.all(np.abs(g - rows.T @ y) <= m * EPS * (np.abs(rows).T @ np.abs(y)))
        A, x = rng.standard_normal((4, 4)), rng.standard_normal(4)
        assert np.all(np.abs(np.array(linalg4.matvec(flat(A), list(x))) - A @ x)
                      <= 4 * EPS * (np.abs(A) @ np.abs(x)))
        assert abs(linalg4.dot(list(A[0]), list(x)) - A[0] @ x) <= 4 * EPS * (np.abs(A[0]) @ np.abs(x))


def test_gram_is_row_by_row_accumulation():
    """The documented order: entry (i, j) accumulates the rows' products onto 0.0 in row order
    (what lets the identifier's C twin reproduce it)."""
    rows = [(0.1, 0.2, 0.3, 0.7), (1e16, 1.0, -1e16, 3.0), (0.3, 0.1, 0.2, 0.9)]
    G = linalg4.gram(rows)
    for i in range(4):
        for j in range(4):
            s = 0.0
            for r in rows:
                s += r[i] * r[j]
            assert G[4 * i + j] == s


# ---------------------------------------------------------------- solve, inverse

@pytest.mark.parametrize("kind", ["random", "spd", "identifier"])
def test_solve_is_backward_stable_and_agrees_with_numpy(kind):
    rng = np.random.default_rng({"random": 2, "spd": 3, "identifier": 4}[kind])
    for _ in range(200):
        A = {"random": lambda: rng.standard_normal((4, 4)),
             "spd": lambda: spd(rng, cond=10 ** rng.uniform(0, 8)),
             "identifier": lambda: identifier_info(rng)}[kind]()
        b = rng.standard_normal(4) * np.abs(A).max()
        x = np.array(linalg4.solve(flat(A), list(b)))
        assert np.linalg.norm(A @ x - b) <= 10 * 4 * EPS * np.linalg.norm(A) * np.linalg.norm(x)
        x_np = np.linalg.solve(A, b)
        assert np.linalg.norm(x - x_np) <= 10 * 4 * EPS * np.linalg.cond(A) * np.linalg.norm(x_np)


@pytest.mark.parametrize("kind", ["random", "spd", "identifier"])
def test_inverse_agrees_with_numpy_within_the_condition_bound(kind):
    rng = np.random.default_rng({"random": 5, "spd": 6, "identifier": 7}[kind])
    for _ in range(200):
        A = {"random": lambda: rng.standard_normal((4, 4)),
             "spd": lambda: spd(rng, cond=10 ** rng.uniform(0, 8)),
             "identifier": lambda: identifier_info(rng)}[kind]()
        X = mat(linalg4.inverse(flat(A)))
        X_np = np.linalg.inv(A)
        assert np.linalg.norm(X - X_np) <= 10 * 4 * EPS * np.linalg.cond(A) * np.linalg.norm(X_np)


def test_sizes_other_than_four():
    rng = np.random.default_rng(8)
    for n in (1, 2, 3, 5, 7):
        A = rng.standard_normal((n, n)) + n * np.eye(n)
        b = rng.standard_normal(n)
        assert np.allclose(linalg4.solve(flat(A), list(b), n), np.linalg.solve(A, b), rtol=1e-12, atol=0)
        assert np.allclose(mat(linalg4.inverse(flat(A), n), n), np.linalg.inv(A), rtol=1e-12, atol=1e-14)


def test_pivoting_takes_the_largest_entry():
    """Without row exchanges the 1e-20 pivot would lose x entirely."""
    A = [1e-20, 1.0, 1.0, 1.0]
    x = linalg4.solve(A, [1.0, 2.0], 2)
    assert x == pytest.approx([1.0, 1.0], rel=1e-15)
    assert mat(linalg4.inverse(A, 2), 2) == pytest.approx(np.linalg.inv(mat(A, 2)), rel=1e-15)


@pytest.mark.parametrize("A", [
    np.zeros((4, 4)),
    np.array([[1.0, 2, 3, 4], [2, 4, 6, 8], [0, 1, 0, 0], [0, 0, 1, 0]]),      # dependent rows
    np.array([[1.0, 1, 0, 0], [1, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]),      # exact zero pivot
    np.diag([1.0, 2.0, 0.0, 3.0]),
])
def test_singular_matrices_raise_where_numpy_raises(A):
    with pytest.raises(np.linalg.LinAlgError):
        np.linalg.inv(A)
    with pytest.raises(ZeroDivisionError):
        linalg4.solve(flat(A), [1.0, 2.0, 3.0, 4.0])
    with pytest.raises(linalg4.SingularMatrixError):
        linalg4.inverse(flat(A))


# ---------------------------------------------------------------- positive definiteness

def test_positive_definiteness_agrees_with_the_smallest_eigenvalue():
    rng = np.random.default_rng(9)
    for _ in range(500):
        Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
        w = np.geomspace(1.0, 10 ** rng.uniform(0, 9), 4) * rng.choice([-1.0, 1.0], 4, p=[0.3, 0.7])
        A = (Q * w) @ Q.T
        A = 0.5 * (A + A.T)
        assert linalg4.is_positive_definite(flat(A)) == (np.linalg.eigvalsh(A)[0] > 0.0)
    assert linalg4.is_positive_definite(flat(identifier_info(rng)))
    assert not linalg4.is_positive_definite(flat(np.zeros((4, 4))))
    assert not linalg4.is_positive_definite(flat(np.ones((4, 4))))      # semidefinite
    nan = np.eye(4)
    nan[2, 2] = math.nan
    assert not linalg4.is_positive_definite(flat(nan))


def test_positive_definiteness_reads_the_lower_triangle_as_eigvalsh_does():
    A = np.eye(4)
    A[0, 3] = 5.0                                       # upper triangle alone: ignored
    assert linalg4.is_positive_definite(flat(A)) and np.linalg.eigvalsh(A)[0] > 0
    A = np.eye(4)
    A[3, 0] = 5.0                                       # lower: indefinite
    assert not linalg4.is_positive_definite(flat(A)) and np.linalg.eigvalsh(A)[0] < 0


# ---------------------------------------------------------------- eigen-decomposition

def check_eigh(A: np.ndarray, c=10.0) -> None:
    n = len(A)
    w, V = linalg4.eigh(flat(A), n)
    w, V = np.array(w), mat(V, n)
    norm = np.linalg.norm(A, 2)
    assert np.all(np.abs(np.sort(w) - np.linalg.eigvalsh(A)) <= c * n * EPS * norm)
    assert np.linalg.norm(V.T @ V - np.eye(n)) <= c * n * EPS
    assert np.linalg.norm((V * w) @ V.T - A) <= c * n * EPS * norm


def test_jacobi_eigen_decomposition_agrees_with_numpy():
    rng = np.random.default_rng(10)
    for _ in range(300):
        B = rng.standard_normal((4, 4)) * 10 ** rng.uniform(-5, 5)
        check_eigh(0.5 * (B + B.T))
    for _ in range(100):                                 # graded, indefinite, ~1e9 span
        Q, _ = np.linalg.qr(rng.standard_normal((4, 4)))
        w = np.geomspace(1e-3, 1e6, 4) * rng.choice([-1.0, 1.0], 4)
        A = (Q * w) @ Q.T
        check_eigh(0.5 * (A + A.T))
    for _ in range(100):                                 # the identifier's information matrices
        check_eigh(identifier_info(rng))
    for n in (2, 3, 6):
        B = rng.standard_normal((n, n))
        check_eigh(B + B.T)


def test_jacobi_special_cases():
    w, V = linalg4.eigh(flat(np.diag([3.0, -1.0, 0.0, 2.0])))      # diagonal: untouched
    assert w == [3.0, -1.0, 0.0, 2.0] and V == linalg4.identity(4)
    check_eigh(np.ones((4, 4)))                                      # repeated eigenvalue 0
    check_eigh(np.eye(4) + 1e-300 * (np.ones((4, 4)) - np.eye(4)))   # negligible off-diagonal
    w, V = linalg4.eigh([1.0, 1e-200, 1e-200, 1.0], 2)
    assert w == [1.0, 1.0]
    w, _ = linalg4.eigh([0.0, 1.0, 1.0, 0.0], 2)                     # theta = 0: 45 degrees
    assert sorted(w) == pytest.approx([-1.0, 1.0], abs=4 * EPS)
    w, _ = linalg4.eigh([1e300, 1e-10, 1e-10, -1e300], 2)            # |theta| > 1e150 branch
    assert w == [1e300, -1e300]
    w, _ = linalg4.eigh([math.nan, 1.0, 1.0, 0.0], 2)                # NaN: bounded, NaN out
    assert any(math.isnan(x) for x in w)


def test_inverse_from_eigen_is_v_diag_inverse_vt():
    rng = np.random.default_rng(11)
    for _ in range(100):
        A = spd(rng, cond=1e6)
        w, V = linalg4.eigh(flat(A))
        X = mat(linalg4.inverse_from_eigen(w, V))
        X_np = np.linalg.inv(A)
        assert np.linalg.norm(X - X_np) <= 100 * 4 * EPS * np.linalg.cond(A) * np.linalg.norm(X_np)


# ---------------------------------------------------------------- the identifier uses it

def test_the_identifiers_method_0_path_calls_no_numpy_linalg(monkeypatch):
    """The first batch, the running estimate, forgetting, mass restarts (run_forgetting too),
    the positive-definiteness repair and the covariances: all through linalg4."""
    from models.estimation.identification import IdentifierConfig, ParameterIdentifier

    def refuse(*a, **k):
        raise AssertionError("numpy.linalg called on the method 0 path")
    rng = np.random.default_rng(12)
    idents = [ParameterIdentifier(IdentifierConfig(speed_std=0.05, forgetting=f, run_forgetting=r))
              for f in (0.0, 0.002) for r in (0.0, 0.3)]
    with monkeypatch.context() as m:
        for name in ("solve", "inv", "eigh", "eigvalsh", "cholesky", "lstsq", "pinv"):
            m.setattr(np.linalg, name, refuse)
        for ident in idents:
            v = 5.0
            for k in range(400):
                f = 20e3 if k % 40 < 20 else 0.0
                v_next = v + 0.1 * (f / 34e3 - 0.01) + 0.05 * rng.standard_normal()
                ident.update(f, 0.0, v, v_next, 0.0, 0.1, contiguous=k % 97 != 0)
                ident.model_covariance(), ident.covariance(), ident.sigma2(), ident.mass_std()
                v = v_next
                if k == 250:
                    ident.restart_mass()
            S = ident._S
            ident._S = [-x for x in S]                      # not positive definite: repaired
            ident.restart_mass()
            ident._S = [-x for x in ident._S]
            ident.update(10e3, 0.0, v, v + 0.01, 0.0, 0.1)
            assert ident.repairs == 2
            assert all(math.isfinite(x) for x in ident.theta)
