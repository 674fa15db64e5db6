/* linalg4.h -- models/linalg4.py in C, operation for operation: small dense matrices, flat
 * row-major double[n*n], vectors double[n]. Every sum runs in the order of the Python reference
 * (compile with -ffp-contract=off), so the results are bit-identical to it.
 *
 * Singular input: where linalg4.py raises SingularMatrixError (a pivot exactly 0.0), solve and
 * inverse return -1 and go on dividing by the zero pivot (the result holds inf/NaN); 0 otherwise.
 * No allocation: scratch lives on the stack, n <= RC_LA_NMAX. */
#ifndef RAILCAR_LINALG4_H
#define RAILCAR_LINALG4_H

#define RC_LA_NMAX 8
#define RC_LA_MAX_SWEEPS 50        /* linalg4.MAX_SWEEPS */

void rc_la_identity(double *out, int n);
/* out = sum_k rows[k] rows[k]^T (accumulated onto 0.0 in row order); rows: m x n, row-major */
void rc_la_gram(const double *rows, long m, int n, double *out);
/* out = Phi^T y */
void rc_la_gram_t_vec(const double *rows, const double *y, long m, int n, double *out);
double rc_la_dot(const double *a, const double *b, int n);
void rc_la_matvec(const double *A, const double *x, int n, double *out);
/* x with A x = b (x may be b); -1 when a pivot was exactly 0 */
int rc_la_solve(const double *A, const double *b, int n, double *x);
/* out = A^-1 (out may be A); -1 when a pivot was exactly 0 */
int rc_la_inverse(const double *A, int n, double *out);
/* 1 when the Cholesky factorisation of A's lower triangle succeeds, else 0 */
int rc_la_is_positive_definite(const double *A, int n);
/* eigenvalues w[n] (diagonal order, unsorted) and eigenvectors (columns of V) of symmetric A */
void rc_la_eigh(const double *A, int n, double *w, double *V);
/* out = V diag(w)^-1 V^T */
void rc_la_inverse_from_eigen(const double *w, const double *V, int n, double *out);

#endif
