/* ato_line_profile.c -- the AtoController's line files (fmu_src/ato_controller.py
 * read_line_profile, read_line_limits) in C; see ato_line_profile.h. */
#include "rc_fp_contract.h"
#include "ato_line_profile.h"

#include <limits.h>
#include <stdlib.h>
#include <string.h>

#define REPR_SIZE 40

static const char LINE_WHERE[] = "line.profile: ";
static const char LIMITS_WHERE[] = "line.speed_limit_profile: ";

static const char *repr(double x, char *buf)
{
    rc_repr(x, buf, REPR_SIZE);
    return buf;
}

int ato_line_profile_parse(const char *text, size_t len, const char *path, ato_line_row **rows,
                           long *n, rc_profile *out)
{
    static const char *const columns[] = ATO_LINE_COLUMNS;
    rc_csv_rows r;
    char a[REPR_SIZE], b[REPR_SIZE];
    double x[5];
    long lineno = 0;
    int got = 0;
    *rows = NULL;
    *n = 0;
    if (rc_csv_rows_open(&r, text, len, path, LINE_WHERE, columns, 5, out) != RC_OK)
        return RC_BAD_CONFIG;
    ato_line_row *all = malloc(sizeof *all * (r.lines ? r.lines : 1));
    if (!all) {
        rc_csv_rows_close(&r);
        return rc_profile_refuse(out, "out of memory");
    }
    long k = 0;
    int status = RC_OK;
    while (status == RC_OK && (got = rc_csv_rows_next(&r, x, &lineno, out)) == 1) {
        double stop = x[0], length = x[1], schedule = x[2], dwell = x[3];
        if (stop <= 0.0)
            status = rc_profile_refuse(out, "%s%s: line %ld: stop_m must be > 0, got %s",
                                       LINE_WHERE, path, lineno, repr(stop, a));
        else if (length != 0.0 && length < stop)
            status = rc_profile_refuse(out, "%s%s: line %ld: length_m = %s m is shorter than "
                                       "stop_m = %s m (0: stop_m)", LINE_WHERE, path, lineno,
                                       repr(length, a), repr(stop, b));
        else if (schedule <= 0.0)
            status = rc_profile_refuse(out, "%s%s: line %ld: schedule_s must be > 0, got %s",
                                       LINE_WHERE, path, lineno, repr(schedule, a));
        else if (dwell <= 0.0)
            status = rc_profile_refuse(out, "%s%s: line %ld: dwell_s must be > 0 (the standstill "
                                       "at the station before the span), got %s", LINE_WHERE,
                                       path, lineno, repr(dwell, a));
        else {
            ato_line_row *row = &all[k++];
            row->stop = stop;
            row->length = length;
            row->schedule = schedule;
            row->dwell = dwell;
            row->boarding = x[4];
            row->line = lineno;
        }
    }
    rc_csv_rows_close(&r);
    if (status == RC_OK && got < 0)                 /* the row reader's refusal, in out */
        status = RC_BAD_CONFIG;
    if (status == RC_OK && k == 0)
        status = rc_profile_refuse(out, "%s%s: no span: give a row per span after the first, or "
                                   "leave line.profile empty for one span", LINE_WHERE, path);
    if (status != RC_OK) {
        free(all);
        return status;
    }
    *rows = all;
    *n = k;
    return RC_OK;
}

void ato_line_limits_free(ato_line_limits *l)
{
    free(l->distances);
    free(l->first);
    memset(l, 0, sizeof *l);
}

int ato_line_limits_parse(const char *text, size_t len, const char *path, int spans,
                          ato_line_limits *out, rc_profile *err)
{
    static const char *const columns[] = ATO_LINE_LIMIT_COLUMNS;
    rc_csv_rows r;
    char a[REPR_SIZE], b[REPR_SIZE];
    double x[3];
    long lineno = 0, n = 0;
    int got = 0, last = 1;
    memset(out, 0, sizeof *out);
    if (spans < 1 || spans > INT_MAX - 1)
        return rc_profile_refuse(err, "%s%s: a line of %d spans", LIMITS_WHERE, path, spans);
    if (rc_csv_rows_open(&r, text, len, path, LIMITS_WHERE, columns, 3, err) != RC_OK)
        return RC_BAD_CONFIG;
    size_t room = r.lines ? r.lines : 1;
    out->distances = malloc(sizeof(double) * 2 * room);
    out->first = calloc(2 * ((size_t)spans + 1), sizeof(long));
    if (!out->distances || !out->first) {
        rc_csv_rows_close(&r);
        ato_line_limits_free(out);
        return rc_profile_refuse(err, "out of memory");
    }
    out->speeds = out->distances + room;
    out->count = out->first + spans + 1;
    out->spans = spans;
    int status = RC_OK;
    while (status == RC_OK && (got = rc_csv_rows_next(&r, x, &lineno, err)) == 1) {
        double span = x[0], distance = x[1], limit = x[2];
        if (!(span == trunc(span) && span >= 2.0 && span <= (double)spans)) {
            char g[32];
            rc_profile_g(span, g, sizeof g);
            status = rc_profile_refuse(err, "%s%s: line %ld: span must be one of line.profile's "
                                       "spans, 2 .. %d, got %s", LIMITS_WHERE, path, lineno,
                                       spans, g);
            break;
        }
        int k = (int)span;
        if (k < last) {
            status = rc_profile_refuse(err, "%s%s: line %ld: span %d after span %d: give each "
                                       "span's rows together, in span order", LIMITS_WHERE,
                                       path, lineno, k, last);
            break;
        }
        if (out->count[k] == 0)
            out->first[k] = n;
        if (out->count[k] == 0 && distance != 0.0)
            status = rc_profile_refuse(err, "%s%s: line %ld: span %d's first limit must start at "
                                       "distance_m 0, got %s", LIMITS_WHERE, path, lineno, k,
                                       repr(distance, a));
        else if (out->count[k] > 0 && distance <= out->distances[n - 1])
            status = rc_profile_refuse(err, "%s%s: line %ld: distance_m must increase within a "
                                       "span (%s after %s)", LIMITS_WHERE, path, lineno,
                                       repr(distance, a), repr(out->distances[n - 1], b));
        else if (limit <= 0.0)
            status = rc_profile_refuse(err, "%s%s: line %ld: speed_limit_mps must be > 0, got %s",
                                       LIMITS_WHERE, path, lineno, repr(limit, a));
        else {
            out->distances[n] = distance;
            out->speeds[n] = limit;
            out->count[k]++;
            n++;
            last = k;
        }
    }
    rc_csv_rows_close(&r);
    if (status == RC_OK && got < 0)                 /* the row reader's refusal, in err */
        status = RC_BAD_CONFIG;
    if (status != RC_OK)
        ato_line_limits_free(out);
    return status;
}
