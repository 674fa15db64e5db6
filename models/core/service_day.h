/* service_day.h -- the 24 h service day of studies/service_day.py run whole in C (issue 31): the
 * C twin of its run_day loop -- ServiceDriver, FaultySensors, the RailCar chain and the faulty
 * stream's EstimatorChain (with the StepRejected retry on the last accepted sample) and both
 * _Score accumulators -- so that a block of steps needs no Python per step. Bit-identical to the
 * Python loop: every expression in the Python's operand order, sums sequential, no FMA
 * (tests/test_service_day.py compares the summaries with ==).
 *
 *   rc_service_day *d = malloc(rc_service_day_size());
 *   rc_service_day_init(d, day, n_day, plant, n_plant, est, n_est, grade_d, grade_g, n_grade,
 *                       wind, n_wind, faults, n_faults, &err);    -- checked, copied, allocated
 *   rc_service_day_run(d, steps, draws, n_draws, &used, &err);    -- a block of steps, repeatable
 *   rc_service_day_export(d, out, cap);                           -- the figures so far, flat
 *   rc_service_day_free(d); free(d);
 *
 * What stays in Python (drawn there as now and passed in): the grade profile, the wind schedule,
 * the fault schedule, the driver's first dwell and the first payload. The driver's later draws
 * come as numpy's Generator.random() doubles in the order ServiceDriver consumes them (departure:
 * target, decel, run, u, [cruise]; arrival: dwell; boarding: payload change); uniform(a, b) is
 * a + (b - a) * draw, as numpy computes it. A step takes at most RC_SD_DRAWS_PER_STEP draws: a run
 * refuses (names the step and the draws left) before a step with fewer left, so it never reads
 * past the array; the steps before it are done and the day can go on with more draws.
 * Allocation happens in rc_service_day_init only.
 */
#ifndef RAILCAR_SERVICE_DAY_H
#define RAILCAR_SERVICE_DAY_H

#include <stddef.h>

#include "railcar.h"
#include "rc_common.h"

/* The day's numbers (the flat `day` values, in this order; studies/service_day.py writes them) */
enum {
    RC_SD_STEPS,                 /* steps of the whole day (n_steps) */
    RC_SD_STEP_S,                /* DayConfig.step_s [s] */
    RC_SD_RUN_LO, RC_SD_RUN_HI,  /* run_time_s [s] */
    RC_SD_DWELL_LO, RC_SD_DWELL_HI,          /* dwell_s [s] */
    RC_SD_TARGET_LO, RC_SD_TARGET_HI,        /* target_kmh [km/h] */
    RC_SD_TRACTION_MAX_S,        /* traction_max_s [s] */
    RC_SD_SHORT_SHARE, RC_SD_SHORT_LO, RC_SD_SHORT_HI,   /* short_cruise_share [-], _s [s] */
    RC_SD_LONG_SHARE, RC_SD_LONG_LO, RC_SD_LONG_HI,      /* long_cruise_share [-], _min [min] */
    RC_SD_DECEL_LO, RC_SD_DECEL_HI,          /* decel_mps2 [m/s^2] */
    RC_SD_PAYLOAD_CHANGE,        /* payload_change_t [t] */
    RC_SD_PAYLOAD_LO, RC_SD_PAYLOAD_HI,      /* payload kept within [t] */
    RC_SD_TRACTION_MAX, RC_SD_BRAKE_MAX,     /* the driver's force limits [N] */
    RC_SD_CRUISE_GAIN,           /* harness.run.phases.CRUISE_GAIN [1/s] */
    RC_SD_BATCH,                 /* est.batch_size: identified samples before 3-sigma counts */
    RC_SD_CAR_MASS,              /* DayConfig.car_mass_t [t] (the first mass seen: it + payload) */
    RC_SD_FIRST_DWELL_END,       /* the driver's first phase_end [s] (drawn in Python) */
    RC_SD_FIRST_PAYLOAD,         /* the first payload [t] (drawn in Python) */
    RC_SD_DAY_VALUES
};

/* FaultySensors' fault kinds (the flat `faults` rows: step index, kind, value) */
enum { RC_SD_FAULT_SPEED, RC_SD_FAULT_POSITION, RC_SD_FAULT_ZERO, RC_SD_FAULT_HOLD, RC_SD_FAULT_KINDS };

#define RC_SD_DRAWS_PER_STEP 7   /* departure 5, arrival 1, boarding 1 */
#define RC_SD_STATUS_MAX 16      /* distinct est.status values counted */
#define RC_SD_MAX_STEPS 1000000000L
#define RC_SD_MAX_STEP_S 3600.0  /* [s] models.chain's MAX_STEP: bounds the hours and stops sized */

/* The export's day part (rc_service_day_export), then the clean and the faulty estimator's part */
enum {
    RC_SD_X_STEPS_DONE, RC_SD_X_STOPS, RC_SD_X_LONG_CRUISES, RC_SD_X_CRUISE_S, RC_SD_X_DISTANCE,
    RC_SD_X_MOVING_STEPS, RC_SD_X_MASS_MIN, RC_SD_X_MASS_MAX,
    RC_SD_X_FAULTS,              /* RC_SD_FAULT_KINDS counts */
    RC_SD_X_REJECTED = RC_SD_X_FAULTS + RC_SD_FAULT_KINDS,
    RC_SD_X_DAY
};
/* An estimator's part: these, then n_outputs non-finite counts (one per output), n_outputs
 * first-seen ranks (the order each first went non-finite; meaningful where counted), hour_len squared
 * speed error sums, hour_len counts, n_status (value, samples) pairs, n_stops stop errors */
