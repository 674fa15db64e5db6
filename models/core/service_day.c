/* service_day.c -- see service_day.h: studies/service_day.py's run_day loop in C, each expression
 * in the Python's operand order (the Python line it twins is quoted where the order matters). */
#include "rc_fp_contract.h"
#include "service_day.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define STOPPED 1e-6             /* [m/s] ServiceDriver.STOPPED: below this the car stands */
/* the plant's outputs used here (models.compiled.OUTPUT_NAMES' order) */
#define OUT_SPEED 0
#define OUT_POSITION 1
#define OUT_TRACTION 3
#define OUT_BRAKE 4
#define OUT_TOTAL_MASS 7
#define OUT_SENSOR_SPEED 8
#define OUT_SENSOR_POSITION 9
#define OUT_EST 12               /* the estimator's outputs start here */
/* the estimator's outputs used here (models/core/estimator.h's order) */
#define EST_MASS 0
#define EST_MASS_STD 1
#define EST_SAMPLES 9
#define EST_FILTER_SPEED 11
#define EST_STATUS 15
#define EST_REJECTED 16

enum { PHASE_DWELL, PHASE_TRACTION, PHASE_CRUISE, PHASE_COAST, PHASE_BRAKE };

static const char *const DAY_NAMES[RC_SD_DAY_VALUES] = {
    "steps", "step_s", "run_time_s[0]", "run_time_s[1]", "dwell_s[0]", "dwell_s[1]",
    "target_kmh[0]", "target_kmh[1]", "traction_max_s", "short_cruise_share", "short_cruise_s[0]",
    "short_cruise_s[1]", "long_cruise_share", "long_cruise_min[0]", "long_cruise_min[1]",
    "decel_mps2[0]", "decel_mps2[1]", "payload_change_t", "payload_low", "payload_high",
    "traction_force_max", "brake_force_max", "cruise_gain", "batch_size", "car_mass_t",
    "first_dwell_end", "first_payload"};

/* ------------------------------------------------------------------------------ set-up */

static rc_status score_init(rc_sd_score *s, int n_outputs, int est_offset, long stops_cap,
                            long hours_cap)
{
    memset(s, 0, sizeof *s);
    s->n_outputs = n_outputs;
    s->est_offset = est_offset;
    s->stops_cap = stops_cap;
    s->hours_cap = hours_cap;
    s->stop_errors = malloc(sizeof *s->stop_errors * (size_t)stops_cap);
    s->hour_se = calloc((size_t)hours_cap, sizeof *s->hour_se);
    s->hour_n = calloc((size_t)hours_cap, sizeof *s->hour_n);
    return s->stop_errors && s->hour_se && s->hour_n ? RC_OK : RC_BAD_CONFIG;
}

static void score_free(rc_sd_score *s)
{
    free(s->stop_errors);
    free(s->hour_se);
    free(s->hour_n);
    s->stop_errors = s->hour_se = NULL;
    s->hour_n = NULL;
}

size_t rc_service_day_size(void) { return sizeof(rc_service_day); }

static rc_status check_day(const double *v, long n, rc_error *err)
{
    if (n != RC_SD_DAY_VALUES)
        return rc_refuse(err, RC_BAD_CONFIG, "day: expected %d values, got %ld", RC_SD_DAY_VALUES, n);
    for (int i = 0; i < RC_SD_DAY_VALUES; i++) {
        if (!isfinite(v[i]))
            return rc_refuse_value(err, "day.", DAY_NAMES[i], "must be finite", v[i]);
        if (v[i] < 0.0 && i != RC_SD_PAYLOAD_LO && i != RC_SD_PAYLOAD_HI
                && i != RC_SD_FIRST_PAYLOAD)
            return rc_refuse_value(err, "day.", DAY_NAMES[i], "must be >= 0", v[i]);
    }
    if (!(v[RC_SD_STEP_S] > 0.0 && v[RC_SD_STEP_S] <= RC_SD_MAX_STEP_S)) {
        char r[40];
        rc_repr(v[RC_SD_STEP_S], r, sizeof r);
        return rc_refuse(err, RC_BAD_CONFIG, "day.step_s must be in (0, %g] s, got %s",
                         RC_SD_MAX_STEP_S, r);
    }
    if (v[RC_SD_STEPS] != floor(v[RC_SD_STEPS]) || v[RC_SD_STEPS] > (double)RC_SD_MAX_STEPS)
        return rc_refuse(err, RC_BAD_CONFIG, "day.steps must be a whole number in 0..1e9");
    if (!(v[RC_SD_DECEL_LO] > 0.0 && v[RC_SD_DECEL_HI] > 0.0))
        return rc_refuse(err, RC_BAD_CONFIG, "day.decel_mps2 must be > 0");
    return RC_OK;
}

