/* repr.c -- the core's messages: Python's repr() of a float (a message names a value as Python
 * does) and rc_refuse / rc_vrefuse, which write a refusal's message. */
#include "rc_fp_contract.h"
#include "rc_common.h"

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

void rc_repr(double x, char *buf, int size)
{
    if (isnan(x)) {
        snprintf(buf, size, "nan");
        return;
    }
    if (isinf(x)) {
        snprintf(buf, size, x > 0 ? "inf" : "-inf");
        return;
    }
    char tmp[40], digits[24], out[64];
    int p, e = 0, nd = 0;
    for (p = 1; p <= 17; p++) {        /* the shortest digits that read back as x */
        snprintf(tmp, sizeof tmp, "%.*e", p - 1, x);
        if (strtod(tmp, NULL) == x)
            break;
    }
    const char *s = tmp;
    int negative = *s == '-';
    if (negative)
        s++;
    for (; *s && *s != 'e'; s++)
        if (*s >= '0' && *s <= '9')
            digits[nd++] = *s;
    if (*s == 'e')
        e = atoi(s + 1);
    while (nd > 1 && digits[nd - 1] == '0')
        nd--;
    digits[nd] = '\0';
    int decpt = e + 1, n = 0;            /* x = 0.digits * 10^decpt */
    n += snprintf(out + n, sizeof out - n, "%s", negative ? "-" : "");
    if (decpt <= -4 || decpt > 16) {     /* Python's repr switches to an exponent here */
        n += snprintf(out + n, sizeof out - n, "%c", digits[0]);
        if (nd > 1)
            n += snprintf(out + n, sizeof out - n, ".%s", digits + 1);
        snprintf(out + n, sizeof out - n, "e%c%02d", e < 0 ? '-' : '+', e < 0 ? -e : e);
    } else if (decpt <= 0) {
        n += snprintf(out + n, sizeof out - n, "0.");
        for (int k = 0; k < -decpt; k++)
            n += snprintf(out + n, sizeof out - n, "0");
        snprintf(out + n, sizeof out - n, "%s", digits);
    } else if (decpt >= nd) {
        n += snprintf(out + n, sizeof out - n, "%s", digits);
        for (int k = 0; k < decpt - nd; k++)
            n += snprintf(out + n, sizeof out - n, "0");
        snprintf(out + n, sizeof out - n, ".0");
    } else {
        snprintf(out + n, sizeof out - n, "%.*s.%s", decpt, digits, digits + decpt);
    }
    snprintf(buf, size, "%s", out);
}

rc_status rc_vrefuse(char *msg, size_t size, rc_status status, const char *fmt, va_list ap)
{
    if (msg)
        vsnprintf(msg, size, fmt, ap);
    return status;
}

rc_status rc_refuse(rc_error *err, rc_status status, const char *fmt, ...)
{
    if (err) {
        va_list ap;
        va_start(ap, fmt);
        rc_vrefuse(err->msg, sizeof err->msg, status, fmt, ap);
        va_end(ap);
    }
    return status;
}

rc_status rc_refuse_value(rc_error *err, const char *where, const char *name, const char *rule,
                          double v)
{
    char r[40];
    rc_repr(v, r, sizeof r);
    return rc_refuse(err, RC_BAD_CONFIG, "%s%s %s, got %s", where, name, rule, r);
}
