/* linalg4.c -- see linalg4.h; the bodies of models/linalg4.py. */
#include "rc_fp_contract.h"
#include <math.h>
#include <string.h>

#include "linalg4.h"

void rc_la_identity(double *out, int n)
{
    for (int i = 0; i < n * n; i++)
        out[i] = 0.0;
    for (int i = 0; i < n; i++)
        out[i * n + i] = 1.0;
}

void rc_la_gram(const double *rows, long m, int n, double *out)
{
    for (int i = 0; i < n * n; i++)
        out[i] = 0.0;
    for (long k = 0; k < m; k++) {
        const double *p = rows + k * n;
        for (int i = 0; i < n; i++) {
            double pi = p[i];
            int r = i * n;
            for (int j = 0; j < n; j++)
                out[r + j] += pi * p[j];
        }
    }
}

void rc_la_gram_t_vec(const double *rows, const double *y, long m, int n, double *out)
{
    for (int i = 0; i < n; i++)
        out[i] = 0.0;
    for (long k = 0; k < m; k++) {
        const double *p = rows + k * n;
        double yk = y[k];
        for (int i = 0; i < n; i++)
            out[i] += p[i] * yk;
    }
}

double rc_la_dot(const double *a, const double *b, int n)
{
    double s = a[0] * b[0];
    for (int i = 1; i < n; i++)
        s += a[i] * b[i];
    return s;
}

void rc_la_matvec(const double *A, const double *x, int n, double *out)
{
    double tmp[RC_LA_NMAX];
    for (int i = 0; i < n; i++) {
        int r = i * n;
        double s = A[r] * x[0];
        for (int j = 1; j < n; j++)
            s += A[r + j] * x[j];
        tmp[i] = s;
    }
    memcpy(out, tmp, (size_t)n * sizeof(double));
}

/* _pivot_row: the first row i >= k with the largest |a[i, k]|; *singular when that is 0.0 */
static int pivot_row(const double *a, int k, int n, int *singular)
{
    int p = k;
    double big = fabs(a[k * n + k]);
    for (int i = k + 1; i < n; i++) {
        double v = fabs(a[i * n + k]);
        if (v > big) {
            p = i;
            big = v;
        }
    }
    if (big == 0.0)
        *singular = 1;
    return p;
}

static void swap_rows(double *a, int i, int k, int n)
{
    int ri = i * n, rk = k * n;
    for (int j = 0; j < n; j++) {
        double t = a[ri + j];
        a[ri + j] = a[rk + j];
        a[rk + j] = t;
    }
}

int rc_la_solve(const double *A, const double *b, int n, double *xo)
{
    double a[RC_LA_NMAX * RC_LA_NMAX], x[RC_LA_NMAX];
    int singular = 0;
    memcpy(a, A, (size_t)(n * n) * sizeof(double));
    memcpy(x, b, (size_t)n * sizeof(double));
    for (int k = 0; k < n; k++) {
        int p = pivot_row(a, k, n, &singular);
        if (p != k) {
            double t = x[p];
            swap_rows(a, p, k, n);
            x[p] = x[k];
            x[k] = t;
        }
        int rk = k * n;
        double piv = a[rk + k];
        for (int i = k + 1; i < n; i++) {
            int ri = i * n;
            double f = a[ri + k] / piv;
            for (int j = k + 1; j < n; j++)
                a[ri + j] -= f * a[rk + j];
            x[i] -= f * x[k];
        }
    }
    for (int i = n - 1; i >= 0; i--) {
        int ri = i * n;
        double s = x[i];
        for (int j = i + 1; j < n; j++)
            s -= a[ri + j] * x[j];
        x[i] = s / a[ri + i];
    }
    memcpy(xo, x, (size_t)n * sizeof(double));
    return singular ? -1 : 0;
}

int rc_la_inverse(const double *A, int n, double *out)
{
    double a[RC_LA_NMAX * RC_LA_NMAX], inv[RC_LA_NMAX * RC_LA_NMAX];
    int singular = 0;
    memcpy(a, A, (size_t)(n * n) * sizeof(double));
    rc_la_identity(inv, n);
    for (int k = 0; k < n; k++) {
        int p = pivot_row(a, k, n, &singular);
        if (p != k) {
            swap_rows(a, p, k, n);
            swap_rows(inv, p, k, n);
        }
        int rk = k * n;
        double piv = a[rk + k];
        for (int j = k + 1; j < n; j++)
            a[rk + j] /= piv;
        a[rk + k] = 1.0;
        for (int j = 0; j < n; j++)
            inv[rk + j] /= piv;
        for (int i = 0; i < n; i++) {
            if (i == k)
                continue;
            int ri = i * n;
            double f = a[ri + k];
            for (int j = k + 1; j < n; j++)
                a[ri + j] -= f * a[rk + j];
            a[ri + k] = 0.0;
            for (int j = 0; j < n; j++)
                inv[ri + j] -= f * inv[rk + j];
        }
    }
    memcpy(out, inv, (size_t)(n * n) * sizeof(double));
    return singular ? -1 : 0;
}

