/* fmi2_glue.c -- the FMI 2.0 co-simulation entry points, on glue_common.c's registry, state
 * rules, checks and logging (what the FMI 3.0 glue does the same way).
 *
 * Rules (see fmi2_glue.h for the backend's side):
 * - A component that is not a live instance of this library (NULL, freed, garbage, another
 *   FMU's) is never dereferenced: the call returns fmi2Error (fmi2FreeInstance does nothing).
 * - A call the current state does not allow returns fmi2Error and logs the function and state.
 * - A refused call (wrong state, bad value reference, NULL array, bad string) changes nothing and
 *   leaves the state as it was. A failing model call puts the instance in the error state, where
 *   only get*, fmi2Terminate, fmi2Reset and fmi2FreeInstance are accepted.
 * - fmi2Fatal comes only from the backend when its runtime cannot be reached.
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"

static const GlueStandard FMI2 = {
    "fmi2", "component", "step complete", {"a Real", "an Integer", "a Boolean", "a String"},
    "vr", "nvr", "value", "nvr", 0
};

/* One FMI 2 instance: the backend's GlueInstance first (fmi2Component points at it), then the
   host's logger, copied from its callbacks (the struct need not outlive fmi2Instantiate). */
typedef struct {
    GlueInstance g;
    fmi2CallbackLogger logger;
    fmi2ComponentEnvironment env;
} Glue2Instance;

#define LOG_ERROR(g, ...) glue_log((g), fmi2Error, "logStatusError", __VA_ARGS__)

/* FMI 2.0 section 4.2.4 and glue_common.h's masks; also: */
#define MASK_SETUP GLUE_INSTANTIATED
#define MASK_STATUS (GLUE_STEP_COMPLETE | GLUE_TERMINATED)

/* ------------------------------------------------------------------------------ logging */

/* The logger is printf-like, but some hosts (fmpy's Python logger among them) print the format
 * without applying it, and a "%s" format then shows as "%s": pass the text itself as the
 * format, each '%' doubled, and no arguments. A printf-like host prints the text; one that
 * prints the format shows "%%" for a literal '%' (the harness undoes that). */
static void log_to_host(GlueInstance *g, int status, const char *category, const char *message) {
    Glue2Instance *g2 = (Glue2Instance *)g;
    const char *p;
    size_t percents = 0, len = 0;
    char *escaped = NULL;
    for (p = message; *p; p++, len++) percents += *p == '%';
    if (percents) {
        char *q;
        escaped = malloc(len + percents + 1);          /* rare: a message with a '%' */
        if (!escaped) return;
        for (q = escaped, p = message; *p; p++) {
            *q++ = *p;
            if (*p == '%') *q++ = '%';
        }
        *q = '\0';
    }
    g2->logger(g2->env, g->instance_name ? g->instance_name : "", (fmi2Status)status, category,
               escaped ? escaped : message);
    free(escaped);
}

/* ------------------------------------------------------------------------------ the GUID */

/* The GUID in <resources>/../modelDescription.xml: 0 when it differs (logged); a file that
   cannot be read is not an error (a host may extract only what it needs). */
static int guid_matches(GlueInstance *g, const char *guid) {
    char found[8192];
    if (gc_description_attribute(g->resources, "guid", found, sizeof found) < 0 ||
        strcmp(found, guid) == 0)
        return 1;
    LOG_ERROR(g, "fmi2Instantiate: fmuGUID '%s' is not the GUID of this FMU's "
                 "modelDescription.xml ('%s')", guid, found);
    return 0;
}

/* ------------------------------------------------------------------ common FMI 2.0 functions */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    Glue2Instance *g2 = calloc(1, sizeof *g2);
    GlueInstance *g;
    if (!g2) return NULL;
    g = &g2->g;
    if (functions) {
        g2->logger = functions->logger;
        g2->env = functions->componentEnvironment;
    }
    if (!gc_init_instance(g, &FMI2, g2->logger ? log_to_host : NULL,
                          instanceName ? instanceName : "", loggingOn != fmi2False,
                          visible != fmi2False))
        goto fail;
    if (!instanceName) {
        LOG_ERROR(g, "fmi2Instantiate: instanceName is NULL");
        goto fail;
    }
    if (fmuType != fmi2CoSimulation) {
        LOG_ERROR(g, "fmi2Instantiate: this FMU supports co-simulation only (fmuType = %d)",
                  (int)fmuType);
        goto fail;
    }
    if (!fmuGUID) {
        LOG_ERROR(g, "fmi2Instantiate: fmuGUID is NULL");
        goto fail;
    }
    g->resources = gc_resource_path(fmuResourceLocation, 1);
    if (!g->resources) {
        LOG_ERROR(g, "fmi2Instantiate: fmuResourceLocation '%s' is not a file: URI of a local "
                     "folder", fmuResourceLocation ? fmuResourceLocation : "(NULL)");
        goto fail;
    }
    if (!guid_matches(g, fmuGUID)) goto fail;
    if (!(g->token = gc_copy_string(fmuGUID))) goto fail;
    if (model_instantiate(g) != fmi2OK) {
        model_free(g);
        goto fail;
    }
    if (!gc_register(g)) {
        LOG_ERROR(g, "fmi2Instantiate: out of memory");
        model_free(g);
        goto fail;
    }
    return g;
