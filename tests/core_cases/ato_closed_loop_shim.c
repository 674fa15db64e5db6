/* ato_closed_loop_shim.c -- a ctypes face of the C ATO closed loop (models/core/ato_closed_loop.c)
 * for tests/model_tests/core/test_core_ato_closed_loop.py, so that a mutated copy of the core can be
 * built and run without the Python extension: one whole run from flat numbers. */
#include "rc_fp_contract.h"
#include "ato_closed_loop.h"

#include <stdlib.h>

int shim_text_size(void) { return ATO_TEXT_SIZE; }

/* One run: chain_values as models/compiled.py's _config_values (+ est.slope_window), the grade
 * (distances, grades), span3 (length, schedule, stop), the limits, car (CarTraction's 18 fields),
 * tuning (AtoTuning's values), truth (VehicleParams' 11 fields). out: ato_loop_result's arrival,
 * settle, stop, margin, energy, interventions, replans, steps, finished. Returns the rc_status;
 * msg (ATO_TEXT_SIZE) says why when it is not RC_OK. */
int shim_run(const double *chain_values, long n_values, const double *grade_d,
             const double *grade_g, long n_grade, const double *span3, const double *lim_d,
             const double *lim_v, int n_lim, const double *car_values,
             const double *tuning_values, const double *truth, double step, double wind,
             long max_steps, double *out, char *msg)
{
    rc_chain_config cfg = {0};
    if (rc_chain_config_from_values(&cfg, chain_values, n_values) != 0)
        return RC_BAD_CONFIG;
    cfg.grade_distances = grade_d;
    cfg.grades = grade_g;
    cfg.grade_n = n_grade;
    double *cum = malloc(sizeof(double) * (size_t)n_grade);
    ato_closed_loop *run = malloc(sizeof *run);
    if (cum == NULL || run == NULL) {
        free(cum);
        free(run);
        return RC_MATH;
    }
    rc_grade_cumulate(grade_d, grade_g, n_grade, cum);
    rc_ato_span span = {span3[0], span3[1], span3[2], {grade_d, grade_g, cum, n_grade}, n_lim,
                        lim_d, lim_v};
    rc_ato_car car;
    ato_car_from_values(&car, car_values);
    ato_tuning tuning;
    ato_tuning_from_values(&tuning, tuning_values);
    ato_loop_config loop = {step, wind, max_steps,
                            {truth[0], truth[1], truth[2], truth[3], truth[4], truth[5], truth[6],
                             truth[7], truth[8], truth[9], truth[10]}};
    ato_loop_result r = {0};
    rc_status st = ato_closed_loop_init(run, &cfg, &span, &car, &tuning, &loop, msg);
    if (st == RC_OK) {
        st = ato_closed_loop_run(run, &r, msg);
        ato_closed_loop_free(run);
    }
    out[0] = r.arrival;
    out[1] = r.settle;
    out[2] = r.stop;
    out[3] = r.margin;
    out[4] = r.energy;
    out[5] = (double)r.interventions;
    out[6] = (double)r.replans;
    out[7] = (double)r.steps;
    out[8] = r.finished;
    free(cum);
    free(run);
    return st;
}
