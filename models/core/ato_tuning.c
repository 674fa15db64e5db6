/* ato_tuning.c -- see ato_tuning.h: models/ato/interface.py's inputs, AtoTuning's defaults and
 * AtoTuning.__post_init__'s checks, message for message. */
#include "rc_fp_contract.h"
#include "ato_tuning.h"

#include <stdarg.h>
#include <stdio.h>
#include <string.h>

static const char *const input_names[ATO_N_ALL_INPUTS] = {
    "filter.speed", "filter.position", "filter.speed_std", "est.mass", "est.A0", "est.A1",
    "est.A2", "est.status", "est.samples", "filter.position_std",
    "est.mass_std", "est.A0_std", "est.A1_std", "est.A2_std", "est.cov_A0_A1", "est.cov_A0_A2",
    "est.cov_A1_A2"};

/* STATED_INPUTS' priors: the estimator's (fmu_src/variables.py est.*_std_initial) */
static const double stated_priors[ATO_N_ALL_INPUTS - ATO_N_INPUTS] = {
    10.0, 2.0, 0.1, 0.02, 0.0, 0.0, 0.0};

const char *ato_input_name(int index)
{
    return index >= 0 && index < ATO_N_ALL_INPUTS ? input_names[index] : NULL;
}

double ato_stated_prior(int index)
{
    return index >= ATO_N_INPUTS && index < ATO_N_ALL_INPUTS ? stated_priors[index - ATO_N_INPUTS]
                                                              : NAN;
}

void ato_tuning_defaults(ato_tuning *t)
{
    memset(t, 0, sizeof *t);      /* padding included: an FMU state holds the struct's bytes */
    t->replan = 1;
    t->use_estimates = 1;
    t->replan_period = 2.0;
    t->grid_step = 10.0;
    t->time_tol = 0.05;
    t->min_samples = 100;
    t->mass_band = 1.6;
    t->limit_margin = 0.5;
    t->k_sigma = 3.0;
    t->gap_sigma = 2.5;
    t->supervisor_gap = 0.1;
    t->mass_reserve = 0.2;
    t->brake_share = 0.85;
    t->approach_gain = 1.0;
    t->brake_integral_gain = 0.5;
    t->brake_integral_max = 0.3;
    t->a_ep = 1.0;
    t->ep_stages = 6;
    t->relay_hysteresis = 0.03;
    t->relay_stage_speed = 0.1;
    t->relay_dwell = 0.3;
    t->stand_speed = 0.05;
    t->stand_time = 0.5;
    t->creep_speed = 0.3;
    t->creep_accel = 0.2;
    t->stop_window = 0.15;
    t->aim_sigma = 1.0;
    t->aim_max = 0.5;
    t->settle_std = 0.13;
    t->settle_sigma = 6.0;
    t->settle_aim_max = 1.5;
    t->settle_time = 5.0;
    t->settle_window = 0.05;
    t->creep_aim = 0.05;
    t->safe_brake = 1.0;
    t->hold_brake = 0.5;
    t->config_mass_std = 0.1;
    t->config_resistance_std = 1.0;
    t->est_gate = 3.0;
    t->time_reserve = 0.01;
}

