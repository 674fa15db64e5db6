/* scenario_driver.c -- see scenario_driver.h: harness/run/phases.py's PhaseDriver and TimeTable
 * and harness/run/driver.py's drive() in C, each expression in the Python's operand order. */
#include "rc_fp_contract.h"
#include "scenario_driver.h"
#include "script_common.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define STOPPED 1e-6               /* [m/s] PhaseDriver.STOPPED: below this the car stands */
#define CRUISE_GAIN 0.5            /* [1/s] harness.run.phases.CRUISE_GAIN */
#define OUT_SPEED 0                /* car.speed, car.position: the first two of railcar.h's outputs */
#define OUT_POSITION 1

static const char *const ACTION_NAMES[RC_ACTIONS] = {"traction", "coast", "cruise", "brake",
                                                     "brake_to_stop", "hold"};
static const char *const PHASE_FIELD_NAMES[RC_PHASE_FIELDS] = {
    "action", "force_N", "until_speed_mps", "until_distance_m", "until_time_s",
    "until_brake_curve", "stop_at_m", "decel_mps2", "mass_change_t", "target_speed_mps"};

static int is_flag(double v) { return v == 0.0 || v == 1.0; }

/* One phase's values into p, checked as harness.run.phases.parse_phase checks the TOML */
static rc_status read_phase(rc_phase *p, const double *v, long i, rc_error *err)
{
    char where[64];
    snprintf(where, sizeof where, "driver[%ld].", i);
    double action = v[RC_PHASE_ACTION];
    if (!(action >= 0.0 && action < RC_ACTIONS) || action != floor(action))
        return rc_refuse_value(err, where, "action", "must be a code 0..5 (traction, coast, "
                               "cruise, brake, brake_to_stop, hold)", action);
    p->action = (int)action;
    snprintf(where, sizeof where, "driver[%ld] (%s).", i, ACTION_NAMES[p->action]);
    for (int f = RC_PHASE_FORCE; f < RC_PHASE_FIELDS; f++) {
        int optional = f != RC_PHASE_UNTIL_BRAKE_CURVE && f != RC_PHASE_DECEL
                       && f != RC_PHASE_MASS_CHANGE;
        if (isfinite(v[f]) || (optional && isnan(v[f])))
            continue;
        return rc_refuse_value(err, where, PHASE_FIELD_NAMES[f],
                               optional ? "must be finite or NaN (not given)" : "must be finite",
                               v[f]);
    }
    p->force_N = v[RC_PHASE_FORCE];
    p->until_speed_mps = v[RC_PHASE_UNTIL_SPEED];
    p->until_distance_m = v[RC_PHASE_UNTIL_DISTANCE];
    p->until_time_s = v[RC_PHASE_UNTIL_TIME];
    p->stop_at_m = v[RC_PHASE_STOP_AT];
    p->decel_mps2 = v[RC_PHASE_DECEL];
    p->mass_change_t = v[RC_PHASE_MASS_CHANGE];
    p->target_speed_mps = v[RC_PHASE_TARGET_SPEED];
    p->next_brake = -1;
    if (!is_flag(v[RC_PHASE_UNTIL_BRAKE_CURVE]))
        return rc_refuse_value(err, where, "until_brake_curve", "must be 0 or 1",
                               v[RC_PHASE_UNTIL_BRAKE_CURVE]);
    p->until_brake_curve = v[RC_PHASE_UNTIL_BRAKE_CURVE] == 1.0;
    if (p->force_N < 0.0)
        return rc_refuse_value(err, where, "force_N", "must be >= 0", p->force_N);
    if (!(p->decel_mps2 > 0.0))
        return rc_refuse_value(err, where, "decel_mps2", "must be > 0", p->decel_mps2);
    if (p->stop_at_m <= 0.0)
        return rc_refuse_value(err, where, "stop_at_m", "must be > 0", p->stop_at_m);
    if (p->target_speed_mps <= 0.0)
        return rc_refuse_value(err, where, "target_speed_mps", "must be > 0", p->target_speed_mps);
    if (p->action == RC_ACTION_BRAKE_TO_STOP && isnan(p->stop_at_m))
        return rc_refuse(err, RC_BAD_CONFIG, "%sstop_at_m: brake_to_stop needs it", where);
    if (p->action == RC_ACTION_HOLD && isnan(p->until_time_s))
        return rc_refuse(err, RC_BAD_CONFIG, "%suntil_time_s: hold needs it (the dwell)", where);
    if (p->action == RC_ACTION_CRUISE && isnan(p->target_speed_mps))
        return rc_refuse(err, RC_BAD_CONFIG, "%starget_speed_mps: cruise needs it", where);
    if (p->mass_change_t != 0.0 && p->action != RC_ACTION_HOLD)
        return rc_refuse(err, RC_BAD_CONFIG, "%smass_change_t: passengers board only in a hold phase", where);
    return RC_OK;
}

