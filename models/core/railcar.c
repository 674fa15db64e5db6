/* railcar.c -- see railcar.h; the bodies of models/chain.py's RailCarChain, same expressions in
 * the same order. */
#include "rc_fp_contract.h"
#include "railcar.h"

#include <stdlib.h>
#include <string.h>

#include "checks.h"
#include "validate.h"
#include "track_sensors.h"

/* RailCarChain._check_inputs: the first input that is bad or beyond physics */
static rc_status check_inputs(const rc_chain *c, rc_error *err, double current_time,
                              double step_size, double traction, double brake, double wind,
                              double payload)
{
    rc_status s;
    if ((s = rc_check_step(err, current_time, step_size))
            || (s = rc_check_force(err, "traction_force_demand", traction))
            || (s = rc_check_force(err, "brake_force_demand", brake))
            || (s = rc_check_bounded(err, "traction_force_demand", traction, c->traction_limit, "N",
                                  "10 x car.traction_force_max"))
            || (s = rc_check_bounded(err, "brake_force_demand", brake, c->brake_limit, "N",
                                  "10 x car.brake_force_max"))
            || (s = rc_check_finite(err, "wind_speed", wind, "m/s"))
            || (s = rc_check_bounded(err, "wind_speed", wind, MAX_WIND, "m/s", "no wind blows that hard"))
            || (s = rc_check_finite(err, "car.payload", payload, "t"))
            || (s = rc_check_bounded(err, "car.payload", payload, c->payload_limit, "t", "10 x car.mass")))
        return s;
    return RC_OK;
}

/* ------------------------------------------------------------------ the chain */

/* a configuration the core leaves to Python: "the C core does not cover <what> ..." */
static rc_status refuse(rc_error *err, const char *what)
{
    return rc_refuse(err, RC_BAD_CONFIG, "the C core does not cover %s (the Python chain runs it)",
                     what);
}


/* RailCarChain._take_sample */
static void take_sample(rc_chain *c)
{
    const rc_plant_state *s = &c->plant.state;
    const rc_filter_config *f = &c->cfg.filter;
    c->sensor_speed = s->speed + (f->speed_std + f->speed_std_rel * fabs(s->speed))
                      * rc_stream_normal(&c->streams[RC_SPEED_SENSOR]);
    c->sensor_position = s->position + (f->position_std + f->position_std_rel * fabs(s->position))
                         * rc_stream_normal(&c->streams[RC_POSITION_SENSOR]);
    rc_estimator_measure(&c->est, c->sensor_speed, c->sensor_position);
    if (c->has_pending_track) {
        double v = c->pending_speed;
        rc_estimator_measure_track_speed(&c->est, v, c->pending_age,
                                         rc_track_speed_std(v, c->cfg.track_base,
                                                            c->cfg.track_resolution,
                                                            c->cfg.track_jitter),
                                         c->cfg.track_base);
        c->has_pending_track = 0;
    }
}

/* RailCarChain._track_reading: the pair's passages at t_first and t_second [s] */
static void track_reading(rc_chain *c, double t_first, double t_second)
{
    const rc_chain_config *tc = &c->cfg;
    double j1 = tc->track_jitter * rc_stream_normal(&c->streams[RC_TRACK_SENSOR]);
    double j2 = tc->track_jitter * rc_stream_normal(&c->streams[RC_TRACK_SENSOR]);
    double v = rc_track_speed_from_times(t_first, t_second, tc->track_base, tc->track_resolution,
                                         j1, j2);
    double stamp = tc->track_resolution != 0.0 ? rc_track_quantise(t_second + j2, tc->track_resolution)
                                               : t_second + j2;
    if (!isfinite(v))
        return;                              /* both stamps on one tick: no reading */
    c->track_speed = v;
    c->track_time = stamp + c->start_time;
    c->has_pending_track = 1;
    c->pending_speed = v;
    c->pending_age = c->plant.time - stamp;
}

/* RailCarChain._track_passages: track sensors passed since (t0, x0, v0); a pair's second sensor
 * yields a speed */
