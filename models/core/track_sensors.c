/* track_sensors.c -- see track_sensors.h; the expressions of models/plant/track_sensors.py and
 * models/chain.py in their order (numpy's elementwise ops on scalars are IEEE double ops). */
#include "rc_fp_contract.h"
#include "track_sensors.h"

#include <math.h>

double rc_track_speed_std(double v, double base, double resolution, double jitter)
{
    /* interval_error_variance(resolution, jitter) */
    double var = resolution * resolution / 6.0 + 2.0 * jitter * jitter;
    return v * v / base * sqrt(var);
}

double rc_track_quantise(double t, double resolution)
{
    const double phase = 0.0;
    if (resolution == 0.0)
        return t;
    return floor((t - phase) / resolution) * resolution + phase;
}

double rc_track_speed_from_times(double t1, double t2, double base, double resolution,
                                 double j1, double j2)
{
    double s1 = rc_track_quantise(t1 + j1, resolution);
    double s2 = rc_track_quantise(t2 + j2, resolution);
    double dt = s2 - s1;
    return dt > 0.0 ? base / dt : INFINITY;
}

/* x_at(s) of _hermite_crossing */
static double hermite_at(double s, double h, double x0, double v0, double x1, double v1)
{
    double s2 = s * s, s3 = s * s * s;
    return (2.0 * s3 - 3.0 * s2 + 1.0) * x0 + (s3 - 2.0 * s2 + s) * h * v0
           + (-2.0 * s3 + 3.0 * s2) * x1 + (s3 - s2) * h * v1;
}

double rc_track_hermite_crossing(double t0, double x0, double v0, double t1, double x1, double v1,
                                 double d)
{
    double h = t1 - t0;
    double lo = 0.0, hi = 1.0;
    for (int i = 0; i < 50; i++) {
        double mid = 0.5 * (lo + hi);
        if (hermite_at(mid, h, x0, v0, x1, v1) < d)
            lo = mid;
        else
            hi = mid;
    }
    return t0 + 0.5 * (lo + hi) * h;
}
