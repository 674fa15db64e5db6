/* fmi3_glue.h -- the FMI 3.0 co-simulation glue: the same backends as fmi2_glue.h, FMI 3 outside.
 *
 * fmi3_glue.c exports the fmi3* entry points of a co-simulation FMU and drives a backend written
 * for fmi2_glue.h (its model_* functions, e.g. native_railcar.c) unchanged. It is a thin
 * compatibility layer, not a second backend interface:
 *   - the instance (GlueInstance) and the glue services (glue_log, glue_alloc_vars, ...) are
 *     glue_common.c's, as for fmi2_glue.c, so a backend links against either glue unchanged;
 *   - the backend's FMI 2 types are FMI 3's on this platform (checked at compile time):
 *     fmi2Status OK..Fatal = fmi3Status OK..Fatal, fmi2Real = fmi3Float64,
 *     fmi2Integer = fmi3Int32 (our Integer variables are Int32 in FMI 3), fmi2String = fmi3String,
 *     fmi2ValueReference = fmi3ValueReference;
 *   - messages reach the host's fmi3LogMessageCallback as plain text (Glue3Instance below);
 *   - fmi3EnterInitializationMode is model_setup_experiment + model_enter_initialization_mode.
 * Call rules (states, value references, statuses) are those of fmi2_glue.h, in FMI 3 terms:
 * instantiated, initialization mode, step mode (GLUE_STEP_COMPLETE), terminated, error, fatal.
 * Event mode, model exchange, scheduled execution, clocks and derivatives are not
 * provided (modelDescription.xml says so): those calls return fmi3Error with the reason.
 */
#ifndef FMI3_GLUE_H
#define FMI3_GLUE_H

#include "fmi2_glue.h"
#include "fmi3Functions.h"

/* One FMI 3 instance: the backend's GlueInstance first (fmi3Instance points at it), then what
   only FMI 3 has: the host's logger. */
typedef struct {
    GlueInstance g;
    fmi3LogMessageCallback log_message;        /* NULL: no logging */
    fmi3InstanceEnvironment environment;
} Glue3Instance;

#endif