/* The header's numbers, checked */
static rc_status read_header(rc_script *s, const double *v, long n, rc_error *err)
{
    if (n < RC_SCRIPT_HEADER)
        return rc_refuse(err, RC_BAD_CONFIG, "script: expected at least %d values (the header), got %ld",
                      RC_SCRIPT_HEADER, n);
    if (v[0] != RC_SCRIPT_PHASES && v[0] != RC_SCRIPT_TABLE)
        return rc_refuse_value(err, "script ", "kind", "must be 0 (phases) or 1 (time table)",
                               v[0]);
    s->kind = (int)v[0];
    rc_status st = rc_script_read_timing(v + 1, &s->step_s, &s->duration_s,
                                         &s->stop_after_last_phase, err);
    if (st != RC_OK)
        return st;
    static const char *const car[] = {"car.mass", "car.traction_force_max", "car.brake_force_max"};
    for (int k = 0; k < 3; k++)
        if (!(v[4 + k] >= 0.0 && isfinite(v[4 + k])))
            return rc_refuse_value(err, "the driver's ", car[k], "must be >= 0 and finite",
                                   v[4 + k]);
    s->mass_t = v[4];
    s->traction_force_max = v[5];
    s->brake_force_max = v[6];
    static const char *const counts[] = {"phases", "table rows", "wind steps"};
    long c[3];
    for (int k = 0; k < 3; k++)
        if ((st = rc_script_read_count(v[7 + k], "script", counts[k], &c[k], err)) != RC_OK)
            return st;
    s->n_phases = c[0];
    s->n_table = c[1];
    s->n_wind = c[2];
    long expected = RC_SCRIPT_HEADER + RC_PHASE_FIELDS * c[0] + 3 * c[1] + 2 * c[2];
    if (n != expected)
        return rc_refuse(err, RC_BAD_CONFIG, "script: expected %ld values for %ld phases, %ld table rows and %ld "
                      "wind steps, got %ld", expected, c[0], c[1], c[2], n);
    if (s->kind == RC_SCRIPT_PHASES && (c[0] < 1 || c[1] != 0))
        return rc_refuse(err, RC_BAD_CONFIG, "script: a phase script needs phases and no time table (got %ld "
                      "phases, %ld table rows)", c[0], c[1]);
    if (s->kind == RC_SCRIPT_TABLE && (c[1] < 1 || c[0] != 0))
        return rc_refuse(err, RC_BAD_CONFIG, "script: a time-table script needs table rows and no phases (got %ld "
                      "phases, %ld table rows)", c[0], c[1]);
    return rc_script_count_steps(s->step_s, s->duration_s, &s->steps, err);
}

/* The time table's and the wind's rows, checked as parse_time_table and the scenario check them */
static rc_status check_rows(const rc_script *s, rc_error *err)
{
    char where[64];
    for (long k = 0; k < s->n_table; k++) {
        const double *row = s->table + 3 * k;
        static const char *const cols[] = {"time_s", "traction_N", "brake_N"};
        snprintf(where, sizeof where, "driver_table row %ld: ", k + 1);
        for (int j = 0; j < 3; j++) {
            if (!isfinite(row[j]))
                return rc_refuse_value(err, where, cols[j], "must be finite", row[j]);
            if (j > 0 && row[j] < 0.0)
                return rc_refuse_value(err, where, cols[j], "must be >= 0", row[j]);
        }
        if (k > 0 && !(row[0] > row[-3]))
            return rc_refuse_value(err, where, "time_s", "must increase", row[0]);
    }
    return rc_wind_schedule_check(s->wind, s->n_wind, err);
}

