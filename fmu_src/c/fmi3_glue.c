/* fmi3_glue.c -- FMI 3.0 co-simulation entry points on an fmi2_glue.h backend (see fmi3_glue.h).
 *
 * Rules, as in fmi2_glue.c:
 * - An instance pointer that is not a live instance of this library (NULL, freed, garbage) is
 *   never dereferenced: the call returns fmi3Error (fmi3FreeInstance does nothing).
 * - A call the current state does not allow returns fmi3Error and logs the function and state.
 * - A refused call (wrong state, bad value reference, nValues != nValueReferences, NULL array,
 *   bad string) changes nothing and leaves the state as it was. A failing model call puts the
 *   instance in the error state, where only get*, fmi3Terminate, fmi3Reset and fmi3FreeInstance
 *   are accepted.
 * - A discarded step (fmi3Discard, the model changed nothing) leaves the instance in step mode
 *   with terminateSimulation = false and lastSuccessfulTime = currentCommunicationPoint: the
 *   importer may retry with other inputs or go on.
 */
#define _POSIX_C_SOURCE 200809L

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_glue.h"

/* The backend's FMI 2 types are the FMI 3 types of our variables (see fmi3_glue.h); FMI 2's
   statuses are glue_common.h's (fmi2_glue.h). */
typedef char glue3_real_is_float64[sizeof(fmi2Real) == sizeof(fmi3Float64) ? 1 : -1];
typedef char glue3_integer_is_int32[sizeof(fmi2Integer) == sizeof(fmi3Int32) &&
                                    (fmi2Integer)-1 < 0 ? 1 : -1];
typedef char glue3_vr_sizes[sizeof(fmi2ValueReference) == sizeof(fmi3ValueReference) ? 1 : -1];
typedef char glue3_status_ok[(int)fmi2OK == (int)fmi3OK && (int)fmi2Warning == (int)fmi3Warning &&
                             (int)fmi2Discard == (int)fmi3Discard &&
                             (int)fmi2Error == (int)fmi3Error && (int)fmi2Fatal == (int)fmi3Fatal
                             ? 1 : -1];

static const GlueStandard FMI3 = {
    "fmi3", "instance", "step mode", {"a Float64", "an Int32", "a Boolean", "a String"},
    "valueReferences", "nValueReferences", "values", "nValues", 1
};

#define LOG_ERROR(g, ...) glue_log((g), fmi2Error, "logStatusError", __VA_ARGS__)

/* ------------------------------------------------------------------------------ logging */

/* The host's fmi3LogMessageCallback: the message is plain text, not a format. */
static void log_to_host(GlueInstance *g, int status, const char *category, const char *message) {
    Glue3Instance *g3 = (Glue3Instance *)g;
    g3->log_message(g3->environment, (fmi3Status)status, category, message);
}

/* The instantiationToken in <resources>/../modelDescription.xml: 0 when it differs (logged); a
   file that cannot be read is not an error (a host may extract only what it needs). */
static int token_matches(GlueInstance *g, const char *token) {
    char found[8192];
    if (gc_description_attribute(g->resources, "instantiationToken", found, sizeof found) < 0 ||
        strcmp(found, token) == 0)
        return 1;
    LOG_ERROR(g, "fmi3InstantiateCoSimulation: instantiationToken '%s' is not the one of this "
                 "FMU's modelDescription.xml ('%s')", token, found);
    return 0;
}

/* ------------------------------------------------------------------ common FMI 3.0 functions */

const char *fmi3GetVersion(void) { return fmi3Version; }