static rc_status check_rows(const double *wind, long n_wind, const double *faults, long n_faults,
                            rc_error *err)
{
    if (n_wind < 1)
        return rc_refuse(err, RC_BAD_CONFIG, "wind: the schedule needs at least one row");
    for (long i = 0; i < 2 * n_wind; i++)
        if (!isfinite(wind[i]))
            return rc_refuse(err, RC_BAD_CONFIG, "wind row %ld: must be finite", i / 2);
    for (long i = 0; i < n_faults; i++) {
        const double *f = faults + 3 * i;
        if (!(f[0] >= 0.0 && f[0] == floor(f[0]) && f[0] <= (double)RC_SD_MAX_STEPS))
            return rc_refuse(err, RC_BAD_CONFIG, "faults row %ld: step must be a whole number >= 0", i);
        if (i > 0 && !(f[0] > f[-3]))
            return rc_refuse(err, RC_BAD_CONFIG, "faults row %ld: steps must increase", i);
        if (!(f[1] >= 0.0 && f[1] < RC_SD_FAULT_KINDS && f[1] == floor(f[1])))
            return rc_refuse(err, RC_BAD_CONFIG, "faults row %ld: kind must be 0..3 (speed, position, "
                          "zero, hold)", i);
        if (!isfinite(f[2]))
            return rc_refuse(err, RC_BAD_CONFIG, "faults row %ld: value must be finite", i);
        int dropout = f[1] >= RC_SD_FAULT_ZERO;
        if (dropout && !(f[2] >= 1.0 && f[2] == floor(f[2])))
            return rc_refuse(err, RC_BAD_CONFIG, "faults row %ld: a dropout's value must be its "
                          "samples, a whole number >= 1", i);
    }
    return RC_OK;
}

