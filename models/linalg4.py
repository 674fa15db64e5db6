"""Small dense linear algebra in scalar Python with a fixed operation order.

The solves, inverses and eigen-decompositions of models/estimation/identification.py (the first batch and
the running estimate before it, a mass restart, regularised forgetting, the positive-definiteness
repair). numpy/LAPACK's blocked, FMA-using kernels could not be reproduced bit for bit; here every
sum runs in the order written (left to right, no fused multiply-add), so models/core/linalg4.c,
which repeats this file line by line, gives the very same doubles.

Matrices are flat row-major lists of n*n floats (n = 4 for the identifier), vectors lists of n.
Singular input: ``solve`` and ``inverse`` raise ``SingularMatrixError`` (a ZeroDivisionError)
when a pivot is exactly 0.0, where numpy raises LinAlgError; the C twin divides on and returns
inf/NaN (it reports the event through its return value).
"""
from __future__ import annotations

import math


class SingularMatrixError(ZeroDivisionError):
    """A pivot of Gaussian elimination was exactly zero."""


def identity(n: int = 4) -> list[float]:
    out = [0.0] * (n * n)
    for i in range(n):
        out[i * n + i] = 1.0
    return out


def gram(rows, n: int = 4) -> list[float]:
    """sum_k phi_k phi_k^T, rows k in order; entry (i, j) accumulates phi_k[i] * phi_k[j] onto
    0.0."""
    out = [0.0] * (n * n)
    for p in rows:
        for i in range(n):
            pi = p[i]
            r = i * n
            for j in range(n):
                out[r + j] += pi * p[j]
    return out


def gram_t_vec(rows, y, n: int = 4) -> list[float]:
    """Phi^T y: entry i accumulates phi_k[i] * y[k] onto 0.0, rows k in order."""
    out = [0.0] * n
    for p, yk in zip(rows, y):
        for i in range(n):
            out[i] += p[i] * yk
    return out


def dot(a, b, n: int = 4) -> float:
    """a[0] b[0] + a[1] b[1] + ... left to right (starting with the first product)."""
    s = a[0] * b[0]
    for i in range(1, n):
        s += a[i] * b[i]
    return s


def matvec(A, x, n: int = 4) -> list[float]:
    """A x: row i is dot(A[i, :], x)."""
    out = []
    for i in range(n):
        r = i * n
        s = A[r] * x[0]
        for j in range(1, n):
            s += A[r + j] * x[j]
        out.append(s)
    return out


def _pivot_row(a, k: int, n: int) -> int:
    """Partial pivoting: the first row i >= k with the largest |a[i, k]|."""
    p = k
    big = abs(a[k * n + k])
    for i in range(k + 1, n):
        v = abs(a[i * n + k])
        if v > big:
            p, big = i, v
    if big == 0.0:
        raise SingularMatrixError("singular matrix")
    return p


def _swap_rows(a, i: int, k: int, n: int) -> None:
    ri, rk = i * n, k * n
    for j in range(n):
        a[ri + j], a[rk + j] = a[rk + j], a[ri + j]


def solve(A, b, n: int = 4) -> list[float]:
    """x with A x = b: Gaussian elimination with partial pivoting (_pivot_row), then back
    substitution x[i] = (b[i] - a[i, i+1] x[i+1] - ... - a[i, n-1] x[n-1]) / a[i, i]."""
    a = [float(v) for v in A]
    x = [float(v) for v in b]
    for k in range(n):
        p = _pivot_row(a, k, n)
        if p != k:
            _swap_rows(a, p, k, n)
            x[p], x[k] = x[k], x[p]
        rk = k * n
        piv = a[rk + k]
        for i in range(k + 1, n):
            ri = i * n
            f = a[ri + k] / piv
            for j in range(k + 1, n):
                a[ri + j] -= f * a[rk + j]
            x[i] -= f * x[k]
    for i in range(n - 1, -1, -1):
        ri = i * n
        s = x[i]
        for j in range(i + 1, n):
            s -= a[ri + j] * x[j]
        x[i] = s / a[ri + i]
    return x


def inverse(A, n: int = 4) -> list[float]:
    """A^-1 by Gauss-Jordan elimination with partial pivoting on [A | I]: for each column k the
    pivot row is swapped in, divided by the pivot, and subtracted from every other row (in row
    order) times that row's entry in column k."""
    a = [float(v) for v in A]
    inv = identity(n)
    for k in range(n):
        p = _pivot_row(a, k, n)
        if p != k:
            _swap_rows(a, p, k, n)
            _swap_rows(inv, p, k, n)
        rk = k * n
        piv = a[rk + k]
        for j in range(k + 1, n):
            a[rk + j] /= piv
        a[rk + k] = 1.0
        for j in range(n):
            inv[rk + j] /= piv
        for i in range(n):
            if i == k:
                continue
            ri = i * n
            f = a[ri + k]
            for j in range(k + 1, n):
                a[ri + j] -= f * a[rk + j]
            a[ri + k] = 0.0
            for j in range(n):
                inv[ri + j] -= f * inv[rk + j]
    return inv


