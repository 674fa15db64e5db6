/* span_driver.h -- a span scenario run whole in C: the C twin of harness/run/span_scenario.py's
 * AtoDriver (the line's ATO, models/core/ato_line.h, reading the estimator's outputs of the C
 * chain) inside harness/run/driver.py's drive() (the scenario's wind schedule, the payload boarded
 * at the dwells, the early end once the last span stands and stop_after_last_phase), stepping the
 * C chain (railcar.h) for a whole run without returning to the caller per step (issue 31).
 * Bit-identical to the Python loop: the rows, every call's AtoStep and the controllers' log lines
 * (tests/harness_tests/run/test_batch_spans.py).
 *
 *   rc_span_script s;
 *   rc_span_script_init(&s, values, n, &err);   -- the flat description below, checked, copied
 *   rc_chain_init(chain, &cfg, &err);           -- a fresh chain (railcar.h)
 *   rc_span_run(&s, chain, &out, &err);         -- builds the line's controllers, runs, frees them
 *   rc_span_script_free(&s);
 *
 * The flat description (doubles; models/batch.py span_script_values writes it):
 *   [0] step_s [s]  [1] duration_s [s]  [2] stop_after_last_phase (0 or 1)
 *   [3] wind steps  [4] spans   (counts)
 *   then CarTraction's 18 fields (the configured car), AtoTuning's ATO_N_TUNING_FIELDS values,
 *   then per span: length [m], schedule [s], stop [m], dwell_s [s], boarding_t [t], limits n_l,
 *   grade rows n_g, then n_l limit distances [m], n_l limit speeds [m/s], n_g grade distances [m],
 *   n_g grades [permille],
 *   then per wind step: time_s [s], speed_mps [m/s] (in the scenario's order).
 * rc_span_script_init allocates the copies; rc_span_run allocates the line's controllers for the
 * run (ato_controller is large) and frees them; nothing is allocated per step.
 */
#ifndef RAILCAR_SPAN_DRIVER_H
#define RAILCAR_SPAN_DRIVER_H

#include "ato_line.h"
#include "railcar.h"
#include "script_common.h"

#define RC_SPAN_HEADER 5
#define RC_SPAN_CAR_FIELDS 18
#define RC_SPAN_FIELDS 7               /* per span before its arrays */
/* One call of the ATO (harness.run.span_scenario.AtoStep, models.ato.line.LineStep): t [s],
 * span (0-based), command traction [N], brake [N], mode, planned_speed [m/s], ep_stage,
 * dwell (0/1), payload_change [t] */
#define RC_SPAN_STEP_FIELDS 9
/* One log line: "span <k>: ATO at t = <t> s: <text>" (AtoDriver prefixes the scenario's name) */
#define RC_SPAN_LOG_SIZE (ATO_TEXT_SIZE + 64)
/* drive()'s step inputs: traction and brake demand [N], wind [m/s], payload boarded so far [t] */
#define RC_SPAN_INPUTS 4
/* est.station_stops in railcar.h's outputs (models.batch holds it to models.compiled.OUTPUT_NAMES) */
#define RC_SPAN_STATION_STOPS 22

typedef struct {
    double step_s, duration_s;         /* [s] */
    int stop_after_last_phase;
    long steps;                        /* int(round(duration_s / step_s)), as drive() */
    int n_spans;
    long n_wind;
    rc_ato_car car;                    /* the configured car */
    ato_tuning tuning;
    rc_ato_span *spans;                /* owned: n_spans, pointing into `arrays` */
    double *dwell_s, *boarding_t;      /* owned: n_spans each (in `arrays`) */
    double *wind;                      /* owned: n_wind rows of (time_s, speed_mps) (in `arrays`) */
    double *arrays;                    /* owned: every array above, and each grade's cumulation */
} rc_span_script;

/* What a run wrote (the caller's arrays: room for steps + 1 output rows, steps input rows, steps
 * ATO calls, log_cap log lines) and how much of it */
typedef struct {
    double *outputs;                   /* RC_CHAIN_OUTPUTS per row: t = 0 and after every step */
    double *inputs;                    /* RC_SPAN_INPUTS per step */
    double *steps;                     /* RC_SPAN_STEP_FIELDS per ATO call */
    char *log;                         /* RC_SPAN_LOG_SIZE per line */
    long log_cap;
    long rows, calls;                  /* output rows written, ATO calls recorded */
    long log_lines;                    /* lines logged; > log_cap: some did not fit (or left
                                          the controller's event ring): only log_cap written */
    int finished;                      /* ended early: the last span stands and stop_after_last_phase */
} rc_span_output;

/* The description from n flat values (above), checked: RC_OK, or RC_BAD_CONFIG with err naming
 * the value ("span[1].dwell_s ...") and nothing to free. The controllers are not built here (the
 * run builds them: their refusals come from rc_span_run). */
rc_status rc_span_script_init(rc_span_script *s, const double *values, long n, rc_error *err);
void rc_span_script_free(rc_span_script *s);

/* drive() with AtoDriver: the whole run on a freshly initialised chain (the line built first:
 * its refusal is RC_BAD_CONFIG with LineController's ValueError text). RC_OK, or the chain's
 * status with err naming the step (the rows before it written and counted). */
rc_status rc_span_run(const rc_span_script *s, rc_chain *chain, rc_span_output *out, rc_error *err);

#endif
