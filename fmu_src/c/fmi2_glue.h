/* fmi2_glue.h -- the FMI 2.0 co-simulation glue shared by our FMU binaries.
 *
 * The glue (fmi2_glue.c, with glue_common.c: what it shares with the FMI 3.0 glue) owns
 * everything FMI 2.0 asks of a binary that is not the model itself: the fmi2* entry points, a
 * registry of live instances (a pointer that is not live is refused without being touched), the
 * state machine, value-reference checks against the variable table, the status rules and logging
 * to the host. A backend implements the model_* functions below: pyslave.c drives a pythonfmu
 * slave through the Python C API; native_railcar.c and native_estimator.c run the C model core.
 * The glue calls a backend function only
 *   - for a live instance, in a state where the call is allowed,
 *   - with every value reference checked (exists, has the type of the call, may be set now),
 *   - with non-NULL arrays when nvr > 0 and valid UTF-8 strings for set String.
 *
 * A backend returns fmi2OK, fmi2Discard (model_do_step only: the step was refused and nothing
 * changed), fmi2Error (the model failed; the message is logged; the glue puts the instance in the
 * error state) or fmi2Fatal (the backend's runtime is gone, e.g. the Python interpreter was
 * finalised; the instance becomes unusable).
 */
#ifndef FMI2_GLUE_H
#define FMI2_GLUE_H

#include <stddef.h>

#include "fmi2Functions.h"
#include "glue_common.h"

/* Only symbols marked GLUE_EXPORT leave the shared library (build with -fvisibility=hidden;
   a Windows DLL exports only what is marked dllexport, as the FMI headers mark theirs). */
#if defined(_WIN32)
#define GLUE_EXPORT __declspec(dllexport)
#elif defined(__GNUC__)
#define GLUE_EXPORT __attribute__((visibility("default")))
#else
#define GLUE_EXPORT
#endif

/* GlueInstance, GlueVar, GlueType, ... and the services of the glue to the backend (glue_log,
   glue_alloc_vars, ...) are in glue_common.h: the FMI 3.0 glue offers the same. Its statuses are
   FMI 2's (a backend may pass an fmi2Status where glue_common.h takes an int status): */
typedef char glue_statuses_are_fmi2s[(int)fmi2OK == GLUE_STATUS_OK &&
                                     (int)fmi2Warning == GLUE_STATUS_WARNING &&
                                     (int)fmi2Discard == GLUE_STATUS_DISCARD &&
                                     (int)fmi2Error == GLUE_STATUS_ERROR &&
                                     (int)fmi2Fatal == GLUE_STATUS_FATAL ? 1 : -1];

/* ---- the backend ---- */

fmi2Status model_instantiate(GlueInstance *g);   /* fills model, vars, model_name, categories */
void model_free(GlueInstance *g);                /* must cope with a half-made model */
fmi2Status model_reset(GlueInstance *g);         /* back to start values */
fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time);
fmi2Status model_enter_initialization_mode(GlueInstance *g);
fmi2Status model_exit_initialization_mode(GlueInstance *g);
fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size);
fmi2Status model_terminate(GlueInstance *g);
/* `values` is fmi2Real*, fmi2Integer*, fmi2Boolean* or fmi2String* after `type`. */
fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values);
fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values);

#endif