static void refuse_without_instance(fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                    const char *message) {
    if (log) log(env, fmi3Error, "logStatusError", message);
    else fprintf(stderr, "[fmi3] %s\n", message);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    refuse_without_instance(instanceEnvironment, logMessage, "fmi3InstantiateModelExchange: this "
                            "FMU provides co-simulation only (no <ModelExchange>)");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName,
                                               fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible,
                                               fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage,
                                               fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName;
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    refuse_without_instance(instanceEnvironment, logMessage, "fmi3InstantiateScheduledExecution: "
                            "this FMU provides co-simulation only (no <ScheduledExecution>)");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible,
                                         fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    Glue3Instance *g3;
    GlueInstance *g;
    (void)earlyReturnAllowed;            /* doStep never returns early: nothing to allow */
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    if (!instanceName || !instanceName[0]) {
        refuse_without_instance(instanceEnvironment, logMessage, "fmi3InstantiateCoSimulation: "
                                "instanceName is NULL or empty");
        return NULL;
    }
    if (eventModeUsed) {
        refuse_without_instance(instanceEnvironment, logMessage, "fmi3InstantiateCoSimulation: "
                                "eventModeUsed = true, but this FMU has no event mode "
                                "(hasEventMode = false)");
        return NULL;
    }
    if (nRequiredIntermediateVariables > 0) {
        refuse_without_instance(instanceEnvironment, logMessage, "fmi3InstantiateCoSimulation: "
                                "requiredIntermediateVariables given, but this FMU has no "
                                "intermediate update mode");
        return NULL;
    }
    g3 = calloc(1, sizeof *g3);
    if (!g3) {
        refuse_without_instance(instanceEnvironment, logMessage,
                                "fmi3InstantiateCoSimulation: out of memory");
        return NULL;
    }
    g = &g3->g;
    g3->log_message = logMessage;
    g3->environment = instanceEnvironment;
    if (!gc_init_instance(g, &FMI3, logMessage ? log_to_host : NULL, instanceName, loggingOn,
                          visible)) {
        refuse_without_instance(instanceEnvironment, logMessage,
                                "fmi3InstantiateCoSimulation: out of memory");
        gc_free_instance(g);
        return NULL;
    }
    g->resources = gc_resource_path(resourcePath, 0);
    if (resourcePath && !g->resources) {   /* NULL: allowed by FMI 3.0 (2.3.1), no resources */
        LOG_ERROR(g, "fmi3InstantiateCoSimulation: resourcePath '%s' is not an absolute path "
                     "on this machine", resourcePath ? resourcePath : "(NULL)");
        gc_free_instance(g);
        return NULL;
    }
    if (!instantiationToken || (g->resources && !token_matches(g, instantiationToken))) {
        if (!instantiationToken)
            LOG_ERROR(g, "fmi3InstantiateCoSimulation: instantiationToken is NULL");
        gc_free_instance(g);
        return NULL;
    }
    if (!(g->token = gc_copy_string(instantiationToken))) {
        LOG_ERROR(g, "fmi3InstantiateCoSimulation: out of memory");
        gc_free_instance(g);
        return NULL;
    }
    if (model_instantiate(g) != fmi2OK) {
        model_free(g);
        gc_free_instance(g);
        return NULL;
    }
    if (!gc_register(g)) {
        LOG_ERROR(g, "fmi3InstantiateCoSimulation: out of memory");
        model_free(g);
        gc_free_instance(g);
        return NULL;
    }
    glue_log(g, fmi2OK, "logAll", "fmi3InstantiateCoSimulation: %s instantiated (resources: %s)",
             g->model_name ? g->model_name : "model", g->resources ? g->resources : "none");
    return g3;
}

void fmi3FreeInstance(fmi3Instance instance) {
    GlueInstance *g = gc_unregister(instance);
    if (!g) {
        if (instance)
            fprintf(stderr, "[fmi3] fmi3FreeInstance: instance %p is not a live instance of this "
                            "FMU; nothing freed\n", instance);
        return;
    }
    model_free(g);
    gc_free_instance(g);
}

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    GlueInstance *g = gc_lookup(&FMI3, instance, "fmi3SetDebugLogging");
    if (!g) return fmi3Error;
    return gc_set_debug_logging(g, "fmi3SetDebugLogging", loggingOn, nCategories, categories,
                                "this FMU") ? fmi3OK : fmi3Error;
}

