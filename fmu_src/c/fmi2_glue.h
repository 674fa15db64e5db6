/* fmi2_glue.h -- the FMI 2.0 co-simulation glue shared by our FMU binaries.
 *
 * The glue (fmi2_glue.c) owns everything FMI 2.0 asks of a binary that is not the model itself:
 * the fmi2* entry points, a registry of live instances (a pointer that is not live is refused
 * without being touched), the state machine, value-reference checks against the variable table,
 * the status rules and logging to the host. A backend implements the model_* functions below:
 * pyslave.c drives a pythonfmu slave through the Python C API; a native FMU would implement them
 * on its own model core. The glue calls a backend function only
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

/* Only symbols marked GLUE_EXPORT leave the shared library (build with -fvisibility=hidden). */
#define GLUE_EXPORT __attribute__((visibility("default")))

/* States of FMI 2.0 co-simulation (section 4.2.4) that a synchronous slave can be in. */
typedef enum {
    GLUE_INSTANTIATED = 1 << 0,
    GLUE_INIT_MODE = 1 << 1,
    GLUE_STEP_COMPLETE = 1 << 2,
    GLUE_TERMINATED = 1 << 3,
    GLUE_ERROR = 1 << 4,
    GLUE_FATAL = 1 << 5
} GlueState;

typedef enum { GLUE_REAL, GLUE_INTEGER, GLUE_BOOLEAN, GLUE_STRING } GlueType;

typedef enum {
    GLUE_PARAMETER, GLUE_CALCULATED_PARAMETER, GLUE_INPUT, GLUE_OUTPUT, GLUE_LOCAL,
    GLUE_INDEPENDENT
} GlueCausality;

typedef enum {
    GLUE_CONSTANT, GLUE_FIXED, GLUE_TUNABLE, GLUE_DISCRETE, GLUE_CONTINUOUS
} GlueVariability;

/* One scalar variable; the table is indexed by value reference (name NULL: no such vr). */
typedef struct {
    char *name;
    GlueType type;
    GlueCausality causality;
    GlueVariability variability;
    int settable;               /* the model can set it at all (pythonfmu: it has a setter) */
} GlueVar;

/* One instance. The glue owns every field but `model`, which is the backend's. */
typedef struct GlueInstance {
    char *instance_name;
    char *model_name;           /* set by the backend, for messages */
    char *resources;            /* file-system path of the FMU's resources folder */
    int visible;

    fmi2CallbackLogger logger;  /* copied from the host's callbacks; NULL: no logging */
    fmi2ComponentEnvironment env;
    int logging_on;             /* debug-level (fmi2OK) messages pass only when this is set */
    char **categories;          /* enabled debug categories (fmi2SetDebugLogging); 0 = all */
    size_t n_categories;
    char **known_categories;    /* the model's LogCategories; 0 = accept any */
    size_t n_known_categories;

    GlueState state;
    double time;                /* end of the last successful step (fmi2LastSuccessfulTime) */
    int terminate_requested;    /* after a discarded step, until a step succeeds (fmi2Terminated) */

    GlueVar *vars;              /* indexed by value reference */
    size_t n_vars;

    char *strings;              /* fmi2GetString results point in here until the next call */
    size_t strings_size;

    void *model;                /* the backend's data */
} GlueInstance;

/* ---- services of the glue to the backend ---- */

/* Log a printf-style message; debug-level messages (status fmi2OK) only pass when logging is on
   and `category` is enabled, warnings and worse always pass. */
void glue_log(GlueInstance *g, fmi2Status status, const char *category, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
/* Log `message` as it is (no formatting). */
void glue_log_text(GlueInstance *g, fmi2Status status, const char *category, const char *message);
/* Would a message of this status and category reach the host? (skip building it if not) */
int glue_log_wanted(const GlueInstance *g, fmi2Status status, const char *category);

/* Allocate the variable table for value references 0 .. n-1 (all empty); 0 on failure. */
int glue_alloc_vars(GlueInstance *g, size_t n);
/* Set the model's name / declare one of its log categories (copied); 0 on failure. */
int glue_set_model_name(GlueInstance *g, const char *name);
int glue_add_category(GlueInstance *g, const char *name);
/* Scratch space for fmi2GetString results, valid until the next call on the instance. */
char *glue_string_space(GlueInstance *g, size_t size);
/* Category name FMI-style for a status: logStatusOK ... (our LogCategories). */
const char *glue_status_category(fmi2Status status);

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
