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
 * RailCarEstimator backend (the model_* lifecycle, variables, get/set, profiles, messages) is in
 * native_common.c; this file gives its chain type (NATIVE_BACKEND) and model_do_step.
 *
 * Differences from the pythonfmu FMU: a step the core cannot compute (RC_MATH, where Python
 * raises ZeroDivisionError or OverflowError and guarded_step discards the step) is fmi2Error
 * here, since the chain's state is then not known to be unchanged.
 */
#include <stddef.h>
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

#define MODEL(g) ((native_instance *)(g)->model)

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

static void free_chain(void *chain) {
    rc_chain_free(chain);
}

/* the estimator exists from rc_chain_init on */
static int has_estimator(const void *chain) {
    (void)chain;
    return 1;
}

/* the plant's pointers into its chain (rc_chain_init's), after an FMU state copied the chain */
static void link(void *chain) {
    rc_chain *c = chain;
    c->plant.grade = &c->grade;
    c->plant.normal = &c->streams[RC_PROCESS];
}

static const native_chain_kind CHAIN = {
    sizeof(rc_chain_config), sizeof(rc_chain), NATIVE_PROFILE_OFFSETS(rc_chain_config),
    config_from_values, validate, init, outputs, NRC_VR_SLOPE_WINDOW, free_chain,
    NATIVE_CHAIN_LAYOUT(rc_chain), has_estimator,
    {offsetof(rc_chain, plant.grade), offsetof(rc_chain, plant.normal), 0, 0}, 2, link
};

const native_backend NATIVE_BACKEND = {&NRC_MODEL, &CHAIN};

/* -------------------------------------------------------------------------------- stepping */

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    native_instance *m = MODEL(g);
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