static void track_passages(rc_chain *c, double t0, double x0, double v0)
{
    const rc_plant_state *s = &c->plant.state;
    double t1 = c->plant.time, x1 = s->position, v1 = s->speed;
    if (x1 < x0) {                           /* the distance restarted at a station */
        c->has_track_t1 = 0;
        return;
    }
    const double spacing = c->cfg.track_spacing, base = c->cfg.track_base;
    double k = floor(x0 / spacing);          /* Python's int: whole, exact in a double */
    for (;;) {                               /* sensors at k*spacing (first) and +base (second) */
        for (int second = 0; second < 2; second++) {
            double d = second ? k * spacing + base : k * spacing;
            if (k >= 1.0 && x0 < d && d <= x1) {
                double t = rc_track_hermite_crossing(t0, x0, v0, t1, x1, v1, d);
                if (!second) {
                    c->has_track_t1 = 1;
                    c->track_t1 = t;
                } else if (c->has_track_t1) {
                    track_reading(c, c->track_t1, t);
                    c->has_track_t1 = 0;
                }
            }
        }
        k += 1.0;
        if (k * spacing > x1)
            return;
    }
}

/* Everything RailCarChain.__init__ does after the profiles are in place (init and reset) */
static rc_status start(rc_chain *c, rc_error *err)
{
    c->start_time = c->cfg.start_time;
    for (int k = 0; k < RC_STREAMS; k++)
        rc_stream_seed(&c->streams[k], (uint64_t)c->cfg.seed, (uint32_t)k);
    c->track_speed = c->track_time = 0.0;
    c->has_track_t1 = 0;
    c->track_t1 = 0.0;
    c->has_pending_track = 0;
    c->pending_speed = c->pending_age = 0.0;
    c->base_mass = c->cfg.vehicle.mass;
    c->traction_limit = FORCE_LIMIT_FACTOR * rc_max(c->cfg.vehicle.traction_force_max, 1.0);
    c->brake_limit = FORCE_LIMIT_FACTOR * rc_max(c->cfg.vehicle.brake_force_max, 1.0);
    c->payload_limit = FORCE_LIMIT_FACTOR * c->cfg.vehicle.mass;
    rc_plant_init(&c->plant, &c->cfg.vehicle, &c->grade, c->cfg.solver_step, c->cfg.process_noise_psd,
                  c->cfg.station.dwell, &c->streams[RC_PROCESS]);
    c->plant.state.speed = c->cfg.initial_speed;
    c->plant.state.position = c->cfg.initial_position;
    rc_plant_refresh_outputs(&c->plant, 0.0, 0.0, 0.0);
    rc_filter_config filt = c->cfg.filter;
    filt.length = c->cfg.vehicle.length;
    if (rc_estimator_init(&c->est, &c->cfg.identifier, &filt, &c->cfg.station, &c->grade,
                          c->speed.n ? &c->speed : NULL, c->cfg.sample_period,
                          c->cfg.method == 2 ? c->cfg.slope_window : 0, c->cfg.physical,
                          c->cfg.sigma2_method) != 0) {
        return rc_refuse(err, RC_BAD_CONFIG, "out of memory for the identifier's batch");
    }
    c->sample_index = 0;
    c->sensor_speed = c->sensor_position = 0.0;
    c->traction_force_mean = c->brake_force_mean = 0.0;
    take_sample(c);
    return RC_OK;
}

rc_status rc_chain_init(rc_chain *c, const rc_chain_config *cfg, rc_error *err)
{
    memset(c, 0, sizeof *c);
    if (err)
        err->msg[0] = '\0';
    rc_status bad = rc_track_sensors_validate(cfg->track_spacing, cfg->track_base,
                                              cfg->track_resolution, cfg->track_jitter, err);
    if (bad)
        return bad;
    const char *why = rc_estimator_not_covered(cfg->method, cfg->physical, cfg->sigma2_method,
                                               cfg->slope_window);
    if (why)
        return refuse(err, why);
    if (rc_profiles_copy(cfg->grade_distances, cfg->grades, cfg->grade_n, cfg->speed_distances,
                         cfg->speeds, cfg->speed_n, &c->profiles, &c->grade, &c->speed) != 0) {
        return rc_refuse(err, RC_BAD_CONFIG, "%s", cfg->grade_n < 1 || cfg->speed_n < 0
                         ? "track.grade_profile must have at least one row"
                         : "out of memory for the profiles");
    }
    memcpy(&c->cfg, cfg, sizeof c->cfg);            /* padding too: a state holds the bytes */
    c->cfg.grade_distances = c->grade.distances;
    c->cfg.grades = c->grade.grades;
    c->cfg.speed_distances = c->speed.distances;
    c->cfg.speeds = c->speed.speeds;
    rc_status st = start(c, err);
    if (st != RC_OK) {
        free(c->profiles);
        c->profiles = NULL;
    }
    return st;
}

