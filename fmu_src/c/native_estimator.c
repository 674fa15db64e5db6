/* native_estimator.c -- the glue's backend for a RailCarEstimator FMU without Python (issue 18):
 * the model_* functions of fmi2_glue.h on the C core's rc_estchain (models/core/railcar.h, the
 * twin of models.chain.EstimatorChain).
 *
 * It behaves as the pythonfmu slave fmu_src/railcar_estimator.py behind pyslave.c does:
 * - every variable holds its start value (native_estimator_table.h, generated from
 *   fmu_src/variables.py) after fmi2Instantiate and fmi2Reset; the outputs keep their start
 *   values until the first step (EstimatorChain has none before it);
 * - fmi2ExitInitializationMode builds the chain as RailCarEstimator._build does, in its order:
 *   the profiles (adapter.load_profiles), then the whole configuration checked by
 *   rc_estchain_validate (EstimatorChain's messages; the options only the pythonfmu
 *   RailCarEstimator.fmu runs are refused naming the parameter and value), then
 *   rc_estchain_init. A failure is fmi2Error with "initialisation failed: <message>";
 * - fmi2DoStep is rc_estchain_step with the inputs (forces, measurements, a track-sensor speed
 *   and its time stamp); a rejected step is fmi2Discard logged as "step discarded: <message>",
 *   nothing changed; a step that let the innovation gate refuse measurements logs
 *   guarded_step's warning.
 * The variables, get/set, the profiles and the messages are native_common.c's (shared with
 * native_railcar.c).
 *
 * Differences from the pythonfmu FMU: a step the core cannot compute (RC_MATH) is fmi2Error.
 */
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "native_common.h"
#include "native_estimator_table.h"
#include "profile.h"
#include "railcar.h"
#include "validate.h"

typedef char nes_outputs_match_the_core[NES_NOUTPUTS == RC_EST_OUTPUTS ? 1 : -1];
typedef char nes_inputs_are_six[NES_NINPUTS == 6 ? 1 : -1];

typedef struct {
    native_values v;                   /* the variables (native_common.h) */
    rc_estchain *chain;                /* after a successful fmi2ExitInitializationMode */
    double outputs[RC_EST_OUTPUTS];
} Native;

#define MODEL(g) ((Native *)(g)->model)

static void drop_chain(Native *m) {
    if (m->chain) {
        rc_estchain_free(m->chain);
        free(m->chain);
        m->chain = NULL;
    }
}

fmi2Status model_instantiate(GlueInstance *g) {
    Native *m = calloc(1, sizeof *m);
    g->model = m;
    if (!m) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return fmi2Error;
    }
    return native_instantiate(g, &NES_MODEL, &m->v);
}

void model_free(GlueInstance *g) {
    Native *m = MODEL(g);
    if (!m) return;
    drop_chain(m);
    native_free(&m->v);
    free(m);
    g->model = NULL;
}

fmi2Status model_reset(GlueInstance *g) {
    drop_chain(MODEL(g));
    native_start_values(&MODEL(g)->v);
    return fmi2OK;
}

fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time) {
    (void)tolerance_defined;
    (void)tolerance;
    (void)stop_time_defined;
    (void)stop_time;
    MODEL(g)->v.start_time = start_time;   /* EstimatorChain does not use it */
    return fmi2OK;
}

fmi2Status model_enter_initialization_mode(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_terminate(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

/* ------------------------------------------------------------------------- initialisation */

/* EstimatorChain (rc_estchain) behind native_build_chain's pointers (native_common.h) */
static long config_from_values(void *cfg, const double *values, long n) {
    return rc_estchain_config_from_values(cfg, values, n);
}

static rc_status validate(const void *cfg, long slope_window, int has_speed, rc_error *err) {
    return rc_estchain_validate(cfg, slope_window, has_speed, err);
}

static rc_status init(void *chain, const void *cfg, rc_error *err) {
    return rc_estchain_init(chain, cfg, err);
}

static int outputs(void *chain, double *out) {
    return rc_estchain_outputs(chain, out);            /* none before the first step */
}

static const native_chain_kind CHAIN = {
    sizeof(rc_estchain_config), sizeof(rc_estchain), NATIVE_PROFILE_OFFSETS(rc_estchain_config),
    config_from_values, validate, init, outputs, NES_VR_SLOPE_WINDOW
};

fmi2Status model_exit_initialization_mode(GlueInstance *g) {
    Native *m = MODEL(g);
    drop_chain(m);
    m->chain = native_build_chain(g, &m->v, &CHAIN, m->outputs);
    return m->chain ? fmi2OK : fmi2Error;
}

/* -------------------------------------------------------------------------------- stepping */

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    Native *m = MODEL(g);
    const double *in = m->v.real;
    rc_error err;
    rc_status s;
    fmi2Integer rejected;
    if (!m->chain)                /* the glue allows doStep only after a successful init */
        return native_not_initialised(g);
    rejected = m->v.integer[NES_VR_FILTER_REJECTED];
    err.msg[0] = '\0';
    /* EstimatorChain.do_step(t, h, traction, brake, speed, position, track_speed, track_time) */
    s = rc_estchain_step(m->chain, current_time, step_size, in[NES_INPUT_VRS[0]],
                         in[NES_INPUT_VRS[1]], in[NES_INPUT_VRS[2]], in[NES_INPUT_VRS[3]],
                         in[NES_INPUT_VRS[4]], in[NES_INPUT_VRS[5]], &err);
    if (s != RC_OK) return native_step_status(g, s, &err);
    if (rc_estchain_outputs(m->chain, m->outputs))
        native_store_outputs(&m->v, m->outputs);
    native_gate_warning(g, &m->v, rejected);
    return fmi2OK;
}

/* ------------------------------------------------------------------- getting and setting */

fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values) {
    return native_get(g, &MODEL(g)->v, type, vr, nvr, values);
}

fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values) {
    return native_set(g, &MODEL(g)->v, type, vr, nvr, values);
}
