/* validate.c -- see validate.h: the validate() methods of models/ in their order, with their
 * messages (floats as Python's repr(), ints as str()). */
#include "rc_fp_contract.h"
#include "validate.h"

#include <stdarg.h>
#include <stdio.h>

#define SEED_MAX 2147483647L            /* 2 ** 31 - 1: the FMU's seed is an fmi2Integer */
#define MAX_INITIAL_SPEED 200.0        /* [m/s] chain.MAX_MEASURED_SPEED */
#define MAX_BATCH_SIZE 100000L          /* identification.MAX_BATCH_SIZE */
#define MAX_SLOPE_WINDOW 1000L          /* identification.MAX_SLOPE_WINDOW */

static void clear(rc_error *err)
{
    if (err)
        err->msg[0] = '\0';
}

rc_status rc_track_sensors_validate(double spacing, double base, double resolution, double jitter,
                                    rc_error *err)
{
    clear(err);
    const char *names[] = {"sensor.track_spacing", "sensor.track_jitter"};
    const double values[] = {spacing, jitter};
    for (int k = 0; k < 2; k++)
        if (!(values[k] >= 0 && isfinite(values[k])))
            return rc_refuse_value(err, "", names[k], "must be >= 0", values[k]);
    if (!(base > 0 && isfinite(base)))
        return rc_refuse_value(err, "", "sensor.track_base", "must be > 0", base);
    if (!(resolution >= 0 && isfinite(resolution)))
        return rc_refuse_value(err, "", "sensor.track_resolution", "must be >= 0", resolution);
    if (spacing != 0.0 && spacing <= base) {           /* `if self.spacing and ...` */
        char a[40], b[40];
        rc_repr(spacing, a, sizeof a);
        rc_repr(base, b, sizeof b);
        return rc_refuse(err, RC_BAD_CONFIG, "sensor.track_spacing (%s) must exceed sensor.track_base (%s)", a, b);
    }
    return RC_OK;
}

rc_status rc_station_validate(const rc_station_config *cfg, rc_error *err)
{
    clear(err);
    if (!(cfg->dwell > 0 && isfinite(cfg->dwell)))
        return rc_refuse_value(err, "", "track.station_dwell", "must be > 0", cfg->dwell);
    return RC_OK;
}

/* IdentifierConfig.validate; with native_fmu, the options the core does not cover are refused
 * right after Python's check of their value, naming the pythonfmu FMU that runs them */