int rc_la_is_positive_definite(const double *A, int n)
{
    double L[RC_LA_NMAX * RC_LA_NMAX] = {0.0};
    for (int j = 0; j < n; j++) {
        int rj = j * n;
        double d = A[rj + j];
        for (int k = 0; k < j; k++)
            d -= L[rj + k] * L[rj + k];
        if (!(d > 0.0))
            return 0;
        double ljj = sqrt(d);
        L[rj + j] = ljj;
        for (int i = j + 1; i < n; i++) {
            int ri = i * n;
            double s = A[ri + j];
            for (int k = 0; k < j; k++)
                s -= L[ri + k] * L[rj + k];
            L[ri + j] = s / ljj;
        }
    }
    return 1;
}

void rc_la_eigh(const double *A, int n, double *w, double *Vo)
{
    double a[RC_LA_NMAX * RC_LA_NMAX], V[RC_LA_NMAX * RC_LA_NMAX];
    memcpy(a, A, (size_t)(n * n) * sizeof(double));
    rc_la_identity(V, n);
    for (int sweep = 0; sweep < RC_LA_MAX_SWEEPS; sweep++) {
        double off = 0.0;
        for (int p = 0; p < n - 1; p++)
            for (int q = p + 1; q < n; q++)
                off += a[p * n + q] * a[p * n + q];
        if (off == 0.0)
            break;
        for (int p = 0; p < n - 1; p++) {
            for (int q = p + 1; q < n; q++) {
                double apq = a[p * n + q];
                if (apq == 0.0)
                    continue;
                double app = a[p * n + p];
                double aqq = a[q * n + q];
                double g = 100.0 * fabs(apq);
                if (fabs(app) + g == fabs(app) && fabs(aqq) + g == fabs(aqq)) {
                    a[p * n + q] = 0.0;
                    a[q * n + p] = 0.0;
                    continue;
                }
                double theta = (aqq - app) / (2.0 * apq);
                double t;
                if (fabs(theta) > 1e150)
                    t = 0.5 / theta;
                else {
                    t = 1.0 / (fabs(theta) + sqrt(theta * theta + 1.0));
                    if (theta < 0.0)
                        t = -t;
                }
                double c = 1.0 / sqrt(t * t + 1.0);
                double s = t * c;
                double tau = s / (1.0 + c);
                double h = t * apq;
                a[p * n + p] = app - h;
                a[q * n + q] = aqq + h;
                a[p * n + q] = 0.0;
                a[q * n + p] = 0.0;
                for (int r = 0; r < n; r++) {
                    if (r == p || r == q)
                        continue;
                    double gr = a[r * n + p];
                    double hr = a[r * n + q];
                    double rp = gr - s * (hr + gr * tau);
                    double rq = hr + s * (gr - hr * tau);
                    a[r * n + p] = rp;
                    a[p * n + r] = rp;
                    a[r * n + q] = rq;
                    a[q * n + r] = rq;
                }
                for (int r = 0; r < n; r++) {
                    double gr = V[r * n + p];
                    double hr = V[r * n + q];
                    V[r * n + p] = gr - s * (hr + gr * tau);
                    V[r * n + q] = hr + s * (gr - hr * tau);
                }
            }
        }
    }
    for (int i = 0; i < n; i++)
        w[i] = a[i * n + i];
    memcpy(Vo, V, (size_t)(n * n) * sizeof(double));
}

void rc_la_inverse_from_eigen(const double *w, const double *V, int n, double *out)
{
    double tmp[RC_LA_NMAX * RC_LA_NMAX];
    for (int i = 0; i < n; i++)
        for (int j = 0; j < n; j++) {
            double s = 0.0;
            for (int k = 0; k < n; k++)
                s += V[i * n + k] / w[k] * V[j * n + k];
            tmp[i * n + j] = s;
        }
    memcpy(out, tmp, (size_t)(n * n) * sizeof(double));
}