rc_status rc_script_init(rc_script *s, const double *values, long n, rc_error *err)
{
    memset(s, 0, sizeof *s);
    if (err)
        err->msg[0] = '\0';
    rc_status st = read_header(s, values, n, err);
    if (st != RC_OK)
        return st;
    long rows = 3 * s->n_table + 2 * s->n_wind;
    s->phases = malloc(sizeof *s->phases * (size_t)(s->n_phases > 0 ? s->n_phases : 1));
    s->table = malloc(sizeof *s->table * (size_t)(rows > 0 ? rows : 1));
    if (!s->phases || !s->table) {
        rc_script_free(s);
        return rc_refuse(err, RC_BAD_CONFIG, "script: out of memory");
    }
    const double *v = values + RC_SCRIPT_HEADER;
    for (long i = 0; i < s->n_phases; i++, v += RC_PHASE_FIELDS)
        if ((st = read_phase(&s->phases[i], v, i, err)) != RC_OK) {
            rc_script_free(s);
            return st;
        }
    for (long i = s->n_phases - 1, next = -1; i >= 0; i--) {   /* PhaseDriver._next_brake_phase */
        s->phases[i].next_brake = next;
        if (s->phases[i].action == RC_ACTION_BRAKE_TO_STOP)
            next = i;
    }
    memcpy(s->table, v, sizeof *s->table * (size_t)rows);
    s->wind = s->table + 3 * s->n_table;
    if ((st = check_rows(s, err)) != RC_OK)
        rc_script_free(s);
    return st;
}

void rc_script_free(rc_script *s)
{
    free(s->phases);
    free(s->table);
    s->phases = NULL;
    s->table = s->wind = NULL;
}

double rc_script_wind_at(const rc_script *s, double t)
{
    return rc_wind_schedule_at(s->wind, s->n_wind, t);
}

void rc_script_driver_start(rc_script_driver *d, const rc_script *s)
{
    d->script = s;
    d->index = 0;
    d->phase_start = 0.0;
}

int rc_script_driver_finished(const rc_script_driver *d)
{
    return d->script->kind == RC_SCRIPT_PHASES && d->index >= d->script->n_phases;
}

/* PhaseDriver._phase_done */
static int phase_done(const rc_script_driver *d, const rc_phase *p, double t, double v, double x)
{
    if (!isnan(p->until_time_s) && t - d->phase_start >= p->until_time_s - 1e-9)
        return 1;
    if (!isnan(p->until_speed_mps)) {
        if (p->action == RC_ACTION_TRACTION && v >= p->until_speed_mps)
            return 1;
        if (p->action != RC_ACTION_TRACTION && v <= p->until_speed_mps)
            return 1;
    }
    if (!isnan(p->until_distance_m) && x >= p->until_distance_m)
        return 1;
    if (p->until_brake_curve && p->next_brake >= 0) {
        const rc_phase *nb = &d->script->phases[p->next_brake];
        if (v * v / (2.0 * rc_max(nb->stop_at_m - x, 1e-3)) >= nb->decel_mps2)
            return 1;
    }
    if (p->action == RC_ACTION_BRAKE_TO_STOP && v <= STOPPED && t > d->phase_start)
        return 1;
    return 0;
}

static rc_demands demands(double traction, double brake, double payload_change_t)
{
    rc_demands d = {traction, brake, payload_change_t};
    return d;
}

/* TimeTable.at: bisect_right, then linear between the rows around t */
static rc_demands table_at(const rc_script *s, double t)
{
    const double *tab = s->table;
    long lo = 0, hi = s->n_table;
    while (lo < hi) {                  /* CPython's bisect_right */
        long mid = (lo + hi) / 2;
        if (t < tab[3 * mid])
            hi = mid;
        else
            lo = mid + 1;
    }
    long k = lo;
    if (k == 0)
        return demands(tab[1], tab[2], 0.0);
    if (k == s->n_table)
        return demands(tab[3 * (k - 1) + 1], tab[3 * (k - 1) + 2], 0.0);
    const double *r0 = tab + 3 * (k - 1), *r1 = tab + 3 * k;
    double w = (t - r0[0]) / (r1[0] - r0[0]);
    return demands(r0[1] + w * (r1[1] - r0[1]), r0[2] + w * (r1[2] - r0[2]), 0.0);
}