fail:
    gc_free_instance(g);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c) {
    GlueInstance *g = gc_unregister(c);   /* out of the registry first: a second free is a no-op */
    if (!g) {
        if (c)
            fprintf(stderr, "[fmi2] fmi2FreeInstance: component %p is not a live instance of "
                            "this FMU (already freed?); nothing done\n", c);
        return;
    }
    model_free(g);
    gc_free_instance(g);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    GlueInstance *g = gc_lookup(&FMI2, c, "fmi2SetDebugLogging");
    if (!g) return fmi2Error;
    return gc_set_debug_logging(g, "fmi2SetDebugLogging", loggingOn != fmi2False, nCategories,
                                categories, g->model_name ? g->model_name : "this FMU")
           ? fmi2OK : fmi2Error;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    GlueInstance *g = gc_enter(&FMI2, c, "fmi2SetupExperiment", MASK_SETUP);
    fmi2Status s;
    if (!g || !gc_check_times(g, "fmi2SetupExperiment", startTime, stopTimeDefined, stopTime))
        return fmi2Error;
    s = model_setup_experiment(g, toleranceDefined != fmi2False, tolerance, startTime,
                               stopTimeDefined != fmi2False, stopTime);
    if (s == fmi2OK) g->time = startTime;
    return (fmi2Status)gc_settle(g, s);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    GlueInstance *g = gc_enter(&FMI2, c, "fmi2EnterInitializationMode", GLUE_MASK_ENTER_INIT);
    if (!g) return fmi2Error;
    return (fmi2Status)gc_finish(g, model_enter_initialization_mode(g), GLUE_INIT_MODE);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    GlueInstance *g = gc_enter(&FMI2, c, "fmi2ExitInitializationMode", GLUE_MASK_EXIT_INIT);
    if (!g) return fmi2Error;
    return (fmi2Status)gc_finish(g, model_exit_initialization_mode(g), GLUE_STEP_COMPLETE);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    GlueInstance *g = gc_enter(&FMI2, c, "fmi2Terminate", GLUE_MASK_TERMINATE);
    if (!g) return fmi2Error;
    if (gc_terminate_after_error(g, "fmi2Terminate")) return fmi2OK;
    return (fmi2Status)gc_finish(g, model_terminate(g), GLUE_TERMINATED);
}

fmi2Status fmi2Reset(fmi2Component c) {
    GlueInstance *g = gc_enter(&FMI2, c, "fmi2Reset", GLUE_MASK_RESET);
    if (!g) return fmi2Error;
    return (fmi2Status)gc_finish_reset(g, model_reset(g));
}

/* ------------------------------------------------------------------- getting and setting */

static fmi2Status get_values(fmi2Component c, const char *function, GlueType type,
                             const fmi2ValueReference vr[], size_t nvr, void *values) {
    GlueInstance *g = gc_enter(&FMI2, c, function, GLUE_MASK_GET);
    if (!g || !gc_check_refs(g, function, (int)type, NULL, vr, nvr, values, nvr, 0))
        return fmi2Error;
    if (nvr == 0) return fmi2OK;
    return (fmi2Status)gc_settle(g, model_get(g, type, vr, nvr, values));
}