rc_status rc_service_day_init(rc_service_day *d, const double *day, long n_day,
                              const double *plant, long n_plant, const double *est, long n_est,
                              const double *grade_distances, const double *grades, long n_grade,
                              const double *wind, long n_wind, const double *faults, long n_faults,
                              rc_error *err)
{
    memset(d, 0, sizeof *d);
    if (err)
        err->msg[0] = '\0';
    rc_status st = check_day(day, n_day, err);
    if (st != RC_OK)
        return st;
    memcpy(d->day, day, sizeof d->day);
    d->n_steps = (long)day[RC_SD_STEPS];
    if ((st = check_rows(wind, n_wind, faults, n_faults, err)) != RC_OK)
        return st;
    if (n_grade < 1)
        return rc_refuse(err, RC_BAD_CONFIG, "grade: the profile needs at least one point");
    rc_chain_config pc;
    memset(&pc, 0, sizeof pc);
    long expected = rc_chain_config_from_values(&pc, plant, n_plant);
    if (expected)
        return rc_refuse(err, RC_BAD_CONFIG, "plant config: the C core takes %ld values, got %ld",
                      expected, n_plant);
    rc_estchain_config ec;
    memset(&ec, 0, sizeof ec);
    expected = rc_estchain_config_from_values(&ec, est, n_est);
    if (expected)
        return rc_refuse(err, RC_BAD_CONFIG, "estimator config: the C core takes %ld values, got %ld",
                      expected, n_est);
    pc.grade_distances = ec.grade_distances = grade_distances;
    pc.grades = ec.grades = grades;
    pc.grade_n = ec.grade_n = n_grade;
    pc.speed_n = ec.speed_n = 0;
    /* hour = int(t / 3600.0) of the last step; an arrival needs a moving step before it */
    double h = day[RC_SD_STEP_S];
    long hours = d->n_steps ? (long)((double)(d->n_steps - 1) * h / 3600.0) + 1 : 1;
    long stops = d->n_steps / 2 + 1;
    d->wind = malloc(sizeof *d->wind * (size_t)(2 * n_wind));
    d->faults = malloc(sizeof *d->faults * (size_t)(3 * (n_faults > 0 ? n_faults : 1)));
    if (!d->wind || !d->faults
            || score_init(&d->score[0], RC_CHAIN_OUTPUTS, OUT_EST, stops, hours) != RC_OK
            || score_init(&d->score[1], RC_EST_OUTPUTS, 0, stops, hours) != RC_OK) {
        rc_service_day_free(d);
        return rc_refuse(err, RC_BAD_CONFIG, "service day: out of memory");
    }
    memcpy(d->wind, wind, sizeof *d->wind * (size_t)(2 * n_wind));
    memcpy(d->faults, faults, sizeof *d->faults * (size_t)(3 * n_faults));
    /* a dropout past the day's end runs as one that ends with it (Python's counter outlives the
     * day): clamped to n_steps + 1 samples so that (long) of it cannot overflow */
    for (long i = 0; i < n_faults; i++) {
        double *f = d->faults + 3 * i;
        if (f[1] >= RC_SD_FAULT_ZERO && f[2] > (double)d->n_steps + 1.0)
            f[2] = (double)d->n_steps + 1.0;
    }
    d->n_wind = n_wind;
    d->n_faults = n_faults;
    if ((st = rc_chain_init(&d->plant, &pc, err)) != RC_OK) {
        rc_service_day_free(d);
        return st;
    }
    d->has_plant = 1;
    if ((st = rc_estchain_init(&d->est, &ec, err)) != RC_OK) {
        rc_service_day_free(d);
        return st;
    }
    d->has_est = 1;
    rc_chain_outputs(&d->plant, d->out);
    d->wind_now = d->wind[1];
    d->held_speed = d->out[OUT_SENSOR_SPEED];
    d->held_position = d->out[OUT_SENSOR_POSITION];
    d->driver.phase = PHASE_DWELL;
    d->driver.phase_end = day[RC_SD_FIRST_DWELL_END];
    d->driver.decel = 0.8;
    d->payload = day[RC_SD_FIRST_PAYLOAD];
    d->mass_min = d->mass_max = day[RC_SD_CAR_MASS] + d->payload;   /* day.car_mass_t + payload */
    return RC_OK;
}

void rc_service_day_free(rc_service_day *d)
{
    if (d->has_plant)
        rc_chain_free(&d->plant);
    if (d->has_est)
        rc_estchain_free(&d->est);
    d->has_plant = d->has_est = 0;
    free(d->wind);
    free(d->faults);
    d->wind = d->faults = NULL;
    score_free(&d->score[0]);
    score_free(&d->score[1]);
}

/* ------------------------------------------------------------------------------ the step */

typedef struct {                 /* the driver's draws of one run call */
    const double *next, *end;
} draws_t;

/* numpy's Generator.uniform(lo, hi): lo + (hi - lo) * next_double */
static double uniform(draws_t *r, double lo, double hi)
{
    double u = *r->next++;
    return lo + (hi - lo) * u;
}