/* fmi3EnterInitializationMode is FMI 2's fmi2SetupExperiment + fmi2EnterInitializationMode */
fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    static const char function[] = "fmi3EnterInitializationMode";
    GlueInstance *g = gc_enter(&FMI3, instance, function, GLUE_MASK_ENTER_INIT);
    fmi2Status s;
    if (!g || !gc_check_times(g, function, startTime, stopTimeDefined, stopTime))
        return fmi3Error;
    s = model_setup_experiment(g, toleranceDefined, tolerance, startTime, stopTimeDefined,
                               stopTime);
    if (s == fmi2OK) {
        g->time = startTime;
        s = model_enter_initialization_mode(g);
    }
    return (fmi3Status)gc_finish(g, s, GLUE_INIT_MODE);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    GlueInstance *g = gc_enter(&FMI3, instance, "fmi3ExitInitializationMode",
                               GLUE_MASK_EXIT_INIT);
    if (!g) return fmi3Error;
    return (fmi3Status)gc_finish(g, model_exit_initialization_mode(g), GLUE_STEP_COMPLETE);
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    GlueInstance *g = gc_enter(&FMI3, instance, "fmi3Terminate", GLUE_MASK_TERMINATE);
    if (!g) return fmi3Error;
    if (gc_terminate_after_error(g, "fmi3Terminate")) return fmi3OK;
    return (fmi3Status)gc_finish(g, model_terminate(g), GLUE_TERMINATED);
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    GlueInstance *g = gc_enter(&FMI3, instance, "fmi3Reset", GLUE_MASK_RESET);
    if (!g) return fmi3Error;
    return (fmi3Status)gc_finish_reset(g, model_reset(g));
}

/* ------------------------------------------------------------------- getting and setting */

/* FMI 3 wants exactly one independent variable: "time", value reference n_vars
   (GlueStandard.time_variable; fmu_src/build/model_description.py writes the same), read-only, its value the
   instance's time (the start time, then the end of the last successful step). The backend never
   sees it. A `type` < 0 is an FMI 3 type none of our variables has (named by `type_name`). */
static fmi3Status get_values(fmi3Instance instance, const char *function, int type,
                             const char *type_name, const fmi3ValueReference vr[], size_t nvr,
                             void *values, size_t nvalues) {
    GlueInstance *g = gc_enter(&FMI3, instance, function, GLUE_MASK_GET);
    if (!g || !gc_check_refs(g, function, type, type_name, vr, nvr, values, nvalues, 0))
        return fmi3Error;
    if (nvr == 0) return fmi3OK;
    if (type == GLUE_REAL) {                   /* "time" among them? then one by one */
        size_t i;
        fmi2Status s = fmi2OK;
        for (i = 0; i < nvr && vr[i] != g->n_vars; i++) {}
        if (i < nvr) {
            for (i = 0; i < nvr && s == fmi2OK; i++) {
                if (vr[i] == g->n_vars) ((fmi3Float64 *)values)[i] = g->time;
                else s = model_get(g, GLUE_REAL, (const fmi2ValueReference *)&vr[i], 1,
                                   (fmi3Float64 *)values + i);
            }
            return (fmi3Status)gc_settle(g, s);
        }
    }
    return (fmi3Status)gc_settle(g, model_get(g, (GlueType)type, (const fmi2ValueReference *)vr,
                                              nvr, values));
}

