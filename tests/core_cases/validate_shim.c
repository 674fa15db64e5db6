/* validate_shim.c -- test-only: rc_chain_validate / rc_estchain_validate (models/core/validate.c)
 * on the flat arrays of models/compiled.py (_config_values; CompiledEstimatorChain's list),
 * turned into configurations by config.c. Loaded with ctypes by tests/model_tests/core/test_core_validate.py.
 *
 * With -DVALIDATE_MAIN it is a program for the sanitizer run: each line of stdin is
 *   <c|e> <slope_window> <has_speed_profile> <n> <n values as strtod reads them>
 * (c: the chain, e: the estimator chain); it prints "<status> <message>" per line. */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "../../models/core/validate.h"

static void copy_message(const rc_error *err, char *msg, int size)
{
    if (msg && size > 0)
        snprintf(msg, (size_t)size, "%s", err->msg);
}

/* RC_OK / RC_BAD_CONFIG, or -1 when n is not the count config.c expects */
int shim_chain_validate(const double *values, long n, long slope_window, int has_speed_profile,
                        char *msg, int size)
{
    rc_chain_config cfg;
    rc_error err;
    memset(&cfg, 0, sizeof cfg);
    if (rc_chain_config_from_values(&cfg, values, n) != 0)
        return -1;
    rc_status st = rc_chain_validate(&cfg, slope_window, has_speed_profile, &err);
    copy_message(&err, msg, size);
    return (int)st;
}

int shim_estchain_validate(const double *values, long n, long slope_window,
                           int has_speed_profile, char *msg, int size)
{
    rc_estchain_config cfg;
    rc_error err;
    memset(&cfg, 0, sizeof cfg);
    if (rc_estchain_config_from_values(&cfg, values, n) != 0)
        return -1;
    rc_status st = rc_estchain_validate(&cfg, slope_window, has_speed_profile, &err);
    copy_message(&err, msg, size);
    return (int)st;
}

/* A NULL err is allowed everywhere: the status alone */
int shim_chain_validate_quiet(const double *values, long n, long slope_window,
                              int has_speed_profile)
{
    rc_chain_config cfg;
    memset(&cfg, 0, sizeof cfg);
    if (rc_chain_config_from_values(&cfg, values, n) != 0)
        return -1;
    return (int)rc_chain_validate(&cfg, slope_window, has_speed_profile, NULL);
}

#ifdef VALIDATE_MAIN
int main(void)
{
    char which;
    long slope_window, n;
    int has_speed;
    while (scanf(" %c %ld %d %ld", &which, &slope_window, &has_speed, &n) == 4) {
        double *v;
        char tok[64], msg[RC_MSG_SIZE];
        if (n < 0 || n > 1000 || !(v = malloc(sizeof(double) * (size_t)(n ? n : 1))))
            return 2;
        for (long k = 0; k < n; k++) {
            if (scanf("%63s", tok) != 1) {
                free(v);
                return 2;
            }
            v[k] = strtod(tok, NULL);
        }
        int st = which == 'c' ? shim_chain_validate(v, n, slope_window, has_speed, msg, sizeof msg)
                              : shim_estchain_validate(v, n, slope_window, has_speed, msg,
                                                       sizeof msg);
        if (which == 'c' && shim_chain_validate_quiet(v, n, slope_window, has_speed) != st)
            return 3;
        printf("%d %s\n", st, msg);
        free(v);
    }
    return 0;
}
#endif