/* ServiceDriver._depart */
static void depart(rc_sd_driver *dr, const double *day, draws_t *r, double t)
{
    dr->run_start = t;
    dr->target = uniform(r, day[RC_SD_TARGET_LO], day[RC_SD_TARGET_HI]) * (1.0 / 3.6);  /* kmh_to_mps */
    dr->decel = uniform(r, day[RC_SD_DECEL_LO], day[RC_SD_DECEL_HI]);
    double run = uniform(r, day[RC_SD_RUN_LO], day[RC_SD_RUN_HI]);
    double u = uniform(r, 0.0, 1.0);
    if (u < day[RC_SD_LONG_SHARE]) {
        dr->cruise = 60.0 * uniform(r, day[RC_SD_LONG_LO], day[RC_SD_LONG_HI]);
        dr->long_cruises++;
    } else if (u < day[RC_SD_LONG_SHARE] + day[RC_SD_SHORT_SHARE]) {
        dr->cruise = uniform(r, day[RC_SD_SHORT_LO], day[RC_SD_SHORT_HI]);
    } else {
        dr->cruise = 0.0;
    }
    dr->deadline = t + run + (dr->cruise > 60.0 ? dr->cruise : 0.0);
    dr->phase = PHASE_TRACTION;
}

/* ServiceDriver.demands: (traction, brake) [N] for [t, t + h] from the true speed and distance */
static void demands(rc_sd_driver *dr, const double *day, draws_t *r, double t, double v, double x,
                    double mass_t, double *traction, double *brake)
{
    const double f_max = day[RC_SD_TRACTION_MAX], b_max = day[RC_SD_BRAKE_MAX];
    dr->board = 0;
    *traction = 0.0;
    *brake = 0.0;
    if (dr->phase == PHASE_DWELL) {
        if (t < dr->phase_end) {
            *brake = 0.3 * b_max;
            return;
        }
        depart(dr, day, r, t);
    }
    if ((dr->phase == PHASE_TRACTION || dr->phase == PHASE_CRUISE || dr->phase == PHASE_COAST)
            && t + v / dr->decel >= dr->deadline) {
        dr->phase = PHASE_BRAKE;
        dr->stop_at = x + v * v / (2.0 * dr->decel);
    }
    if (dr->phase == PHASE_TRACTION) {
        if (v >= dr->target || t - dr->run_start >= day[RC_SD_TRACTION_MAX_S]) {
            dr->phase = dr->cruise > 0.0 ? PHASE_CRUISE : PHASE_COAST;
            dr->phase_end = t + dr->cruise;
        } else {
            *traction = f_max;
            return;
        }
    }
    if (dr->phase == PHASE_CRUISE) {
        if (t < dr->phase_end) {
            dr->cruise_s += day[RC_SD_STEP_S];
            double demand = 1000.0 * mass_t * day[RC_SD_CRUISE_GAIN] * (dr->target - v);
            if (demand >= 0.0)
                *traction = rc_min(demand, f_max);
            else
                *brake = rc_min(-demand, b_max);
            return;
        }
        dr->phase = PHASE_COAST;
    }
    if (dr->phase == PHASE_COAST)
        return;
    double left = dr->stop_at - x;           /* brake_to_stop on the braking curve to stop_at */
    if (v <= STOPPED) {
        dr->phase = PHASE_DWELL;
        dr->phase_end = t + uniform(r, day[RC_SD_DWELL_LO], day[RC_SD_DWELL_HI]);
        dr->stops++;
        dr->board = 1;
        *brake = 0.3 * b_max;
        return;
    }
    if (left <= 0.05) {
        *brake = 0.3 * b_max;
        return;
    }
    *brake = rc_min(b_max, 1000.0 * mass_t * v * v / (2.0 * left));
}

