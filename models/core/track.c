/* track.c -- see track.h; the bodies of models/plant/track.py's GradeProfile and SpeedProfile. */
#include "rc_fp_contract.h"
#include "track.h"

#include <stdlib.h>
#include <string.h>

/* bisect.bisect_right(d[0..n), x): the first index whose distance exceeds x */
static long bisect_right(const double *d, long n, double x)
{
    long lo = 0, hi = n;
    while (lo < hi) {
        long mid = (lo + hi) / 2;
        if (x < d[mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    return lo;
}

void rc_grade_cumulate(const double *distances, const double *grades, long n, double *cum)
{
    cum[0] = 0.0;
    for (long k = 1; k < n; k++)
        cum[k] = cum[k - 1] + grades[k - 1] * (distances[k] - distances[k - 1]);
}

double rc_grade_at(const rc_grade_profile *g, double x)
{
    long k = bisect_right(g->distances, g->n, x) - 1;
    return g->grades[k >= 0 ? k : 0];
}

static double grade_integral(const rc_grade_profile *g, double x)
{
    long k = bisect_right(g->distances, g->n, x) - 1;
    if (k < 0)
        return g->grades[0] * (x - g->distances[0]);
    return g->cum[k] + g->grades[k] * (x - g->distances[k]);
}

double rc_grade_average(const rc_grade_profile *g, double x, double length)
{
    if (length <= 0.0)
        return rc_grade_at(g, x);
    return (grade_integral(g, x) - grade_integral(g, x - length)) / length;
}

double rc_speed_at(const rc_speed_profile *s, double x)
{
    const double *d = s->distances;
    long k = bisect_right(d, s->n, x);
    if (k == 0)
        return s->speeds[0];
    if (k == s->n)
        return s->speeds[s->n - 1];
    double x0 = d[k - 1], x1 = d[k];
    double v0 = s->speeds[k - 1], v1 = s->speeds[k];
    return v0 + (v1 - v0) * (x - x0) / (x1 - x0);
}

int rc_profiles_copy(const double *grade_distances, const double *grades, long grade_n,
                     const double *speed_distances, const double *speeds, long speed_n,
                     double **buffer, rc_grade_profile *grade, rc_speed_profile *speed)
{
    long ng = grade_n, ns = speed_n;
    *buffer = NULL;
    if (ng < 1 || ns < 0)
        return -1;
    double *b = malloc(sizeof(double) * (size_t)(3 * ng + 2 * ns));
    if (!b)
        return -1;
    double *gd = b, *gg = gd + ng, *gc = gg + ng, *sd = gc + ng, *sv = sd + ns;
    memcpy(gd, grade_distances, sizeof(double) * (size_t)ng);
    memcpy(gg, grades, sizeof(double) * (size_t)ng);
    rc_grade_cumulate(gd, gg, ng, gc);
    if (ns) {
        memcpy(sd, speed_distances, sizeof(double) * (size_t)ns);
        memcpy(sv, speeds, sizeof(double) * (size_t)ns);
    }
    grade->distances = gd;
    grade->grades = gg;
    grade->cum = gc;
    grade->n = ng;
    speed->distances = ns ? sd : NULL;
    speed->speeds = ns ? sv : NULL;
    speed->n = ns;
    *buffer = b;
    return 0;
}
