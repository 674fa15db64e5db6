/* native_railcar.c -- the glue's backend for a RailCar FMU without Python (issue 18): the
 * model_* functions of fmi2_glue.h on the C core's rc_chain (models/core/railcar.h).
 *
 * It behaves as the pythonfmu slave fmu_src/railcar.py behind pyslave.c does:
 * - every variable holds its start value (native_railcar_table.h, generated from
 *   fmu_src/variables.py) after fmi2Instantiate and fmi2Reset; outputs read before
 *   initialisation are those start values;
 * - fmi2ExitInitializationMode builds the chain as fmu_src/adapter.py does, in its order: the
 *   profiles (load_profiles: track.grade_profile, then track.speed_profile; a relative path is
 *   looked up in resources/ first, then the working directory), then the whole configuration
 *   checked by rc_chain_validate (RailCarChain's messages; the options only the pythonfmu
 *   RailCar.fmu runs are refused naming the parameter and value), then rc_chain_init. A failure
 *   is fmi2Error with "initialisation failed: <message>", as adapter.initialise words it;
 * - fmi2DoStep is rc_chain_step with the inputs; a rejected step is fmi2Discard logged as
 *   "step discarded: <message>" (adapter.guarded_step), nothing changed; a step that let the
 *   innovation gate refuse measurements logs guarded_step's warning.
 * The flat configuration (rc_chain_config_from_values) is filled from the table's mapping of
 * each of its numbers to a parameter, the start time or a constant. What it shares with the
 * RailCarEstimator backend (variables, get/set, profiles, messages) is in native_common.c.
 *
 * Differences from the pythonfmu FMU: a step the core cannot compute (RC_MATH, where Python
 * raises ZeroDivisionError or OverflowError and guarded_step discards the step) is fmi2Error
 * here, since the chain's state is then not known to be unchanged.
 */
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"
#include "native_common.h"
#include "native_railcar_table.h"
#include "profile.h"
#include "railcar.h"
#include "validate.h"

/* the table's outputs must be the core's */
typedef char nrc_outputs_match_the_core[NRC_NOUTPUTS == RC_CHAIN_OUTPUTS ? 1 : -1];
typedef char nrc_inputs_are_four[NRC_NINPUTS == 4 ? 1 : -1];

typedef struct {
    native_values v;                   /* the variables (native_common.h) */
    rc_chain *chain;                   /* after a successful fmi2ExitInitializationMode */
    double outputs[RC_CHAIN_OUTPUTS];
} Native;

#define MODEL(g) ((Native *)(g)->model)

static void drop_chain(Native *m) {
    if (m->chain) {
        rc_chain_free(m->chain);
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
    return native_instantiate(g, &NRC_MODEL, &m->v);
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
    MODEL(g)->v.start_time = start_time;
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

/* RailCarChain (rc_chain) behind native_build_chain's pointers (native_common.h) */
static long config_from_values(void *cfg, const double *values, long n) {
    return rc_chain_config_from_values(cfg, values, n);
}

static rc_status validate(const void *cfg, long slope_window, int has_speed, rc_error *err) {
    return rc_chain_validate(cfg, slope_window, has_speed, err);
}

static rc_status init(void *chain, const void *cfg, rc_error *err) {
    return rc_chain_init(chain, cfg, err);
}

static int outputs(void *chain, double *out) {
    rc_chain_outputs(chain, out);
    return 1;
}

static const native_chain_kind CHAIN = {
    sizeof(rc_chain_config), sizeof(rc_chain), NATIVE_PROFILE_OFFSETS(rc_chain_config),
    config_from_values, validate, init, outputs, NRC_VR_SLOPE_WINDOW
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
    rejected = m->v.integer[NRC_VR_FILTER_REJECTED];
    err.msg[0] = '\0';
    s = rc_chain_step(m->chain, current_time, step_size, in[NRC_INPUT_VRS[0]],
                      in[NRC_INPUT_VRS[1]], in[NRC_INPUT_VRS[2]], in[NRC_INPUT_VRS[3]], &err);
    if (s != RC_OK) return native_step_status(g, s, &err);
    rc_chain_outputs(m->chain, m->outputs);
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