enum {
    RC_SD_S_NONFINITE, RC_SD_S_HAS_FIRST, RC_SD_S_FIRST_T, RC_SD_S_FIRST_OUTPUT, RC_SD_S_SIGMA_IN,
    RC_SD_S_SIGMA_N, RC_SD_S_SE_ALL, RC_SD_S_N_ALL, RC_SD_S_HAS_REJECTED, RC_SD_S_REJECTED_LAST,
    RC_SD_S_REJECTED_MAX, RC_SD_S_HOUR_LEN, RC_SD_S_N_STOPS, RC_SD_S_N_STATUS, RC_SD_S_N_OUTPUTS,
    RC_SD_S_FIXED
};

typedef struct {                 /* studies/service_day.py _Score */
    int n_outputs;               /* RC_CHAIN_OUTPUTS (clean) or RC_EST_OUTPUTS (faulty) */
    int est_offset;              /* where the estimator's outputs start among them */
    long nonfinite;
    long nonfinite_by_output[RC_CHAIN_OUTPUTS];
    int first_seen[RC_CHAIN_OUTPUTS];        /* the order outputs first went non-finite */
    int names_seen;
    int has_first;
    double first_t;              /* [s] */
    int first_output;
    long sigma_in, sigma_n;
    double samples_at_departure;
    double *stop_errors;         /* owned: room for stops_cap */
    long n_stops, stops_cap;
    double se_all;               /* [(m/s)^2] */
    long n_all;
    double *hour_se;             /* owned: room for hours_cap [(m/s)^2] */
    long *hour_n;                /* owned */
    long hour_len, hours_cap;
    int has_rejected;
    double rejected_last, rejected_max;
    double status_value[RC_SD_STATUS_MAX];
    long status_count[RC_SD_STATUS_MAX];
    int n_status;
} rc_sd_score;

typedef struct {                 /* studies/service_day.py ServiceDriver */
    int phase;                   /* dwell, traction, cruise, coast, brake */
    double phase_end;            /* [s] */
    long stops, long_cruises;
    double cruise_s;             /* [s] */
    int board;
    double run_start, deadline, target, cruise, decel, stop_at;   /* [s] [s] [m/s] [s] [m/s^2] [m] */
} rc_sd_driver;

typedef struct {
    double day[RC_SD_DAY_VALUES];
    long n_steps;
    long k;                      /* the next step */
    rc_chain plant;              /* points into itself: the struct is never copied */
    rc_estchain est;
    int has_plant, has_est;
    double out[RC_CHAIN_OUTPUTS];            /* the plant's outputs after the last step */
    double est_out[RC_EST_OUTPUTS];
    double *wind;                /* owned: n_wind (time [s], speed [m/s]) rows */
    long n_wind, wind_k;
    double wind_now;             /* [m/s] */
    double *faults;              /* owned: n_faults (step, kind, value) rows, steps increasing */
    long n_faults, fault_k;
    long dropout_left;           /* FaultySensors */
    int dropout_kind;
    double last_speed;           /* [m/s] */
    long fault_counts[RC_SD_FAULT_KINDS];
    double held_speed, held_position;        /* the last accepted faulty sample [m/s], [m] */
    rc_sd_driver driver;
    double payload;              /* [t] */
    double mass_min, mass_max;   /* [t] */
    double distance;             /* [m] */
    long moving_steps, rejected;
    rc_sd_score score[2];        /* clean, faulty */
    int failed;                  /* a refusal mid-step: the state moved, d->k did not; no more runs */
    char failed_msg[RC_MSG_SIZE];
} rc_service_day;

/* sizeof(rc_service_day), for callers that allocate it without this header (ctypes) */
size_t rc_service_day_size(void);

/* The day from its flat values, checked (err names the value: "day.dwell_s ...", "faults row 3:
 * ...", "plant config: ..."): RC_OK, or RC_BAD_CONFIG and nothing to free. plant: the chain's
 * configuration values (models/compiled.py's order, est.slope_window after it); est: the
 * EstimatorChain's (CompiledEstimatorChain's order); wind: n_wind (time, speed) pairs in the
 * schedule's order; faults: n_faults (step index, kind RC_SD_FAULT_*, value) rows, steps
 * increasing. The chains are assumed validated by the caller (open_chain does). */
rc_status rc_service_day_init(rc_service_day *d, const double *day, long n_day,
                              const double *plant, long n_plant, const double *est, long n_est,
                              const double *grade_distances, const double *grades, long n_grade,
                              const double *wind, long n_wind, const double *faults, long n_faults,
                              rc_error *err);
void rc_service_day_free(rc_service_day *d);

/* The next `steps` steps of the day with the driver's draws (*used: how many it took). RC_OK;
 * RC_BAD_CONFIG when the steps go past the day or a step might need more draws than are left
 * (err names it; the steps before it done, the day can go on); a refusal mid-step with err naming
 * the step and who refused: the plant's status, the faulty estimator's when it is not RC_REJECTED
 * (RC_MATH, RC_BAD_CONFIG: Python's exception), or its retry's on the held sample after an
 * RC_REJECTED, or a score's RC_BAD_CONFIG. After a refusal mid-step the day is failed: every later
 * run refuses (RC_BAD_CONFIG, "the day stopped at step k: ..."). */
rc_status rc_service_day_run(rc_service_day *d, long steps, const double *draws, long n_draws,
                             long *used, rc_error *err);

/* The figures so far into out (layout above) when cap is large enough; the values needed */
long rc_service_day_export(const rc_service_day *d, double *out, long cap);

#endif