rc_demands rc_script_driver_demands(rc_script_driver *d, double t, double speed, double position)
{
    const rc_script *s = d->script;
    if (s->kind == RC_SCRIPT_TABLE)
        return table_at(s, t);
    double mass_change = 0.0;
    while (!rc_script_driver_finished(d) && phase_done(d, &s->phases[d->index], t, speed, position)) {
        d->index++;
        d->phase_start = t;
        if (!rc_script_driver_finished(d) && s->phases[d->index].mass_change_t != 0.0)
            mass_change += s->phases[d->index].mass_change_t;
    }
    const double b_max = s->brake_force_max;
    if (rc_script_driver_finished(d))
        return demands(0.0, speed <= STOPPED ? 0.3 * b_max : 0.0, mass_change);
    const rc_phase *p = &s->phases[d->index];
    switch (p->action) {
    case RC_ACTION_TRACTION:
        return demands(isnan(p->force_N) ? s->traction_force_max : p->force_N, 0.0, mass_change);
    case RC_ACTION_COAST:
        return demands(0.0, 0.0, mass_change);
    case RC_ACTION_BRAKE:
        return demands(0.0, isnan(p->force_N) ? 0.6 * b_max : p->force_N, mass_change);
    case RC_ACTION_HOLD:
        return demands(0.0, 0.3 * b_max, mass_change);
    case RC_ACTION_CRUISE: {
        double demand = 1000.0 * s->mass_t * CRUISE_GAIN * (p->target_speed_mps - speed);
        if (demand >= 0.0)
            return demands(rc_min(demand, s->traction_force_max), 0.0, mass_change);
        return demands(0.0, rc_min(-demand, b_max), mass_change);
    }
    default: {                         /* brake_to_stop: the deceleration to stop at stop_at_m */
        double left = p->stop_at_m - position;
        if (speed <= STOPPED || left <= 0.05)
            return demands(0.0, 0.3 * b_max, mass_change);
        double need = speed * speed / (2.0 * left);
        return demands(0.0, rc_min(b_max, 1000.0 * s->mass_t * need), mass_change);
    }
    }
}

rc_status rc_script_advance(rc_chain *chain, long k, double t, double h, const double *u,
                            double *next_outputs, rc_error *err)
{
    rc_status st = rc_chain_step(chain, t, h, u[0], u[1], u[2], u[3], err);
    if (st != RC_OK) {
        if (err) {
            char why[RC_MSG_SIZE];
            memcpy(why, err->msg, sizeof why);
            snprintf(err->msg, sizeof err->msg, "step %ld: %.200s", k, why);
        }
        return st;
    }
    rc_chain_outputs(chain, next_outputs);
    return RC_OK;
}

rc_status rc_script_run(const rc_script *s, rc_chain *chain, double *outputs, double *inputs,
                        long *rows, int *finished, rc_error *err)
{
    const double h = s->step_s;
    rc_script_driver driver;
    rc_script_driver_start(&driver, s);
    double *out = outputs;
    rc_chain_outputs(chain, out);
    *rows = 1;
    *finished = 0;
    if (err)
        err->msg[0] = '\0';
    double payload = 0.0;
    for (long k = 0; k < s->steps; k++) {
        double t = (double)k * h;
        rc_demands d = rc_script_driver_demands(&driver, t, out[OUT_SPEED], out[OUT_POSITION]);
        payload += d.payload_change_t;
        if (s->stop_after_last_phase && rc_script_driver_finished(&driver)) {
            *finished = 1;
            break;
        }
        double *u = inputs + RC_SCRIPT_INPUTS * k;
        u[0] = d.traction;
        u[1] = d.brake;
        u[2] = rc_script_wind_at(s, t);
        u[3] = payload;
        out += RC_CHAIN_OUTPUTS;
        rc_status st = rc_script_advance(chain, k, t, h, u, out, err);
        if (st != RC_OK)
            return st;
        (*rows)++;
    }
    return RC_OK;
}
