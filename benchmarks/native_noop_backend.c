/* native_noop_backend.c -- a native FMU that computes nothing (benchmarks/native_benchmark.py):
 * RailCar's variable table (native_railcar_table.h) and no chain behind native_common.c's
 * model_* lifecycle (storage, get and set as the native FMUs), and a fmi2DoStep that does
 * nothing. Through a host it costs what the FMI path costs: the glue's
 * checks, the value-reference lookups and the copies, but no model. Outputs keep their start
 * values. Built with the FMU's glue and native_common.c, the same flags as fmu_src/build/native.py. */
#include "fmi2_glue.h"
#include "native_common.h"
#include "native_railcar_table.h"

const native_backend NATIVE_BACKEND = {&NRC_MODEL, NULL};

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    (void)g;
    (void)current_time;
    (void)step_size;
    return fmi2OK;
}