static fmi2Status set_values(fmi2Component c, const char *function, GlueType type,
                             const fmi2ValueReference vr[], size_t nvr, const void *values) {
    GlueInstance *g = gc_enter(&FMI2, c, function, GLUE_MASK_SET);
    if (!g || !gc_check_refs(g, function, (int)type, NULL, vr, nvr, values, nvr, 1))
        return fmi2Error;
    if (nvr == 0) return fmi2OK;
    return (fmi2Status)gc_settle(g, model_set(g, type, vr, nvr, values));
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    return get_values(c, "fmi2GetReal", GLUE_REAL, vr, nvr, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    return get_values(c, "fmi2GetInteger", GLUE_INTEGER, vr, nvr, value);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    return get_values(c, "fmi2GetBoolean", GLUE_BOOLEAN, vr, nvr, value);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    return get_values(c, "fmi2GetString", GLUE_STRING, vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    return set_values(c, "fmi2SetReal", GLUE_REAL, vr, nvr, value);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    return set_values(c, "fmi2SetInteger", GLUE_INTEGER, vr, nvr, value);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    return set_values(c, "fmi2SetBoolean", GLUE_BOOLEAN, vr, nvr, value);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    return set_values(c, "fmi2SetString", GLUE_STRING, vr, nvr, value);
}

/* ------------------------------------------------------- what this FMU does not provide */

/* modelDescription.xml: providesDirectionalDerivative and canInterpolateInputs are false,
   maxOutputDerivativeOrder is 0. */
static fmi2Status not_supported(fmi2Component c, const char *function, const char *why) {
    gc_not_supported(&FMI2, c, function, why);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    return not_supported(c, "fmi2GetDirectionalDerivative", "providesDirectionalDerivative = false");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return not_supported(c, "fmi2SetRealInputDerivatives", "canInterpolateInputs = false");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[], fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    return not_supported(c, "fmi2GetRealOutputDerivatives", "maxOutputDerivativeOrder = 0");
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return not_supported(c, "fmi2CancelStep", "fmi2DoStep never returns fmi2Pending");
}

/* --------------------------------------------------------------------------- FMU states */

/* glue_common.c's (gc_get_state ...), on the backend's GlueStateOps; a backend without them
   (pyslave.c) answers "not supported". The native FMUs declare canGetAndSetFMUstate and
   canSerializeFMUstate. */
fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return (fmi2Status)gc_get_state(&FMI2, c, "fmi2GetFMUstate", FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    return (fmi2Status)gc_set_state(&FMI2, c, "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return (fmi2Status)gc_free_state(&FMI2, c, "fmi2FreeFMUstate", FMUstate);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    return (fmi2Status)gc_state_size(&FMI2, c, "fmi2SerializedFMUstateSize", FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    return (fmi2Status)gc_serialize_state(&FMI2, c, "fmi2SerializeFMUstate", FMUstate,
                                          (unsigned char *)serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    return (fmi2Status)gc_deserialize_state(&FMI2, c, "fmi2DeSerializeFMUstate",
                                            (const unsigned char *)serializedState, size,
                                            FMUstate);
}

/* -------------------------------------------------------------------------- stepping */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    GlueInstance *g = gc_enter(&FMI2, c, "fmi2DoStep", GLUE_MASK_DO_STEP);
    fmi2Status s;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!g) return fmi2Error;
    /* the model judges time and step size itself (a bad one is a discarded step, logged) */
    s = model_do_step(g, currentCommunicationPoint, communicationStepSize);
    if (s == fmi2OK || s == fmi2Warning) g->time = currentCommunicationPoint + communicationStepSize;
    /* After a discarded step the slave asks to end the simulation (fmi2Terminated), as pythonfmu
       did: a master that cannot retry stops at fmi2LastSuccessfulTime instead of repeating the
       step forever (fmpy's simulate_fmu). A master that retries or goes on may: nothing changed. */
    if (s == fmi2OK || s == fmi2Discard) g->terminate_requested = s == fmi2Discard;
    return (fmi2Status)gc_settle(g, s);
}

/* Status queries. doStep is synchronous: there is never a pending step to ask about. */
static GlueInstance *status_call(fmi2Component c, const char *function, const void *value) {
    GlueInstance *g = gc_enter(&FMI2, c, function, MASK_STATUS);
    if (!g) return NULL;
    if (!value) {
        LOG_ERROR(g, "%s: value is NULL", function);
        return NULL;
    }
    return g;
}

static fmi2Status no_such_status(GlueInstance *g, const char *function, fmi2StatusKind s) {
    static const char *const kinds[] = {"fmi2DoStepStatus", "fmi2PendingStatus",
                                        "fmi2LastSuccessfulTime", "fmi2Terminated"};
    const char *kind = (int)s >= 0 && (int)s < 4 ? kinds[(int)s] : "an unknown status kind";
    if (s == fmi2DoStepStatus || s == fmi2PendingStatus)
        LOG_ERROR(g, "%s(%s): fmi2DoStep is synchronous here and never returns fmi2Pending, so "
                     "there is no pending step to report on", function, kind);
    else
        LOG_ERROR(g, "%s: %s (%d) is not a status kind of this function", function, kind, (int)s);
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    GlueInstance *g = status_call(c, "fmi2GetStatus", value);
    if (!g) return fmi2Error;
    return no_such_status(g, "fmi2GetStatus", s);
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    GlueInstance *g = status_call(c, "fmi2GetRealStatus", value);
    if (!g) return fmi2Error;
    if (s != fmi2LastSuccessfulTime) return no_such_status(g, "fmi2GetRealStatus", s);
    *value = g->time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    GlueInstance *g = status_call(c, "fmi2GetIntegerStatus", value);
    if (!g) return fmi2Error;
    return no_such_status(g, "fmi2GetIntegerStatus", s);
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    GlueInstance *g = status_call(c, "fmi2GetBooleanStatus", value);
    if (!g) return fmi2Error;
    if (s != fmi2Terminated) return no_such_status(g, "fmi2GetBooleanStatus", s);
    *value = g->terminate_requested ? fmi2True : fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    GlueInstance *g = status_call(c, "fmi2GetStringStatus", value);
    if (!g) return fmi2Error;
    return no_such_status(g, "fmi2GetStringStatus", s);
}
