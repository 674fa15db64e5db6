/* pow_square: how often this C library's pow(x, 2.0) is not x * x (correctly rounded).
 *
 *   pow_square N     prints "N MISMATCHES BEYOND_ONE_ULP"
 *
 * x = 1 / (g m) for N masses m spread over 10 t .. 200 t by a fixed xorshift sequence: the
 * values of theta1 = 1 / (g m) whose square the estimator's mass_std divides by
 * (models/core/ident.c). Built for Linux and for Windows (mingw-w64, -static) by
 * tests/fmu_tests/test_cross_platform.py, which explains with it why est.mass_std is not
 * bit-identical under Wine. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>

int main(int argc, char **argv) {
    volatile double two = 2.0;      /* keeps the compiler from turning pow(x, 2.0) into x * x */
    unsigned long long state = 88172645463325252ULL;
    long n = argc > 1 ? atol(argv[1]) : 1000000, i, mismatches = 0, beyond = 0;
    for (i = 0; i < n; i++) {
        double unit, x, p, q;
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        unit = (double)(state >> 11) / 9007199254740992.0;      /* [0, 1) */
        x = 1.0 / (9.81 * (10e3 + 190e3 * unit));
        p = pow(x, two);
        q = x * x;
        if (p != q) {
            mismatches++;
            if (p > nextafter(q, INFINITY) || p < nextafter(q, -INFINITY)) beyond++;
        }
    }
    printf("%ld %ld %ld\n", n, mismatches, beyond);
    return 0;
}