/* FaultySensors.sample: the faulty (speed [m/s], position [m]) of step k */
static void faulty_sample(rc_service_day *d, long k, double *speed, double *position)
{
    while (d->fault_k < d->n_faults && d->faults[3 * d->fault_k] < (double)k)
        d->fault_k++;
    if (d->fault_k < d->n_faults && d->faults[3 * d->fault_k] == (double)k) {
        const double *f = d->faults + 3 * d->fault_k;
        int kind = (int)f[1];
        d->fault_counts[kind]++;
        if (kind == RC_SD_FAULT_SPEED)
            *speed += f[2];
        else if (kind == RC_SD_FAULT_POSITION)
            *position += f[2];
        else {
            d->dropout_kind = kind;
            d->dropout_left = (long)f[2];
        }
    }
    if (d->dropout_left) {
        d->dropout_left--;
        *speed = d->dropout_kind == RC_SD_FAULT_ZERO ? 0.0 : d->last_speed;
    } else {
        d->last_speed = *speed;
    }
}

/* _Score.check_finite and _Score.add: the outputs after the step ending at t [s] */
static rc_status score_add(rc_sd_score *s, const double *out, double t, long hour, double v,
                           double v_prev, double mass, double batch, rc_error *err)
{
    for (int i = 0; i < s->n_outputs; i++)
        if (!isfinite(out[i])) {
            s->nonfinite++;
            if (s->nonfinite_by_output[i]++ == 0)
                s->first_seen[i] = s->names_seen++;   /* the names' dict order in Python */
            if (!s->has_first) {
                s->has_first = 1;
                s->first_t = t;
                s->first_output = i;
            }
        }
    const double *est = out + s->est_offset;
    double samples = est[EST_SAMPLES];
    double e = est[EST_FILTER_SPEED] - v;
    if (v > 0.0) {
        /* identified = samples - samples_at_departure (est.samples is always there in C) */
        if (samples - s->samples_at_departure >= batch) {
            double mass_error = fabs(est[EST_MASS] - mass);
            s->sigma_n++;
            if (mass_error <= 3.0 * est[EST_MASS_STD])
                s->sigma_in++;
        }
        if (hour >= s->hours_cap)
            return rc_refuse(err, RC_BAD_CONFIG, "hour %ld past the day's %ld", hour, s->hours_cap);
        while (s->hour_len <= hour)
            s->hour_len++;                   /* the sums start at 0 (calloc) */
        s->hour_se[hour] += e * e;
        s->hour_n[hour]++;
    } else {
        s->samples_at_departure = samples;   /* standing: the run's count starts here */
    }
    if (v <= 0.0 && 0.0 < v_prev) {         /* arrival: stop_indices' definition */
        if (s->n_stops >= s->stops_cap)
            return rc_refuse(err, RC_BAD_CONFIG, "stop errors: more than %ld", s->stops_cap);
        s->stop_errors[s->n_stops++] = (est[EST_MASS] - mass) / mass;
    }
    s->se_all += e * e;
    s->n_all++;
    double rej = est[EST_REJECTED];
    s->rejected_last = rej;
    s->rejected_max = s->has_rejected ? rc_max(s->rejected_max, rej) : rej;
    s->has_rejected = 1;
    double st = est[EST_STATUS];
    int i = 0;
    while (i < s->n_status && !(s->status_value[i] == st))
        i++;
    if (i == s->n_status) {
        if (s->n_status >= RC_SD_STATUS_MAX)
            return rc_refuse(err, RC_BAD_CONFIG, "est.status: more than %d distinct values",
                          RC_SD_STATUS_MAX);
        s->status_value[s->n_status++] = st;
    }
    s->status_count[i]++;
    return RC_OK;
}

/* A refusal mid-step: the driver, payload, fault cursor and chains may have moved but d->k has
 * not, so the day is marked failed (rc_service_day_run refuses to go on) and keeps the reason. */
static rc_status step_refused(rc_service_day *d, rc_error *err, rc_status st, long k, const char *who)
{
    char why[RC_MSG_SIZE];
    memcpy(why, err ? err->msg : "", err ? sizeof why : 1);
    d->failed = 1;
    snprintf(d->failed_msg, sizeof d->failed_msg, "step %ld (%s): %.200s", k, who, why);
    if (err)
        memcpy(err->msg, d->failed_msg, sizeof err->msg);
    return st;
}

