/* ato_tuning_shim.c -- test-only: models/core/ato_tuning.c on flat arrays for ctypes
 * (tests/model_tests/core/test_core_ato_tuning.py). A tuning is ATO_N_TUNING_FIELDS doubles in
 * AtoTuning's order (bool and int fields as whole numbers).
 *
 * With -DATO_TUNING_MAIN it is a program for the sanitizer run: each line of stdin is
 *   <prefix> <ATO_N_TUNING_FIELDS values as strtod reads them>
 * (prefix "-": NULL); it prints "<status> <message>" per line. */
#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "ato_tuning.h"

int shim_n_fields(void) { return ATO_N_TUNING_FIELDS; }
int shim_n_inputs(int *all) { *all = ATO_N_ALL_INPUTS; return ATO_N_INPUTS; }
const char *shim_input_name(int index) { return ato_input_name(index); }
double shim_stated_prior(int index) { return ato_stated_prior(index); }

/* Field k's name (NULL outside), kind and offset */
const char *shim_field(int k, int *kind, long *offset)
{
    const ato_tuning_field *f = ato_tuning_field_at(k);
    if (!f)
        return NULL;
    *kind = (int)f->kind;
    *offset = (long)f->offset;
    return f->name;
}

int shim_field_named(const char *name)
{
    const ato_tuning_field *f = ato_tuning_field_named(name);
    return f ? (int)(f - ato_tuning_field_at(0)) : -1;
}

static void to_values(const ato_tuning *t, double *out)
{
    for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = ato_tuning_field_at(k);
        const char *at = (const char *)t + f->offset;
        out[k] = f->kind == ATO_FIELD_REAL ? *(const double *)at : (double)*(const int *)at;
    }
}

/* 0, or -1 - k when field k (bool or int) is not a whole number in int's range */
static int from_values(ato_tuning *t, const double *values)
{
    for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = ato_tuning_field_at(k);
        char *at = (char *)t + f->offset;
        if (f->kind == ATO_FIELD_REAL) {
            *(double *)at = values[k];
            continue;
        }
        if (!(values[k] >= INT_MIN && values[k] <= INT_MAX) || values[k] != (int)values[k])
            return -1 - k;
        *(int *)at = (int)values[k];
    }
    return 0;
}

void shim_defaults(double *out)
{
    ato_tuning t;
    ato_tuning_defaults(&t);
    to_values(&t, out);
}

/* RC_OK / RC_BAD_CONFIG with the message, or -1 - k for an unrepresentable field k */
int shim_validate(const double *values, const char *prefix, char *msg, int size)
{
    ato_tuning t;
    rc_error err;
    ato_tuning_defaults(&t);
    int bad = from_values(&t, values);
    if (bad != 0)
        return bad;
    rc_status st = ato_tuning_validate(&t, prefix, &err);
    if (msg && size > 0)
        snprintf(msg, (size_t)size, "%s", err.msg);
    if (ato_tuning_validate(&t, prefix, NULL) != st)     /* err may be NULL: the same status */
        return -1000;
    return (int)st;
}

#ifdef ATO_TUNING_MAIN
int main(void)
{
    char prefix[32], tok[64], msg[RC_MSG_SIZE];
    double v[ATO_N_TUNING_FIELDS];
    while (scanf("%31s", prefix) == 1) {
        for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
            if (scanf("%63s", tok) != 1)
                return 2;
            v[k] = strtod(tok, NULL);
        }
        int st = shim_validate(v, strcmp(prefix, "-") == 0 ? NULL : prefix, msg, sizeof msg);
        printf("%d %s\n", st, msg);
    }
    return 0;
}
#endif