static rc_status ident_validate(const rc_ident_config *c, int method, int physical,
                                int sigma2_method, long slope_window, const char *native_fmu,
                                rc_error *err)
{
    static const char *const fmt = "%s = %d is not in the native %s FMU (only 0, %s): use "
                                   "%s.fmu (pythonfmu) for it";
    clear(err);
    if (c->batch_size < 4)
        return rc_refuse(err, RC_BAD_CONFIG, "est.batch_size must be >= 4 (4 parameters), got %ld", c->batch_size);
    if (!(method >= 0 && method <= 3))                 /* identification.METHODS */
        return rc_refuse(err, RC_BAD_CONFIG, "est.method must be 0 (paper LS), 1 (LS + filter-error refit), "
                           "2 (LS on Sidorenko's slopes), 3 (LS mass + Meleshin's coasting EKF), "
                           "got %d", method);
    if (native_fmu && method != 0 && method != 2)
        return rc_refuse(err, RC_BAD_CONFIG, fmt, "est.method", method, native_fmu,
                      "the paper's LS, or 2, LS on Sidorenko's slopes", native_fmu);
    if (!(sigma2_method == 0 || sigma2_method == 1))
        return rc_refuse(err, RC_BAD_CONFIG, "est.sigma2_method must be 0 (LAG sums of the LS residuals) or 1 "
                           "(innovation likelihood), got %d", sigma2_method);
    if (!(physical == 0 || physical == 1))
        return rc_refuse(err, RC_BAD_CONFIG, "est.physical must be 0 (as identified) or 1 (A0, A2 >= 0), got %d",
                      physical);
    if (slope_window < 2)
        return rc_refuse(err, RC_BAD_CONFIG, "est.slope_window must be >= 2 (a first-order fit), got %ld",
                      slope_window);
    if (!(0.0 <= c->run_forgetting && c->run_forgetting < 1.0))
        return rc_refuse_value(err, "", "est.run_forgetting", "must be in [0, 1)", c->run_forgetting);
    if (!(0.0 <= c->forgetting && c->forgetting < 1.0))
        return rc_refuse_value(err, "", "est.forgetting", "must be in [0, 1)", c->forgetting);
    if (!(c->dt > 0 && isfinite(c->dt)))
        return rc_refuse_value(err, "", "sampling period", "must be > 0", c->dt);
    const char *positive[] = {"est.mass_initial", "est.mass_std_initial", "est.A0_std_initial",
                              "est.A1_std_initial", "est.A2_std_initial", "est.sigma2_initial"};
    const double pv[] = {c->mass_initial, c->mass_std_initial, c->A0_std_initial,
                         c->A1_std_initial, c->A2_std_initial, c->sigma2_initial};
    for (int k = 0; k < 6; k++)
        if (!(pv[k] > 0 && isfinite(pv[k])))
            return rc_refuse_value(err, "", positive[k], "must be > 0", pv[k]);
    const char *finite[] = {"est.A0_initial", "est.A1_initial", "est.A2_initial", "est.gamma",
                            "est.speed_std"};
    const double fv[] = {c->A0_initial, c->A1_initial, c->A2_initial, c->gamma, c->speed_std};
    for (int k = 0; k < 5; k++)
        if (!isfinite(fv[k]))
            return rc_refuse_value(err, "", finite[k], "must be finite", fv[k]);
    if (c->gamma < 0)
        return rc_refuse_value(err, "", "est.gamma", "must be >= 0", c->gamma);
    /* identification.PRIOR_BOUNDS: the priors a run stays alive with (why: there) */
    static const struct {
        const char *name, *rule;
        double low, high;
    } bounds[] = {
        {"est.mass_initial", "must be in [1, 1000] t", 1.0, 1000.0},
        {"est.mass_std_initial", "must be in [1e-6, 1e8] t", 1e-6, 1e8},
        {"est.A0_initial", "must be in [-20, 20] N/kN", -20.0, 20.0},
        {"est.A1_initial", "must be in [-2, 2] N/kN/(m/s)", -2.0, 2.0},
        {"est.A2_initial", "must be in [-0.2, 0.2] N/kN/(m/s)^2", -0.2, 0.2},
        {"est.A0_std_initial", "must be in [1e-9, 1e8] N/kN", 1e-9, 1e8},
        {"est.A1_std_initial", "must be in [1e-9, 1e8] N/kN/(m/s)", 1e-9, 1e8},
        {"est.A2_std_initial", "must be in [1e-9, 1e8] N/kN/(m/s)^2", 1e-9, 1e8},
        {"est.sigma2_initial", "must be in [1e-20, 1] (m/s)^2 per sample", 1e-20, 1.0},
        {"est.gamma", "must be in [0, 1]", 0.0, 1.0},
        {"est.A0_drift_std", "must be in [0, 10] N/kN per stop", 0.0, 10.0},
        {"est.A1_drift_std", "must be in [0, 1] N/kN/(m/s) per stop", 0.0, 1.0},
    };
    const double bv[] = {c->mass_initial, c->mass_std_initial, c->A0_initial, c->A1_initial,
                         c->A2_initial, c->A0_std_initial, c->A1_std_initial, c->A2_std_initial,
                         c->sigma2_initial, c->gamma, c->A0_drift_std, c->A1_drift_std};
    for (size_t k = 0; k < sizeof bv / sizeof bv[0]; k++)
        if (!(bounds[k].low <= bv[k] && bv[k] <= bounds[k].high))
            return rc_refuse_value(err, "", bounds[k].name, bounds[k].rule, bv[k]);
    /* identification.DRIFT_METHODS: the LS's own carried A's */
    if ((c->A0_drift_std != 0.0 || c->A1_drift_std != 0.0) && method != 0 && method != 2) {
        char q0[40], q1[40];
        rc_repr(c->A0_drift_std, q0, sizeof q0);
        rc_repr(c->A1_drift_std, q1, sizeof q1);
        return rc_refuse(err, RC_BAD_CONFIG, "est.A0_drift_std and est.A1_drift_std apply to est.method 0 and 2 (the "
                           "LS's carried A's), got est.A0_drift_std = %s, est.A1_drift_std = %s "
                           "with est.method %d", q0, q1, method);
    }
    if (c->batch_size > MAX_BATCH_SIZE)
        return rc_refuse(err, RC_BAD_CONFIG, "est.batch_size must be <= %ld (the first batch is held in memory "
                           "until solved), got %ld", MAX_BATCH_SIZE, c->batch_size);
    if (slope_window > MAX_SLOPE_WINDOW)
        return rc_refuse(err, RC_BAD_CONFIG, "est.slope_window must be <= %ld, got %ld", MAX_SLOPE_WINDOW,
                      slope_window);
    return RC_OK;
}

rc_status rc_ident_validate(const rc_ident_config *cfg, int method, int physical,
                            int sigma2_method, long slope_window, rc_error *err)
{
    return ident_validate(cfg, method, physical, sigma2_method, slope_window, NULL, err);
}

/* build_estimator's checks in OnlineEstimator.__init__'s order: the identifier (dt, and
 * speed_std = sensor.speed_std), the filter, the station detector */