rc_status rc_chain_reset(rc_chain *c, rc_error *err)
{
    if (err)
        err->msg[0] = '\0';
    if (!c->profiles)
        return refuse(err, "a chain that was never initialised");
    rc_estimator_free(&c->est);
    rc_status st = start(c, err);
    if (st != RC_OK) {
        free(c->profiles);
        c->profiles = NULL;
    }
    return st;
}


void rc_chain_free(rc_chain *c)
{
    if (c->profiles) {
        rc_estimator_free(&c->est);
        free(c->profiles);
        c->profiles = NULL;
    }
}

double rc_chain_next_sample_time(const rc_chain *c)
{
    return (double)(c->sample_index + 1) * c->cfg.sample_period;
}

rc_status rc_chain_step(rc_chain *c, double current_time, double step_size, double traction_demand,
                        double brake_demand, double wind_speed, double payload, rc_error *err)
{
    if (err)
        err->msg[0] = '\0';
    if (!(0.0 < step_size && step_size <= MAX_STEP && 0.0 <= traction_demand
          && traction_demand <= c->traction_limit && 0.0 <= brake_demand
          && brake_demand <= c->brake_limit && -MAX_WIND <= wind_speed && wind_speed <= MAX_WIND
          && -c->payload_limit <= payload && payload <= c->payload_limit
          && -INFINITY < current_time && current_time < INFINITY)) {
        rc_status s = check_inputs(c, err, current_time, step_size, traction_demand, brake_demand,
                                   wind_speed, payload);
        if (s)
            return s;
    }
    current_time -= c->start_time;           /* internal time starts at 0 */
    double mass = c->base_mass + payload;
    if (mass <= 0.0) {
        char p[40], m[40];
        rc_repr(payload, p, sizeof p);
        rc_repr(c->base_mass, m, sizeof m);
        return rc_refuse(err, RC_REJECTED, "car.payload %s t leaves a mass <= 0 (car.mass %s t)",
                         p, m);
    }
    c->plant.p.mass = mass;
    double t_end = current_time + step_size;
    double eps = 1e-9 * rc_max(1.0, fabs(t_end));
    if (fabs(current_time - c->plant.time) > eps) {
        char a[40], b[40];
        rc_repr(current_time + c->start_time, a, sizeof a);
        rc_repr(c->plant.time + c->start_time, b, sizeof b);
        return rc_refuse(err, RC_REJECTED,
                         "current time %s s does not continue the FMU's time %s s", a, b);
    }
    for (;;) {
        double t_sample = rc_chain_next_sample_time(c);
        if (t_sample > t_end + eps) {
            if (c->plant.time < t_end - eps)
                rc_plant_advance(&c->plant, t_end, traction_demand, brake_demand, wind_speed);
            return RC_OK;
        }
        double t0 = c->plant.time, x0 = c->plant.state.position, v0 = c->plant.state.speed;
        rc_plant_advance(&c->plant, t_sample, traction_demand, brake_demand, wind_speed);
        if (c->cfg.track_spacing != 0.0)
            track_passages(c, t0, x0, v0);
        /* forces applied over the last sample interval, then the new measurement */
        double ts = c->cfg.sample_period;
        c->traction_force_mean = c->plant.traction_impulse / ts;
        c->brake_force_mean = c->plant.brake_impulse / ts;
        rc_estimator_propagate(&c->est, c->traction_force_mean, c->brake_force_mean, ts);
        c->plant.traction_impulse = c->plant.brake_impulse = 0.0;
        c->sample_index += 1;
        take_sample(c);
    }
}

void rc_chain_outputs(rc_chain *c, double *out)
{
    const rc_plant_state *s = &c->plant.state;
    out[0] = s->speed;
    out[1] = s->position;
    out[2] = s->acceleration;
    out[3] = s->traction_force;
    out[4] = s->brake_force;
    out[5] = s->grade;
    out[6] = (double)s->mode;
    out[7] = c->plant.p.mass;
    out[8] = c->sensor_speed;
    out[9] = c->sensor_position;
    out[10] = c->track_speed;
    out[11] = c->track_time;
    rc_estimator_outputs(&c->est, 0, out + 12);
    out[12 + RC_EST_OUTPUTS] = c->traction_force_mean;
    out[12 + RC_EST_OUTPUTS + 1] = c->brake_force_mean;
}