rc_status rc_service_day_run(rc_service_day *d, long steps, const double *draws, long n_draws,
                             long *used, rc_error *err)
{
    *used = 0;
    if (err)
        err->msg[0] = '\0';
    if (d->failed)
        return rc_refuse(err, RC_BAD_CONFIG, "the day stopped at step %ld: %.200s", d->k,
                         d->failed_msg);
    if (steps < 0 || steps > d->n_steps - d->k)
        return rc_refuse(err, RC_BAD_CONFIG, "steps: %ld asked at step %ld of a day of %ld", steps,
                      d->k, d->n_steps);
    const double *day = d->day;
    const double h = day[RC_SD_STEP_S];
    draws_t r = {draws, draws + (n_draws > 0 ? n_draws : 0)};
    double new_out[RC_CHAIN_OUTPUTS];
    for (long j = 0; j < steps; j++) {
        long k = d->k;
        if (r.end - r.next < RC_SD_DRAWS_PER_STEP) {
            *used = (long)(r.next - draws);
            return rc_refuse(err, RC_BAD_CONFIG, "driver draws: %ld left before step %ld, a step may "
                          "take %d (give more draws)", (long)(r.end - r.next), k,
                          RC_SD_DRAWS_PER_STEP);
        }
        double t = (double)k * h;
        while (d->wind_k + 1 < d->n_wind && d->wind[2 * (d->wind_k + 1)] <= t) {
            d->wind_k++;
            d->wind_now = d->wind[2 * d->wind_k + 1];
        }
        double v_prev = d->out[OUT_SPEED], x = d->out[OUT_POSITION];
        double traction, brake;
        demands(&d->driver, day, &r, t, v_prev, x, d->out[OUT_TOTAL_MASS], &traction, &brake);
        if (d->driver.board)
            d->payload = rc_min(day[RC_SD_PAYLOAD_HI], rc_max(day[RC_SD_PAYLOAD_LO],
                d->payload + uniform(&r, -day[RC_SD_PAYLOAD_CHANGE], day[RC_SD_PAYLOAD_CHANGE])));
        double speed = d->out[OUT_SENSOR_SPEED], position = d->out[OUT_SENSOR_POSITION];
        faulty_sample(d, k, &speed, &position);
        rc_status st = rc_chain_step(&d->plant, t, h, traction, brake, d->wind_now, d->payload, err);
        if (st != RC_OK) {
            *used = (long)(r.next - draws);
            return step_refused(d, err, st, k, "RailCar chain");
        }
        rc_chain_outputs(&d->plant, new_out);
        double f_app = new_out[OUT_TRACTION], b_app = new_out[OUT_BRAKE];
        st = rc_estchain_step(&d->est, t, h, f_app, b_app, speed, position, 0.0, 0.0, err);
        if (st == RC_OK) {
            d->held_speed = speed;
            d->held_position = position;
        } else if (st == RC_REJECTED) {      /* StepRejected (nothing changed): redo held */
            d->rejected++;
            st = rc_estchain_step(&d->est, t, h, f_app, b_app, d->held_speed, d->held_position,
                                  0.0, 0.0, err);
            if (st != RC_OK) {
                *used = (long)(r.next - draws);
                return step_refused(d, err, st, k, "faulty estimator, the held sample");
            }
        } else {                             /* RC_MATH, RC_BAD_CONFIG: Python's raise ends the day */
            *used = (long)(r.next - draws);
            return step_refused(d, err, st, k, "faulty estimator");
        }
        rc_estchain_outputs(&d->est, d->est_out);
        double t1 = t + h;
        double vt = new_out[OUT_SPEED], mt = new_out[OUT_TOTAL_MASS];
        long hour = (long)(t / 3600.0);
        const double *outs[2] = {new_out, d->est_out};
        for (int e = 0; e < 2; e++) {
            rc_sd_score *s = &d->score[e];
            if ((st = score_add(s, outs[e], t1, hour, vt, v_prev, mt, day[RC_SD_BATCH], err)) != RC_OK) {
                *used = (long)(r.next - draws);
                return step_refused(d, err, st, k, e ? "faulty score" : "clean score");
            }
        }
        if (vt > 0.0) {
            d->moving_steps++;
            d->distance += 0.5 * (vt + v_prev) * h;
        }
        d->mass_min = rc_min(d->mass_min, mt);
        d->mass_max = rc_max(d->mass_max, mt);
        memcpy(d->out, new_out, sizeof new_out);
        d->k++;
    }
    *used = (long)(r.next - draws);
    return RC_OK;
}