static fmi3Status set_values(fmi3Instance instance, const char *function, int type,
                             const char *type_name, const fmi3ValueReference vr[], size_t nvr,
                             const void *values, size_t nvalues) {
    GlueInstance *g = gc_enter(&FMI3, instance, function, GLUE_MASK_SET);
    if (!g || !gc_check_refs(g, function, type, type_name, vr, nvr, values, nvalues, 1))
        return fmi3Error;
    if (nvr == 0) return fmi3OK;
    return (fmi3Status)gc_settle(g, model_set(g, (GlueType)type, (const fmi2ValueReference *)vr,
                                              nvr, values));
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    return get_values(instance, "fmi3GetFloat64", GLUE_REAL, "a Float64", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Int32 values[], size_t nValues) {
    return get_values(instance, "fmi3GetInt32", GLUE_INTEGER, "an Int32", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3GetString(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, fmi3String values[], size_t nValues) {
    return get_values(instance, "fmi3GetString", GLUE_STRING, "a String", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    return set_values(instance, "fmi3SetFloat64", GLUE_REAL, "a Float64", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Int32 values[], size_t nValues) {
    return set_values(instance, "fmi3SetInt32", GLUE_INTEGER, "an Int32", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3SetString(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const fmi3String values[], size_t nValues) {
    return set_values(instance, "fmi3SetString", GLUE_STRING, "a String", valueReferences,
                      nValueReferences, values, nValues);
}

/* Boolean: the backend's fmi2Boolean is an int, fmi3Boolean a bool: converted element-wise. */
fmi3Status fmi3GetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Boolean values[], size_t nValues) {
    GlueInstance *g = gc_enter(&FMI3, instance, "fmi3GetBoolean", GLUE_MASK_GET);
    fmi2Boolean *tmp;
    fmi2Status s;
    size_t i;
    if (!g || !gc_check_refs(g, "fmi3GetBoolean", GLUE_BOOLEAN, "a Boolean", valueReferences,
                             nValueReferences, values, nValues, 0))
        return fmi3Error;
    if (nValueReferences == 0) return fmi3OK;
    if (!(tmp = malloc(nValueReferences * sizeof *tmp))) {
        LOG_ERROR(g, "fmi3GetBoolean: out of memory");
        return fmi3Error;
    }
    s = model_get(g, GLUE_BOOLEAN, (const fmi2ValueReference *)valueReferences, nValueReferences,
                  tmp);
    if (s == fmi2OK)
        for (i = 0; i < nValueReferences; i++) values[i] = tmp[i] != fmi2False;
    free(tmp);
    return (fmi3Status)gc_settle(g, s);
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Boolean values[], size_t nValues) {
    GlueInstance *g = gc_enter(&FMI3, instance, "fmi3SetBoolean", GLUE_MASK_SET);
    fmi2Boolean *tmp;
    fmi2Status s;
    size_t i;
    if (!g || !gc_check_refs(g, "fmi3SetBoolean", GLUE_BOOLEAN, "a Boolean", valueReferences,
                             nValueReferences, values, nValues, 1))
        return fmi3Error;
    if (nValueReferences == 0) return fmi3OK;
    if (!(tmp = malloc(nValueReferences * sizeof *tmp))) {
        LOG_ERROR(g, "fmi3SetBoolean: out of memory");
        return fmi3Error;
    }
    for (i = 0; i < nValueReferences; i++) tmp[i] = values[i] ? fmi2True : fmi2False;
    s = model_set(g, GLUE_BOOLEAN, (const fmi2ValueReference *)valueReferences, nValueReferences,
                  tmp);
    free(tmp);
    return (fmi3Status)gc_settle(g, s);
}

/* FMI 3 types no variable of ours has: any value reference is refused by check_refs (a call
   with none is fmi3OK, as the standard allows). */
#define NO_SUCH_TYPE_GET(fn, ctype, tname)                                                      \
    fmi3Status fn(fmi3Instance instance, const fmi3ValueReference valueReferences[],          \
                  size_t nValueReferences, ctype values[], size_t nValues) {                  \
        return get_values(instance, #fn, -1, tname, valueReferences, nValueReferences, values, \
                          nValues);                                                           \
    }
#define NO_SUCH_TYPE_SET(fn, ctype, tname)                                                      \
    fmi3Status fn(fmi3Instance instance, const fmi3ValueReference valueReferences[],          \
                  size_t nValueReferences, const ctype values[], size_t nValues) {            \
        return set_values(instance, #fn, -1, tname, valueReferences, nValueReferences, values, \
                          nValues);                                                           \
    }

NO_SUCH_TYPE_GET(fmi3GetFloat32, fmi3Float32, "a Float32")
NO_SUCH_TYPE_GET(fmi3GetInt8, fmi3Int8, "an Int8")
NO_SUCH_TYPE_GET(fmi3GetUInt8, fmi3UInt8, "a UInt8")
NO_SUCH_TYPE_GET(fmi3GetInt16, fmi3Int16, "an Int16")
NO_SUCH_TYPE_GET(fmi3GetUInt16, fmi3UInt16, "a UInt16")
NO_SUCH_TYPE_GET(fmi3GetUInt32, fmi3UInt32, "a UInt32")
NO_SUCH_TYPE_GET(fmi3GetInt64, fmi3Int64, "an Int64")
NO_SUCH_TYPE_GET(fmi3GetUInt64, fmi3UInt64, "a UInt64")
NO_SUCH_TYPE_SET(fmi3SetFloat32, fmi3Float32, "a Float32")
NO_SUCH_TYPE_SET(fmi3SetInt8, fmi3Int8, "an Int8")
NO_SUCH_TYPE_SET(fmi3SetUInt8, fmi3UInt8, "a UInt8")
NO_SUCH_TYPE_SET(fmi3SetInt16, fmi3Int16, "an Int16")
NO_SUCH_TYPE_SET(fmi3SetUInt16, fmi3UInt16, "a UInt16")
NO_SUCH_TYPE_SET(fmi3SetUInt32, fmi3UInt32, "a UInt32")
NO_SUCH_TYPE_SET(fmi3SetInt64, fmi3Int64, "an Int64")
NO_SUCH_TYPE_SET(fmi3SetUInt64, fmi3UInt64, "a UInt64")

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueSizes;
    return get_values(instance, "fmi3GetBinary", -1, "a Binary", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueSizes;
    return set_values(instance, "fmi3SetBinary", -1, "a Binary", valueReferences,
                      nValueReferences, values, nValues);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    return get_values(instance, "fmi3GetClock", -1, "a Clock", valueReferences,
                      nValueReferences, values, nValueReferences);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    return set_values(instance, "fmi3SetClock", -1, "a Clock", valueReferences,
                      nValueReferences, values, nValueReferences);
}

/* -------------------------------------------------------------------------- stepping */

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    GlueInstance *g = gc_enter(&FMI3, instance, "fmi3DoStep", GLUE_MASK_DO_STEP);
    fmi2Status s;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!g) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        LOG_ERROR(g, "fmi3DoStep: an out-argument (eventHandlingNeeded, terminateSimulation, "
                     "earlyReturn, lastSuccessfulTime) is NULL");
        return fmi3Error;
    }
    /* the model judges time and step size itself (a bad one is a discarded step, logged) */
    s = model_do_step(g, currentCommunicationPoint, communicationStepSize);
    if (s == fmi2OK || s == fmi2Warning)
        g->time = currentCommunicationPoint + communicationStepSize;
    *eventHandlingNeeded = fmi3False;    /* no event mode */
    *earlyReturn = fmi3False;            /* every step runs to its end or not at all */
    /* a discarded step changed nothing: the importer may retry or go on */
    *terminateSimulation = s == fmi2Error || s == fmi2Fatal;
    *lastSuccessfulTime = s == fmi2OK || s == fmi2Warning
                        ? currentCommunicationPoint + communicationStepSize
                        : currentCommunicationPoint;
    return (fmi3Status)gc_settle(g, s);
}

/* ------------------------------------------------------- what this FMU does not provide */

static fmi3Status not_supported(fmi3Instance instance, const char *function, const char *why) {
    gc_not_supported(&FMI3, instance, function, why);
    return fmi3Error;
}

#define NO_EVENT_MODE "a co-simulation FMU without event mode (hasEventMode = false)"
#define NO_ME "co-simulation only, no model exchange"
#define NO_SE "co-simulation only, no scheduled execution"
#define NO_CLOCKS "no clocks"

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    return not_supported(instance, "fmi3EnterEventMode", NO_EVENT_MODE);
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference;
    (void)nDependencies;
    return not_supported(instance, "fmi3GetNumberOfVariableDependencies",
                         "providesPerElementDependencies = false");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    return not_supported(instance, "fmi3GetVariableDependencies",
                         "providesPerElementDependencies = false");
}

/* FMU states: glue_common.c's (gc_get_state ...), as in fmi2_glue.c */
fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return (fmi3Status)gc_get_state(&FMI3, instance, "fmi3GetFMUState", FMUState);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return (fmi3Status)gc_set_state(&FMI3, instance, "fmi3SetFMUState", FMUState);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return (fmi3Status)gc_free_state(&FMI3, instance, "fmi3FreeFMUState", FMUState);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    return (fmi3Status)gc_state_size(&FMI3, instance, "fmi3SerializedFMUStateSize", FMUState,
                                     size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    return (fmi3Status)gc_serialize_state(&FMI3, instance, "fmi3SerializeFMUState", FMUState,
                                          (unsigned char *)serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    return (fmi3Status)gc_deserialize_state(&FMI3, instance, "fmi3DeserializeFMUState",
                                            (const unsigned char *)serializedState, size,
                                            FMUState);
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return not_supported(instance, "fmi3GetDirectionalDerivative",
                         "providesDirectionalDerivatives = false");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns;
    (void)nUnknowns;
    (void)knowns;
    (void)nKnowns;
    (void)seed;
    (void)nSeed;
    (void)sensitivity;
    (void)nSensitivity;
    return not_supported(instance, "fmi3GetAdjointDerivative",
                         "providesAdjointDerivatives = false");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return not_supported(instance, "fmi3EnterConfigurationMode", "no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return not_supported(instance, "fmi3ExitConfigurationMode", "no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    (void)qualifiers;
    return not_supported(instance, "fmi3GetIntervalDecimal", NO_CLOCKS);
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance,
                                   const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    return not_supported(instance, "fmi3GetIntervalFraction", NO_CLOCKS);
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    return not_supported(instance, "fmi3GetShiftDecimal", NO_CLOCKS);
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    return not_supported(instance, "fmi3GetShiftFraction", NO_CLOCKS);
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    return not_supported(instance, "fmi3SetIntervalDecimal", NO_CLOCKS);
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance,
                                   const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    return not_supported(instance, "fmi3SetIntervalFraction", NO_CLOCKS);
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    return not_supported(instance, "fmi3SetShiftDecimal", NO_CLOCKS);
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    return not_supported(instance, "fmi3SetShiftFraction", NO_CLOCKS);
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    return not_supported(instance, "fmi3EvaluateDiscreteStates", NO_EVENT_MODE);
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    (void)discreteStatesNeedUpdate;
    (void)terminateSimulation;
    (void)nominalsOfContinuousStatesChanged;
    (void)valuesOfContinuousStatesChanged;
    (void)nextEventTimeDefined;
    (void)nextEventTime;
    return not_supported(instance, "fmi3UpdateDiscreteStates", NO_EVENT_MODE);
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    return not_supported(instance, "fmi3EnterContinuousTimeMode", NO_ME);
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    return not_supported(instance, "fmi3CompletedIntegratorStep", NO_ME);
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    (void)time;
    return not_supported(instance, "fmi3SetTime", NO_ME);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates;
    (void)nContinuousStates;
    return not_supported(instance, "fmi3SetContinuousStates", NO_ME);
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    (void)derivatives;
    (void)nContinuousStates;
    return not_supported(instance, "fmi3GetContinuousStateDerivatives", NO_ME);
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    (void)eventIndicators;
    (void)nEventIndicators;
    return not_supported(instance, "fmi3GetEventIndicators", NO_ME);
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    (void)continuousStates;
    (void)nContinuousStates;
    return not_supported(instance, "fmi3GetContinuousStates", NO_ME);
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    (void)nominals;
    (void)nContinuousStates;
    return not_supported(instance, "fmi3GetNominalsOfContinuousStates", NO_ME);
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    (void)nEventIndicators;
    return not_supported(instance, "fmi3GetNumberOfEventIndicators", NO_ME);
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    (void)nContinuousStates;
    return not_supported(instance, "fmi3GetNumberOfContinuousStates", NO_ME);
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    return not_supported(instance, "fmi3EnterStepMode", NO_EVENT_MODE
                         ": fmi3ExitInitializationMode enters step mode");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance,
                                    const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    (void)valueReferences;
    (void)nValueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    return not_supported(instance, "fmi3GetOutputDerivatives", "maxOutputDerivativeOrder = 0");
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference;
    (void)activationTime;
    return not_supported(instance, "fmi3ActivateModelPartition", NO_SE);
}