static rc_status estimator_validate(const rc_ident_config *ident, const rc_filter_config *filt,
                                    const rc_station_config *station, int method, int physical,
                                    int sigma2_method, long slope_window, double dt,
                                    int has_speed_profile, const char *native_fmu, rc_error *err)
{
    rc_status st;
    rc_ident_config id = *ident;
    id.dt = dt;
    id.speed_std = filt->speed_std;
    if ((st = ident_validate(&id, method, physical, sigma2_method, slope_window, native_fmu, err)))
        return st;
    if (sigma2_method == 1 && !(filt->speed_std * filt->speed_std > 0.0)) {
        char q0[40], R[40];            /* ProcessNoiseBank's check (LikelihoodNoise.from_config) */
        rc_repr(id.sigma2_initial, q0, sizeof q0);
        rc_repr(filt->speed_std * filt->speed_std, R, sizeof R);
        return rc_refuse(err, RC_BAD_CONFIG, "est.sigma2_method 1 (the likelihood bank) needs est.sigma2_initial > 0 "
                      "and a speed measurement variance > 0 (sensor.speed_std), got "
                      "est.sigma2_initial = %s, sensor.speed_std^2 = %s", q0, R);
    }
    if ((st = rc_filter_validate(filt, has_speed_profile, err)))
        return st;
    return rc_station_validate(station, err);
}

rc_status rc_chain_validate(const rc_chain_config *cfg, long slope_window, int has_speed_profile,
                            rc_error *err)
{
    rc_status st;
    clear(err);
    /* ChainConfig.validate: the vehicle alone (rc_plant_validate with a good step and psd:
     * CarPlant checks them later) */
    if ((st = rc_plant_validate(&cfg->vehicle, 1.0, 0.0, err)))
        return st;
    if ((st = rc_track_sensors_validate(cfg->track_spacing, cfg->track_base,
                                        cfg->track_resolution, cfg->track_jitter, err)))
        return st;
    if (!(cfg->seed >= 0 && cfg->seed <= SEED_MAX))
        return rc_refuse(err, RC_BAD_CONFIG, "seed must be in 0..2147483647 (a 32-bit fmi2Integer), got %ld",
                      cfg->seed);
    if (!(cfg->sample_period > 0 && isfinite(cfg->sample_period)))
        return rc_refuse_value(err, "", "sensor.sample_period", "must be > 0", cfg->sample_period);
    if (!(cfg->initial_speed >= 0 && isfinite(cfg->initial_speed)))
        return rc_refuse_value(err, "", "car.initial_speed", "must be >= 0", cfg->initial_speed);
    if (!(cfg->initial_position >= 0 && isfinite(cfg->initial_position)))
        return rc_refuse_value(err, "", "car.initial_position", "must be >= 0", cfg->initial_position);
    if (cfg->initial_speed > MAX_INITIAL_SPEED)     /* chain.MAX_MEASURED_SPEED */
        return rc_refuse_value(err, "", "car.initial_speed",
                            "must be <= 200 m/s (no rail car is that fast)", cfg->initial_speed);
    if (cfg->sample_period + 1e-12 < cfg->solver_step) {
        char a[40], b[40];
        rc_repr(cfg->solver_step, a, sizeof a);
        rc_repr(cfg->sample_period, b, sizeof b);
        return rc_refuse(err, RC_BAD_CONFIG, "solver.step (%s) must not exceed sensor.sample_period (%s)", a, b);
    }
    /* RailCarChain.__init__ */
    if (!isfinite(cfg->start_time))
        return rc_refuse_value(err, "", "start time", "must be finite", cfg->start_time);
    if ((st = rc_plant_validate(&cfg->vehicle, cfg->solver_step, cfg->process_noise_psd, err)))
        return st;
    rc_filter_config filt = cfg->filter;
    filt.length = cfg->vehicle.length;
    return estimator_validate(&cfg->identifier, &filt, &cfg->station, cfg->method, cfg->physical,
                              cfg->sigma2_method, slope_window, cfg->sample_period,
                              has_speed_profile, "RailCar", err);
}

rc_status rc_estchain_validate(const rc_estchain_config *cfg, long slope_window,
                               int has_speed_profile, rc_error *err)
{
    rc_status st;
    clear(err);
    /* EstimatorChain.__init__: the track sensors, then build_estimator(..., dt=1.0) */
    if ((st = rc_track_sensors_validate(0.0, cfg->track_base, cfg->track_resolution,
                                        cfg->track_jitter, err)))
        return st;
    return estimator_validate(&cfg->identifier, &cfg->filter, &cfg->station, cfg->method,
                              cfg->physical, cfg->sigma2_method, slope_window, 1.0,
                              has_speed_profile, "RailCarEstimator", err);
}