/* ------------------------------------------------------------------------------ export */

static long score_export(const rc_sd_score *s, double *out, int write)
{
    long n = RC_SD_S_FIXED + 2 * s->n_outputs + 2 * s->hour_len + 2 * s->n_status + s->n_stops;
    if (!write)
        return n;
    out[RC_SD_S_NONFINITE] = (double)s->nonfinite;
    out[RC_SD_S_HAS_FIRST] = s->has_first;
    out[RC_SD_S_FIRST_T] = s->first_t;
    out[RC_SD_S_FIRST_OUTPUT] = s->first_output;
    out[RC_SD_S_SIGMA_IN] = (double)s->sigma_in;
    out[RC_SD_S_SIGMA_N] = (double)s->sigma_n;
    out[RC_SD_S_SE_ALL] = s->se_all;
    out[RC_SD_S_N_ALL] = (double)s->n_all;
    out[RC_SD_S_HAS_REJECTED] = s->has_rejected;
    out[RC_SD_S_REJECTED_LAST] = s->rejected_last;
    out[RC_SD_S_REJECTED_MAX] = s->rejected_max;
    out[RC_SD_S_HOUR_LEN] = (double)s->hour_len;
    out[RC_SD_S_N_STOPS] = (double)s->n_stops;
    out[RC_SD_S_N_STATUS] = s->n_status;
    out[RC_SD_S_N_OUTPUTS] = s->n_outputs;
    double *p = out + RC_SD_S_FIXED;
    for (int i = 0; i < s->n_outputs; i++)
        *p++ = (double)s->nonfinite_by_output[i];
    for (int i = 0; i < s->n_outputs; i++)
        *p++ = (double)s->first_seen[i];
    for (long i = 0; i < s->hour_len; i++)
        *p++ = s->hour_se[i];
    for (long i = 0; i < s->hour_len; i++)
        *p++ = (double)s->hour_n[i];
    for (int i = 0; i < s->n_status; i++) {
        *p++ = s->status_value[i];
        *p++ = (double)s->status_count[i];
    }
    for (long i = 0; i < s->n_stops; i++)
        *p++ = s->stop_errors[i];
    return n;
}

long rc_service_day_export(const rc_service_day *d, double *out, long cap)
{
    long n = RC_SD_X_DAY + score_export(&d->score[0], NULL, 0) + score_export(&d->score[1], NULL, 0);
    if (!out || cap < n)
        return n;
    out[RC_SD_X_STEPS_DONE] = (double)d->k;
    out[RC_SD_X_STOPS] = (double)d->driver.stops;
    out[RC_SD_X_LONG_CRUISES] = (double)d->driver.long_cruises;
    out[RC_SD_X_CRUISE_S] = d->driver.cruise_s;
    out[RC_SD_X_DISTANCE] = d->distance;
    out[RC_SD_X_MOVING_STEPS] = (double)d->moving_steps;
    out[RC_SD_X_MASS_MIN] = d->mass_min;
    out[RC_SD_X_MASS_MAX] = d->mass_max;
    for (int i = 0; i < RC_SD_FAULT_KINDS; i++)
        out[RC_SD_X_FAULTS + i] = (double)d->fault_counts[i];
    out[RC_SD_X_REJECTED] = (double)d->rejected;
    long at = RC_SD_X_DAY;
    at += score_export(&d->score[0], out + at, 1);
    score_export(&d->score[1], out + at, 1);
    return n;
}