#define FIELD(name, kind) {#name, kind, offsetof(ato_tuning, name)}
static const ato_tuning_field tuning_fields[ATO_N_TUNING_FIELDS] = {
    FIELD(replan, ATO_FIELD_BOOL), FIELD(use_estimates, ATO_FIELD_BOOL),
    FIELD(replan_period, ATO_FIELD_REAL), FIELD(grid_step, ATO_FIELD_REAL),
    FIELD(time_tol, ATO_FIELD_REAL), FIELD(min_samples, ATO_FIELD_INT),
    FIELD(mass_band, ATO_FIELD_REAL), FIELD(limit_margin, ATO_FIELD_REAL),
    FIELD(k_sigma, ATO_FIELD_REAL), FIELD(gap_sigma, ATO_FIELD_REAL),
    FIELD(supervisor_gap, ATO_FIELD_REAL), FIELD(mass_reserve, ATO_FIELD_REAL),
    FIELD(brake_share, ATO_FIELD_REAL), FIELD(approach_gain, ATO_FIELD_REAL),
    FIELD(brake_integral_gain, ATO_FIELD_REAL), FIELD(brake_integral_max, ATO_FIELD_REAL),
    FIELD(a_ep, ATO_FIELD_REAL), FIELD(ep_stages, ATO_FIELD_INT),
    FIELD(relay_hysteresis, ATO_FIELD_REAL), FIELD(relay_stage_speed, ATO_FIELD_REAL),
    FIELD(relay_dwell, ATO_FIELD_REAL), FIELD(stand_speed, ATO_FIELD_REAL),
    FIELD(stand_time, ATO_FIELD_REAL), FIELD(creep_speed, ATO_FIELD_REAL),
    FIELD(creep_accel, ATO_FIELD_REAL), FIELD(stop_window, ATO_FIELD_REAL),
    FIELD(aim_sigma, ATO_FIELD_REAL), FIELD(aim_max, ATO_FIELD_REAL),
    FIELD(settle_std, ATO_FIELD_REAL), FIELD(settle_sigma, ATO_FIELD_REAL),
    FIELD(settle_aim_max, ATO_FIELD_REAL), FIELD(settle_time, ATO_FIELD_REAL),
    FIELD(settle_window, ATO_FIELD_REAL), FIELD(creep_aim, ATO_FIELD_REAL),
    FIELD(safe_brake, ATO_FIELD_REAL), FIELD(hold_brake, ATO_FIELD_REAL),
    FIELD(config_mass_std, ATO_FIELD_REAL), FIELD(config_resistance_std, ATO_FIELD_REAL),
    FIELD(est_gate, ATO_FIELD_REAL), FIELD(time_reserve, ATO_FIELD_REAL)};
#undef FIELD

const ato_tuning_field *ato_tuning_field_at(int k)
{
    return k >= 0 && k < ATO_N_TUNING_FIELDS ? &tuning_fields[k] : NULL;
}

const ato_tuning_field *ato_tuning_field_named(const char *name)
{
    for (int k = 0; name && k < ATO_N_TUNING_FIELDS; k++)
        if (strcmp(tuning_fields[k].name, name) == 0)
            return &tuning_fields[k];
    return NULL;
}

/* interface.UPPER_BOUNDS: (field, largest value, why) */
static const struct {
    const char *name;
    double high;
    const char *why;
} upper_bounds[] = {
    {"grid_step", 100.0, "m: 1e300 refused every schedule as infeasible without naming the grid"},
    {"limit_margin", 5.0, "m/s below every limit: 1e300 refused every limit"},
    {"time_tol", 2.5, "the planner's tolerance cannot exceed the running-time target itself: "
                      "1e300 arrived 24 s late"},
    {"k_sigma", 10.0, "sigmas of filter.speed_std: 1e300 never left the station"},
    {"gap_sigma", 10.0, "sigmas of filter.speed_std: 1e300 never left the station"},
    {"supervisor_gap", 5.0, "m/s below the supervision curve: 1e300 never left the station"},
    {"mass_reserve", 1.0, "a share of the planned mass: 1e300 never left the station"},
    {"stand_time", 10.0, "s at rest before the car counts as standing: 1e300 never finished a "
                         "stop, 60 outlasted the estimator's station dwell"},
    {"aim_sigma", 10.0, "sigmas of filter.speed_std short of the mark"},
    {"config_mass_std", 1.0, "a share of car.mass"},
    {"config_resistance_std", 100.0, "N/kN: 100 times any car's resistance uncertainty"},
    {"est_gate", 100.0, "combined sigmas"},
};

/* the fields that must be > 0 (AtoTuning.__post_init__'s `positive`) */
static const char *const positive_fields[] = {
    "replan_period", "grid_step", "time_tol", "approach_gain", "a_ep", "relay_stage_speed",
    "stand_speed", "creep_speed", "brake_share", "creep_accel", "safe_brake", "hold_brake",
    "config_mass_std", "config_resistance_std"};

