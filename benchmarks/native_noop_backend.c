/* native_noop_backend.c -- a native FMU that computes nothing (benchmarks/native_benchmark.py):
 * the model_* functions of fmu_src/c/fmi2_glue.h with RailCar's variable table
 * (native_railcar_table.h) and the native FMUs' storage, get and set (native_common.c), and a
 * fmi2DoStep that does nothing. Through a host it costs what the FMI path costs: the glue's
 * checks, the value-reference lookups and the copies, but no model. Outputs keep their start
 * values. Built with the FMU's glue and native_common.c, the same flags as fmu_src/native.py. */
#include <stdlib.h>

#include "fmi2_glue.h"
#include "native_common.h"
#include "native_railcar_table.h"

typedef struct {
    native_values v;
} Noop;

#define NOOP(g) ((Noop *)(g)->model)

fmi2Status model_instantiate(GlueInstance *g) {
    Noop *m = calloc(1, sizeof *m);
    g->model = m;
    if (!m) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return fmi2Error;
    }
    return native_instantiate(g, &NRC_MODEL, &m->v);
}

void model_free(GlueInstance *g) {
    Noop *m = NOOP(g);
    if (!m) return;
    native_free(&m->v);
    free(m);
    g->model = NULL;
}

fmi2Status model_reset(GlueInstance *g) {
    native_start_values(&NOOP(g)->v);
    return fmi2OK;
}

fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time) {
    (void)tolerance_defined;
    (void)tolerance;
    (void)stop_time_defined;
    (void)stop_time;
    NOOP(g)->v.start_time = start_time;
    return fmi2OK;
}

fmi2Status model_enter_initialization_mode(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_exit_initialization_mode(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    (void)g;
    (void)current_time;
    (void)step_size;
    return fmi2OK;
}

fmi2Status model_terminate(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values) {
    return native_get(g, &NOOP(g)->v, type, vr, nvr, values);
}

fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values) {
    return native_set(g, &NOOP(g)->v, type, vr, nvr, values);
}
