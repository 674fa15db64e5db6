/* railcar.h -- the whole RailCar chain of models/chain.py in C: plant -> sensors -> online
 * estimator, one struct, the C twin of RailCarChain (bit-identical outputs for the same seed).
 *
 *   rc_chain *c = malloc(sizeof *c);
 *   rc_chain_init(c, &cfg, &err);          -- validated config; copies the profiles
 *   rc_chain_step(c, t, h, F, B, wind, payload, &err);   -- RailCarChain.do_step
 *   rc_chain_outputs(c, out);              -- RailCarChain.outputs(), RC_CHAIN_OUTPUTS values
 *   rc_chain_free(c); free(c);
 *
 * The struct points into itself (the plant at its noise stream and profiles): initialise it
 * where it stays, never copy it. Covered: filter kinds 0-4 (Singer: singer.h), est.method 0 and
 * 2 (est.method 2 needs slope_window: the optional value after the flat configuration,
 * config.c), est.physical 0 and 1, est.sigma2_method 0 and 1, any est.forgetting / est.run_forgetting,
 * car.length, odometry drift, track sensors (track_sensors.h); not covered (rc_chain_init answers
 * RC_BAD_CONFIG, the Python chain runs): est.method 1 and 3.
 */
#ifndef RAILCAR_RAILCAR_H
#define RAILCAR_RAILCAR_H

#include "estimator.h"
#include "noise.h"
#include "plant.h"
#include "rc_common.h"
#include "track.h"

typedef struct {                       /* models.chain.ChainConfig + the profiles */
    rc_vehicle vehicle;
    double solver_step;                /* [s] */
    double process_noise_psd;          /* [m^2/s^3] */
    double sample_period;              /* [s] */
    long seed;                         /* 0..2^31-1 */
    double initial_speed, initial_position;   /* [m/s], [m] */
    rc_station_config station;
    rc_ident_config identifier;
    rc_filter_config filter;
    double track_spacing;              /* [m]: a sensor pair every spacing from a station; 0 none */
    double track_base, track_resolution, track_jitter;   /* [m], [s], [s] (TrackSensorConfig) */
    int method, physical, sigma2_method;      /* est.*: method 0 or 2, physical and sigma2_method 0 or 1 */
    long slope_window;                 /* est.slope_window, with method 2 (config.c) */
    const double *grade_distances, *grades;   /* [m], [permille] */
    long grade_n;
    const double *speed_distances, *speeds;   /* [m], [m/s]; speed_n 0: no speed profile */
    long speed_n;
    double start_time;                 /* host time of the chain's t = 0 [s] */
} rc_chain_config;

/* RailCarChain.outputs(): car.speed, car.position, car.acceleration, car.traction_force,
 * car.brake_force, car.grade, car.mode, car.total_mass, sensor.speed, sensor.position,
 * sensor.track_speed, sensor.track_time, then the estimator's RC_EST_OUTPUTS (estimator.h),
 * then car.traction_force_mean, car.brake_force_mean (the forces the estimator's last propagate
 * received); integers as doubles. The names are models/compiled.py's OUTPUT_NAMES. */
#define RC_CHAIN_OUTPUTS (12 + RC_EST_OUTPUTS + 2)

enum { RC_PROCESS, RC_SPEED_SENSOR, RC_POSITION_SENSOR, RC_TRACK_SENSOR, RC_STREAMS };

typedef struct {
    rc_chain_config cfg;               /* its profile pointers point into `profiles` */
    double *profiles;                  /* owned copy: grade d, g, cum; speed d, v */
    rc_grade_profile grade;
    rc_speed_profile speed;
    rc_stream streams[RC_STREAMS];
    double start_time;
    double track_speed, track_time;    /* [m/s], [s] */
    int has_track_t1;  double track_t1;        /* _track_t1 (None: has_track_t1 0) [s] */
    int has_pending_track;                     /* _pending_track is not None */
    double pending_speed, pending_age;         /* _pending_track's (v, age) [m/s], [s] */
    double base_mass;                  /* [t] */
    double traction_limit, brake_limit, payload_limit;   /* [N], [N], [t] */
    rc_plant plant;
    rc_estimator est;
    long sample_index;
    double sensor_speed, sensor_position;
    /* the forces the estimator's last propagate received: impulse / sample_period [N], 0 before */
    double traction_force_mean, brake_force_mean;
} rc_chain;

/* The configuration from n numbers in models/compiled.py's _config_values order, optionally
 * followed by est.slope_window (the profile pointers are left to the caller): 0, or the
 * number of values expected when n is neither it nor one more (config.c) */
long rc_chain_config_from_values(rc_chain_config *c, const double *values, long n);
rc_status rc_chain_init(rc_chain *c, const rc_chain_config *cfg, rc_error *err);
void rc_chain_free(rc_chain *c);
/* Back to the state rc_chain_init left (same configuration and seed) */
rc_status rc_chain_reset(rc_chain *c, rc_error *err);
/* RailCarChain.do_step: RC_OK, or RC_REJECTED with err naming the input (nothing changed but
 * car.total_mass, as in Python, when the time does not continue) */
rc_status rc_chain_step(rc_chain *c, double current_time, double step_size, double traction_demand,
                        double brake_demand, double wind_speed, double payload, rc_error *err);
/* RailCarChain.next_sample_time() [s] */
double rc_chain_next_sample_time(const rc_chain *c);
/* RailCarChain.outputs() into out[RC_CHAIN_OUTPUTS] */
void rc_chain_outputs(rc_chain *c, double *out);

/* ------------------------------------------------------------------ RailCarEstimator
 * models.chain.EstimatorChain: the estimator alone, one measurement per communication step; the
 * estimator is built at the first step, whose size is the nominal sampling period. */

typedef struct {                       /* what EstimatorChain is built from */
    rc_ident_config identifier;
    rc_filter_config filter;
    rc_station_config station;
    double track_base, track_resolution, track_jitter;   /* [m], [s], [s] */
    int method, physical, sigma2_method;      /* est.*: method 0 or 2, physical and sigma2_method 0 or 1 */
    long slope_window;                 /* est.slope_window, with method 2 (config.c) */
    const double *grade_distances, *grades;
    long grade_n;
    const double *speed_distances, *speeds;
    long speed_n;
} rc_estchain_config;

/* EstimatorChain's outputs: the estimator's RC_EST_OUTPUTS, none before the first step */
typedef struct {
    rc_estchain_config cfg;
    double *profiles;
    rc_grade_profile grade;
    rc_speed_profile speed;
    double last_track_time;            /* [s], -inf before the first */
    double force_limit;                /* [N] */
    int started;                       /* the estimator exists (after the first step) */
    int has_time;  double time;        /* [s] */
    rc_estimator est;
} rc_estchain;

/* As rc_chain_config_from_values, in CompiledEstimatorChain's order (config.c) */
long rc_estchain_config_from_values(rc_estchain_config *c, const double *values, long n);
rc_status rc_estchain_init(rc_estchain *c, const rc_estchain_config *cfg, rc_error *err);
void rc_estchain_free(rc_estchain *c);
/* EstimatorChain.do_step: forces [N] applied over [t, t + h], measurements [m/s], [m], a
 * track-sensor speed [m/s] with its time stamp [s] */
rc_status rc_estchain_step(rc_estchain *c, double current_time, double step_size, double traction,
                           double brake, double speed_meas, double position_meas,
                           double track_speed, double track_time, rc_error *err);
/* EstimatorChain.outputs() into out[RC_EST_OUTPUTS]: 0 before the first step (no outputs) */
int rc_estchain_outputs(rc_estchain *c, double *out);

#endif