/* shares of a force: in (0, 1] */
static const char *const share_fields[] = {"brake_share", "safe_brake", "hold_brake"};

static int named_in(const char *name, const char *const *list, size_t n)
{
    for (size_t k = 0; k < n; k++)
        if (strcmp(list[k], name) == 0)
            return 1;
    return 0;
}

#define COUNT(a) (sizeof(a) / sizeof((a)[0]))

/* "<prefix><name> " then the printf-formatted rest after it (rc_vrefuse: the whole cut to
   RC_MSG_SIZE - 1 bytes) into err; RC_BAD_CONFIG */
static rc_status refuse(rc_error *err, const char *prefix, const char *name, const char *fmt, ...)
{
    if (err) {
        int n = snprintf(err->msg, sizeof err->msg, "%s%s ", prefix, name);
        if (n > 0 && (size_t)n < sizeof err->msg) {
            va_list ap;
            va_start(ap, fmt);
            rc_vrefuse(err->msg + n, sizeof err->msg - (size_t)n, RC_BAD_CONFIG, fmt, ap);
            va_end(ap);
        }
    }
    return RC_BAD_CONFIG;
}

/* The checks of one float field (x: its value), in __post_init__'s order */
static rc_status check_real(const char *p, const char *name, double x, rc_error *err)
{
    char r[40];
    rc_repr(x, r, sizeof r);
    if (!isfinite(x) || x < 0.0)
        return refuse(err, p, name, "must be finite and >= 0, got %s", r);
    if (strcmp(name, "mass_band") == 0 && !(1.0 <= x && x <= ATO_MAX_MASS_BAND))
        return refuse(err, p, name, "must be in [1, %g], got %s (the estimator reports est.mass "
                      "within a factor 5 of its start: a wider band admits nothing more)",
                      ATO_MAX_MASS_BAND, r);
    if (named_in(name, positive_fields, COUNT(positive_fields)) && x == 0.0)
        return refuse(err, p, name, "must be > 0, got %s", r);
    if (strcmp(name, "est_gate") == 0 && x < 1.0)
        return refuse(err, p, name, "must be >= 1, got %s (full weight ends est_gate - 1 sigmas "
                      "from the configured car)", r);
    for (size_t k = 0; k < COUNT(upper_bounds); k++)
        if (strcmp(upper_bounds[k].name, name) == 0 && x > upper_bounds[k].high)
            return refuse(err, p, name, "must be <= %g, got %s (%s)", upper_bounds[k].high, r,
                          upper_bounds[k].why);
    if (strcmp(name, "time_reserve") == 0 && x > 0.2)
        return refuse(err, p, name, "must be in [0, 0.2], got %s (a share of the remaining "
                      "running time planned early)", r);
    if (named_in(name, share_fields, COUNT(share_fields)) && x > 1.0)
        return refuse(err, p, name, "must be in (0, 1], got %s", r);
    return RC_OK;
}

rc_status ato_tuning_validate(const ato_tuning *t, const char *prefix, rc_error *err)
{
    const char *p = prefix ? prefix : "tuning.";
    if (err)
        err->msg[0] = '\0';
    for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = &tuning_fields[k];
        const char *at = (const char *)t + f->offset;
        if (f->kind == ATO_FIELD_BOOL) {
            int v = *(const int *)at;
            if (v != 0 && v != 1)
                return refuse(err, p, f->name, "must be True or False, got %d", v);
        } else if (f->kind == ATO_FIELD_INT) {
            int v = *(const int *)at;
            if (v < 1)
                return refuse(err, p, f->name, "must be an integer >= 1, got %d", v);
            if (strcmp(f->name, "ep_stages") == 0 && v > ATO_MAX_EP_STAGES)
                return refuse(err, p, f->name, "must be in [1, %d], got %d: the relay switches "
                              "one stage per relay_dwell, and a stage of car.mech_force_max / %d "
                              "corrects next to nothing", ATO_MAX_EP_STAGES, v, v);
        } else {
            rc_status st = check_real(p, f->name, *(const double *)at, err);
            if (st != RC_OK)
                return st;
        }
    }
    return RC_OK;
}