def is_positive_definite(A, n: int = 4) -> bool:
    """Whether the Cholesky factorisation of A (its lower triangle, as numpy's eigvalsh reads)
    succeeds: every pivot d_j = a[j, j] - sum_k<j l[j, k]^2 > 0 (False on NaN). It answers the
    question asked (is A positive definite, up to rounding) in a fixed number of operations,
    with no iteration count or stopping threshold in the decision, as the smallest eigenvalue
    of an iterative eigen-solver would have."""
    L = [0.0] * (n * n)
    for j in range(n):
        rj = j * n
        d = A[rj + j]
        for k in range(j):
            d -= L[rj + k] * L[rj + k]
        if not d > 0.0:
            return False
        ljj = math.sqrt(d)
        L[rj + j] = ljj
        for i in range(j + 1, n):
            ri = i * n
            s = A[ri + j]
            for k in range(j):
                s -= L[ri + k] * L[rj + k]
            L[ri + j] = s / ljj
    return True


MAX_SWEEPS = 50


def eigh(A, n: int = 4) -> tuple[list[float], list[float]]:
    """Eigenvalues w and eigenvectors V (columns of the flat row-major V) of the symmetric A,
    by cyclic Jacobi rotations (Rutishauser's form, as in Numerical Recipes' jacobi):

    - at most MAX_SWEEPS sweeps; a sweep visits (p, q) for p = 0..n-2, q = p+1..n-1;
    - before each sweep, off = sum of a[p, q]^2 over that order; stop when off == 0.0;
    - an a[p, q] with |a[p,p]| + 100 |a[p,q]| == |a[p,p]| and the same for a[q,q] is below the
      diagonal's rounding: it is set to 0.0 without a rotation (so off reaches 0.0 exactly);
    - otherwise theta = (a[q,q] - a[p,p]) / (2 a[p,q]), t = sign(theta) / (|theta| +
      sqrt(theta^2 + 1)) (t = 1 / (2 theta) for |theta| > 1e150), c = 1 / sqrt(t^2 + 1),
      s = t c, tau = s / (1 + c); a[p,p] -= t a[p,q], a[q,q] += t a[p,q], a[p,q] = 0, and rows
      r != p, q then V's rows r = 0..n-1 rotate as g - s (h + g tau), h + s (g - h tau).

    w is the diagonal in its own order (not sorted). Only the upper triangle's (p, q) entries
    decide; A must be symmetric (the lower triangle is kept equal to the upper)."""
    a = [float(v) for v in A]
    V = identity(n)
    for _ in range(MAX_SWEEPS):
        off = 0.0
        for p in range(n - 1):
            for q in range(p + 1, n):
                off += a[p * n + q] * a[p * n + q]
        if off == 0.0:
            break
        for p in range(n - 1):
            for q in range(p + 1, n):
                apq = a[p * n + q]
                if apq == 0.0:
                    continue
                app = a[p * n + p]
                aqq = a[q * n + q]
                g = 100.0 * abs(apq)
                if abs(app) + g == abs(app) and abs(aqq) + g == abs(aqq):
                    a[p * n + q] = 0.0
                    a[q * n + p] = 0.0
                    continue
                theta = (aqq - app) / (2.0 * apq)
                if abs(theta) > 1e150:
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                tau = s / (1.0 + c)
                h = t * apq
                a[p * n + p] = app - h
                a[q * n + q] = aqq + h
                a[p * n + q] = 0.0
                a[q * n + p] = 0.0
                for r in range(n):
                    if r == p or r == q:
                        continue
                    g = a[r * n + p]
                    h = a[r * n + q]
                    rp = g - s * (h + g * tau)
                    rq = h + s * (g - h * tau)
                    a[r * n + p] = rp
                    a[p * n + r] = rp
                    a[r * n + q] = rq
                    a[q * n + r] = rq
                for r in range(n):
                    g = V[r * n + p]
                    h = V[r * n + q]
                    V[r * n + p] = g - s * (h + g * tau)
                    V[r * n + q] = h + s * (g - h * tau)
    return [a[i * n + i] for i in range(n)], V


def inverse_from_eigen(w, V, n: int = 4) -> list[float]:
    """V diag(w)^-1 V^T: entry (i, j) accumulates (V[i, k] / w[k]) V[j, k] onto 0.0, k in order."""
    out = [0.0] * (n * n)
    for i in range(n):
        for j in range(n):
            s = 0.0
            for k in range(n):
                s += V[i * n + k] / w[k] * V[j * n + k]
            out[i * n + j] = s
    return out
