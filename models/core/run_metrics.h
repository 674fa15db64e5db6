/* run_metrics.h -- the metrics of a recorded RailCar run that run a model again, in C (issue 31: a
 * run's metrics at the speed of the core): the twins of harness/metrics/estimation.py's
 * oracle_filter (with _interval_forces and true_theta), coast_segments and coast_time, and of
 * models.plant.dynamics.applied_forces (the wind they read: script_common.h rc_wind_schedule_at).
 * Bit-identical to the Python, which stays the reference
 * (tests/model_tests/core/test_core_run_metrics.py).
 *
 * The oracle is the library's estimator (estimator.h) with a frozen identifier whose theta is set
 * to the truth before every sample, replaying the recorded measurements and interval forces. The
 * coast times re-run a coast with RK4 (plant.h rc_rk4_step) until the coast's end distance.
 * Arrays are the caller's; rc_oracle_filter and rc_coast_times allocate only at their start (the
 * grade profile's integral, the estimator's buffers) and free it before they return. */
#ifndef RAILCAR_RUN_METRICS_H
#define RAILCAR_RUN_METRICS_H

#include "plant.h"
#include "railcar.h"
#include "script_common.h"          /* rc_wind_schedule_at: the wind of a run */

#define RC_COASTING_MODE 2.0     /* car.mode of a coast (RC_COASTING) */

/* models.plant.dynamics.applied_forces: the traction and brake force [N] the car p applies at
 * speed v [m/s] for the demands [N] (a brake demand cuts traction; each force clipped to its limit) */
void rc_applied_forces(const rc_vehicle *p, double v, double traction_demand, double brake_demand,
                       double *traction, double *brake);

/* harness.metrics.estimation._interval_forces with recorded demands: for k < n - 1, the mean of the
 * applied forces at speed[k] and speed[k + 1] with demands[k] held, the car `car` with its mass
 * mass[k + 1] [t] -> traction_mean[k], brake_mean[k] [N] */
void rc_interval_forces(const rc_vehicle *car, long n, const double *speed, const double *mass,
                        const double *traction_demand, const double *brake_demand,
                        double *traction_mean, double *brake_mean);

/* harness.metrics.estimation.true_theta: (1/(P g), A0 + A2 w^2, A1 + 2 A2 w, A2) for a mass [t], the
 * still-air A[3] and the wind w [m/s] -> theta[4] */
void rc_true_theta(double mass_t, const double *A, double wind, double *theta);

typedef struct {                 /* what oracle_filter builds its estimator from */
    rc_estchain_config est;      /* identifier (frozen), filter, station, method 0; the profiles
                                    (EstimatorChain's flat layout, config.c; track values unread) */
    double A[3];                 /* the car's still-air A0, A1, A2 */
    double step;                 /* the run's communication step = the sample period [s] */
    const double *wind;          /* the scenario's wind schedule: wind_n (time_s, speed_mps) rows */
    long wind_n;
} rc_oracle_config;

/* harness.metrics.estimation.oracle_filter's loop over n >= 1 rows: per row k the truth theta
 * (mass[k], the wind at time[k]) set, the measurements (speed_meas[k], position_meas[k]) taken,
 * the filter's speed and distance written to v_out[k], x_out[k], then (k < n - 1) the prediction
 * with traction_mean[k], brake_mean[k] [N] over the step. RC_OK, or RC_BAD_CONFIG naming the
 * first bad setting (the Python estimator's message) or "out of memory". */
rc_status rc_oracle_filter(const rc_oracle_config *cfg, long n, const double *time,
                           const double *mass, const double *speed_meas,
                           const double *position_meas, const double *traction_mean,
                           const double *brake_mean, double *v_out, double *x_out, rc_error *err);

/* harness.metrics.estimation.coast_segments: the (first, last) rows of each run of mode ==
 * RC_COASTING_MODE at least min_rows long among mode[n], into first[], last[] (room for n / 2 + 1
 * each is always enough); returns how many */
long rc_coast_segments(const double *mode, long n, long min_rows, long *first, long *last);

/* harness.metrics.estimation.coast_time with the wind of a schedule: the time [s] the car p
 * (coasting: no demand) takes from x0 to x1 [m] starting at v0 [m/s] on the grade, RK4 steps of h
 * [s] with the wind rc_wind_schedule_at(wind, wind_n, t0 + t) held over each (no rows: still air);
 * inf when it stops short or t_max [s] passes */
double rc_coast_time(const rc_vehicle *p, const rc_grade_profile *grade, double v0, double x0,
                     double x1, const double *wind, long wind_n, double t0, double h, double t_max);

#endif
