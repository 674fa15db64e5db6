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
#include <stddef.h>
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

#define MODEL(g) ((native_instance *)(g)->model)

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

static void free_chain(void *chain) {
    rc_estchain_free(chain);
}

/* EstimatorChain builds its estimator at the first step */
static int has_estimator(const void *chain) {
    return ((const rc_estchain *)chain)->started;
}

/* no pointers into itself beyond those native_state.c rebuilds */
static void link(void *chain) {
    (void)chain;
}

static const native_chain_kind CHAIN = {
    sizeof(rc_estchain_config), sizeof(rc_estchain), NATIVE_PROFILE_OFFSETS(rc_estchain_config),
    config_from_values, validate, init, outputs, NES_VR_SLOPE_WINDOW, free_chain,
    NATIVE_CHAIN_LAYOUT(rc_estchain), has_estimator, {0, 0, 0, 0}, 0, link
};

const native_backend NATIVE_BACKEND = {&NES_MODEL, &CHAIN};

/* -------------------------------------------------------------------------------- stepping */

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    native_instance *m = MODEL(g);
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
