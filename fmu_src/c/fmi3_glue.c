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

#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3_glue.h"

/* The backend's FMI 2 types are the FMI 3 types of our variables (see fmi3_glue.h). */
typedef char glue3_real_is_float64[sizeof(fmi2Real) == sizeof(fmi3Float64) ? 1 : -1];
typedef char glue3_integer_is_int32[sizeof(fmi2Integer) == sizeof(fmi3Int32) &&
                                    (fmi2Integer)-1 < 0 ? 1 : -1];
typedef char glue3_vr_sizes[sizeof(fmi2ValueReference) == sizeof(fmi3ValueReference) ? 1 : -1];
typedef char glue3_status_ok[(int)fmi2OK == (int)fmi3OK && (int)fmi2Warning == (int)fmi3Warning &&
                             (int)fmi2Discard == (int)fmi3Discard &&
                             (int)fmi2Error == (int)fmi3Error && (int)fmi2Fatal == (int)fmi3Fatal
                             ? 1 : -1];

/* ------------------------------------------------------------------------------- registry */

static pthread_mutex_t registry_lock = PTHREAD_MUTEX_INITIALIZER;
static Glue3Instance **registry;
static size_t registry_count, registry_capacity;

static int registry_add(Glue3Instance *g) {
    int ok = 1;
    pthread_mutex_lock(&registry_lock);
    if (registry_count == registry_capacity) {
        size_t cap = registry_capacity ? 2 * registry_capacity : 8;
        Glue3Instance **grown = realloc(registry, cap * sizeof *grown);
        if (grown) {
            registry = grown;
            registry_capacity = cap;
        } else {
            ok = 0;
        }
    }
    if (ok) registry[registry_count++] = g;
    pthread_mutex_unlock(&registry_lock);
    return ok;
}

/* Find `c` among the live instances by pointer value only; with `remove`, take it out. */
static Glue3Instance *registry_find(const void *c, int remove) {
    Glue3Instance *found = NULL;
    size_t i;
    if (!c) return NULL;
    pthread_mutex_lock(&registry_lock);
    for (i = 0; i < registry_count; i++) {
        if ((const void *)registry[i] == c) {
            found = registry[i];
            if (remove) {
                registry[i] = registry[--registry_count];
                if (registry_count == 0) {
                    free(registry);
                    registry = NULL;
                    registry_capacity = 0;
                }
            }
            break;
        }
    }
    pthread_mutex_unlock(&registry_lock);
    return found;
}

static GlueInstance *lookup(fmi3Instance c, const char *function) {
    Glue3Instance *g3 = registry_find(c, 0);
    if (!g3) {
        fprintf(stderr, "[fmi3] %s: instance %p is not a live instance of this FMU "
                        "(NULL, already freed, or never created); returning fmi3Error\n",
                function, c);
        return NULL;
    }
    return &g3->g;
}

/* ------------------------------------------------------------------------------ logging */

/* The FMI 2 style logger glue_log_text calls: to the host's fmi3LogMessageCallback, with the
   '%' doubling of glue_log_text undone (FMI 3 messages are not formats). */
static void forward_log(fmi2ComponentEnvironment env, fmi2String instance_name, fmi2Status status,
                        fmi2String category, fmi2String message, ...) {
    Glue3Instance *g3 = (Glue3Instance *)env;
    char small[512], *text = small;
    const char *p;
    size_t n;
    (void)instance_name;
    if (!g3 || !g3->log_message) return;
    if (!message) message = "";
    n = strlen(message) + 1;
    if (n > sizeof small && !(text = malloc(n))) return;
    {
        char *q = text;
        for (p = message; *p; p++) {
            *q++ = *p;
            if (p[0] == '%' && p[1] == '%') p++;
        }
        *q = '\0';
    }
    g3->log_message(g3->environment, (fmi3Status)status, category, text);
    if (text != small) free(text);
}

const char *glue_status_category(fmi2Status status) {
    switch (status) {
    case fmi2Warning: return "logStatusWarning";
    case fmi2Discard: return "logStatusDiscard";
    case fmi2Error: return "logStatusError";
    case fmi2Fatal: return "logStatusFatal";
    default: return "logAll";
    }
}

int glue_log_wanted(const GlueInstance *g, fmi2Status status, const char *category) {
    size_t i;
    if (!g || !g->logger) return 0;
    if (status >= fmi2Warning) return 1;
    if (!g->logging_on) return 0;
    if (g->n_categories == 0) return 1;
    for (i = 0; i < g->n_categories; i++)
        if (strcmp(g->categories[i], "logAll") == 0 ||
            (category && strcmp(g->categories[i], category) == 0))
            return 1;
    return 0;
}

void glue_log_text(GlueInstance *g, fmi2Status status, const char *category, const char *message) {
    /* as fmi2_glue.c: each '%' doubled for the printf-like FMI 2 logger (forward_log undoes it) */
    const char *text = message ? message : "", *p;
    size_t percents = 0, len = 0;
    char *escaped = NULL;
    if (!category) category = glue_status_category(status);
    if (!glue_log_wanted(g, status, category)) return;
    for (p = text; *p; p++, len++) percents += *p == '%';
    if (percents) {
        char *q;
        escaped = malloc(len + percents + 1);
        if (!escaped) return;
        for (q = escaped, p = text; *p; p++) {
            *q++ = *p;
            if (*p == '%') *q++ = '%';
        }
        *q = '\0';
    }
    g->logger(g->env, g->instance_name ? g->instance_name : "", status, category,
              escaped ? escaped : text);
    free(escaped);
}

void glue_log(GlueInstance *g, fmi2Status status, const char *category, const char *fmt, ...) {
    char small[512], *text = small;
    va_list ap;
    int n;
    if (!category) category = glue_status_category(status);
    if (!glue_log_wanted(g, status, category)) return;
    va_start(ap, fmt);
    n = vsnprintf(small, sizeof small, fmt, ap);
    va_end(ap);
    if (n >= (int)sizeof small) {
        char *big = malloc((size_t)n + 1);
        if (big) {
            va_start(ap, fmt);
            vsnprintf(big, (size_t)n + 1, fmt, ap);
            va_end(ap);
            text = big;
        }
    }
    glue_log_text(g, status, category, n < 0 ? fmt : text);
    if (text != small) free(text);
}

#define LOG_ERROR(g, ...) glue_log((g), fmi2Error, "logStatusError", __VA_ARGS__)

/* ------------------------------------------------------------------------------ helpers */

static char *copy_string(const char *s) {
    char *d;
    size_t n;
    if (!s) return NULL;
    n = strlen(s) + 1;
    d = malloc(n);
    if (d) memcpy(d, s, n);
    return d;
}

static void free_strings(char **list, size_t n) {
    size_t i;
    for (i = 0; i < n; i++) free(list[i]);
    free(list);
}

static const char *state_name(GlueState s) {
    switch (s) {
    case GLUE_INSTANTIATED: return "instantiated";
    case GLUE_INIT_MODE: return "initialization mode";
    case GLUE_STEP_COMPLETE: return "step mode";
    case GLUE_TERMINATED: return "terminated";
    case GLUE_ERROR: return "error";
    case GLUE_FATAL: return "fatal";
    }
    return "?";
}

/* FMI 3 type names of our variables' types */
static const char *type_phrase(GlueType t) {
    return t == GLUE_INTEGER ? "an Int32" : t == GLUE_REAL ? "a Float64"
         : t == GLUE_BOOLEAN ? "a Boolean" : "a String";
}

static const char *causality_phrase(GlueCausality c) {
    switch (c) {
    case GLUE_PARAMETER: return "a parameter";
    case GLUE_CALCULATED_PARAMETER: return "a calculated parameter";
    case GLUE_INPUT: return "an input";
    case GLUE_OUTPUT: return "an output";
    case GLUE_LOCAL: return "a local variable";
    case GLUE_INDEPENDENT: return "the independent variable";
    }
    return "?";
}

static const char *variability_name(GlueVariability v) {
    switch (v) {
    case GLUE_CONSTANT: return "constant";
    case GLUE_FIXED: return "fixed";
    case GLUE_TUNABLE: return "tunable";
    case GLUE_DISCRETE: return "discrete";
    case GLUE_CONTINUOUS: return "continuous";
    }
    return "?";
}

static void describe_mask(int mask, char *out, size_t size) {
    static const GlueState all[] = {GLUE_INSTANTIATED, GLUE_INIT_MODE, GLUE_STEP_COMPLETE,
                                    GLUE_TERMINATED, GLUE_ERROR};
    size_t i, used = 0;
    out[0] = '\0';
    for (i = 0; i < sizeof all / sizeof all[0]; i++) {
        int n;
        if (!(mask & (int)all[i])) continue;
        n = snprintf(out + used, size - used, "%s%s", used ? ", " : "", state_name(all[i]));
        if (n < 0 || (size_t)n >= size - used) break;
        used += (size_t)n;
    }
}

static int allowed(GlueInstance *g, const char *function, int mask) {
    char where[128];
    if ((int)g->state & mask) return 1;
    describe_mask(mask, where, sizeof where);
    LOG_ERROR(g, "%s: not allowed in state '%s' (allowed in: %s)", function, state_name(g->state),
              where);
    return 0;
}

static fmi3Status settle(GlueInstance *g, fmi2Status s) {
    if (s == fmi2Fatal) g->state = GLUE_FATAL;
    else if (s == fmi2Error) g->state = GLUE_ERROR;
    return (fmi3Status)s;
}

static int utf8_valid(const char *s) {
    const unsigned char *p = (const unsigned char *)s;
    while (*p) {
        unsigned c = *p++;
        int extra;
        unsigned min;
        uint32_t cp;
        if (c < 0x80) continue;
        if ((c & 0xE0) == 0xC0) { extra = 1; min = 0x80; cp = c & 0x1F; }
        else if ((c & 0xF0) == 0xE0) { extra = 2; min = 0x800; cp = c & 0x0F; }
        else if ((c & 0xF8) == 0xF0) { extra = 3; min = 0x10000; cp = c & 0x07; }
        else return 0;
        while (extra--) {
            if ((*p & 0xC0) != 0x80) return 0;
            cp = (cp << 6) | (*p++ & 0x3F);
        }
        if (cp < min || cp > 0x10FFFF || (cp >= 0xD800 && cp <= 0xDFFF)) return 0;
    }
    return 1;
}

/* resourcePath (FMI 3: an absolute path, normally with a trailing separator) -> no trailing '/'.
   A file: URI is accepted too (hosts that pass FMI 2 style locations). */
static char *resource_path(const char *path) {
    char *out;
    size_t n;
    if (!path) return NULL;
    if (strncmp(path, "file://", 7) == 0) {
        path += 7;
        if (strncmp(path, "localhost/", 10) == 0) path += 9;
    } else if (strncmp(path, "file:", 5) == 0) {
        path += 5;
    }
    if (*path != '/') return NULL;
    out = copy_string(path);
    if (!out) return NULL;
    n = strlen(out);
    while (n > 1 && out[n - 1] == '/') out[--n] = '\0';
    return out;
}

/* The instantiationToken in <resources>/../modelDescription.xml. 1: equal, 0: differs (logged),
   -1: could not be read (not an error: a host may extract only what it needs). */
static int check_token(GlueInstance *g, const char *token) {
    char head[8192], *root, *attr, *end, *path;
    size_t n, len = strlen(g->resources);
    static const char key[] = " instantiationToken=\"";
    FILE *f;
    path = malloc(len + sizeof "/../modelDescription.xml");
    if (!path) return -1;
    memcpy(path, g->resources, len);
    memcpy(path + len, "/../modelDescription.xml", sizeof "/../modelDescription.xml");
    f = fopen(path, "rb");
    free(path);
    if (!f) return -1;
    n = fread(head, 1, sizeof head - 1, f);
    fclose(f);
    head[n] = '\0';
    root = strstr(head, "<fmiModelDescription");
    if (!root) return -1;
    end = strchr(root, '>');
    attr = strstr(root, key);
    if (!attr || (end && attr > end)) return -1;
    attr += sizeof key - 1;
    end = strchr(attr, '"');
    if (!end) return -1;
    if ((size_t)(end - attr) == strlen(token) && strncmp(attr, token, (size_t)(end - attr)) == 0)
        return 1;
    *end = '\0';
    LOG_ERROR(g, "fmi3InstantiateCoSimulation: instantiationToken '%s' is not the one of this "
                 "FMU's modelDescription.xml ('%s')", token, attr);
    return 0;
}

/* ----------------------------------------------------------------- services to the backend */

int glue_alloc_vars(GlueInstance *g, size_t n) {
    g->vars = calloc(n ? n : 1, sizeof *g->vars);
    g->n_vars = g->vars ? n : 0;
    return g->vars != NULL;
}

int glue_set_model_name(GlueInstance *g, const char *name) {
    char *copy = copy_string(name);
    if (!copy) return 0;
    free(g->model_name);
    g->model_name = copy;
    return 1;
}

int glue_add_category(GlueInstance *g, const char *name) {
    char **grown = realloc(g->known_categories, (g->n_known_categories + 1) * sizeof *grown);
    if (!grown) return 0;
    g->known_categories = grown;
    if (!(grown[g->n_known_categories] = copy_string(name))) return 0;
    g->n_known_categories++;
    return 1;
}

char *glue_string_space(GlueInstance *g, size_t size) {
    if (size > g->strings_size) {
        char *grown = realloc(g->strings, size);
        if (!grown) return NULL;
        g->strings = grown;
        g->strings_size = size;
    }
    return g->strings;
}

static void free_instance(Glue3Instance *g3) {
    GlueInstance *g = &g3->g;
    size_t i;
    for (i = 0; i < g->n_vars; i++) free(g->vars[i].name);
    free(g->vars);
    free_strings(g->categories, g->n_categories);
    free_strings(g->known_categories, g->n_known_categories);
    free(g->strings);
    free(g->instance_name);
    free(g->model_name);
    free(g->resources);
    free(g3);
}

/* --------------------------------------------------------------------------- the states */

#define ANY_STATE (GLUE_INSTANTIATED | GLUE_INIT_MODE | GLUE_STEP_COMPLETE | GLUE_TERMINATED | GLUE_ERROR)
#define MASK_ENTER_INIT GLUE_INSTANTIATED
#define MASK_EXIT_INIT GLUE_INIT_MODE
#define MASK_DO_STEP GLUE_STEP_COMPLETE
#define MASK_TERMINATE (GLUE_STEP_COMPLETE | GLUE_ERROR)
#define MASK_RESET ANY_STATE
#define MASK_GET (GLUE_INIT_MODE | GLUE_STEP_COMPLETE | GLUE_TERMINATED | GLUE_ERROR)
#define MASK_SET (GLUE_INSTANTIATED | GLUE_INIT_MODE | GLUE_STEP_COMPLETE)

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
    g->logger = logMessage ? forward_log : NULL;
    g->env = g3;
    g->logging_on = loggingOn;
    g->visible = visible;
    g->state = GLUE_INSTANTIATED;
    g->instance_name = copy_string(instanceName);
    g->resources = resource_path(resourcePath);
    if (!g->instance_name) {
        refuse_without_instance(instanceEnvironment, logMessage,
                                "fmi3InstantiateCoSimulation: out of memory");
        free_instance(g3);
        return NULL;
    }
    if (!g->resources) {
        LOG_ERROR(g, "fmi3InstantiateCoSimulation: resourcePath '%s' is not an absolute path "
                     "on this machine", resourcePath ? resourcePath : "(NULL)");
        free_instance(g3);
        return NULL;
    }
    if (!instantiationToken || check_token(g, instantiationToken) == 0) {
        if (!instantiationToken)
            LOG_ERROR(g, "fmi3InstantiateCoSimulation: instantiationToken is NULL");
        free_instance(g3);
        return NULL;
    }
    if (model_instantiate(g) != fmi2OK) {
        model_free(g);
        free_instance(g3);
        return NULL;
    }
    if (!registry_add(g3)) {
        LOG_ERROR(g, "fmi3InstantiateCoSimulation: out of memory");
        model_free(g);
        free_instance(g3);
        return NULL;
    }
    glue_log(g, fmi2OK, "logAll", "fmi3InstantiateCoSimulation: %s instantiated (resources: %s)",
             g->model_name ? g->model_name : "model", g->resources);
    return g3;
}

void fmi3FreeInstance(fmi3Instance instance) {
    Glue3Instance *g3 = registry_find(instance, 1);
    if (!g3) {
        if (instance)
            fprintf(stderr, "[fmi3] fmi3FreeInstance: instance %p is not a live instance of this "
                            "FMU; nothing freed\n", instance);
        return;
    }
    model_free(&g3->g);
    free_instance(g3);
}

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    GlueInstance *g = lookup(instance, "fmi3SetDebugLogging");
    char **list;
    size_t i, k;
    if (!g) return fmi3Error;
    if (nCategories > 0 && !categories) {
        LOG_ERROR(g, "fmi3SetDebugLogging: categories[] is NULL but nCategories = %zu",
                  nCategories);
        return fmi3Error;
    }
    for (i = 0; i < nCategories; i++) {
        int known = g->n_known_categories == 0;
        if (!categories[i]) {
            LOG_ERROR(g, "fmi3SetDebugLogging: categories[%zu] is NULL", i);
            return fmi3Error;
        }
        for (k = 0; k < g->n_known_categories && !known; k++)
            known = strcmp(g->known_categories[k], categories[i]) == 0;
        if (!known) {
            LOG_ERROR(g, "fmi3SetDebugLogging: '%s' is not a log category of this FMU",
                      categories[i]);
            return fmi3Error;
        }
    }
    list = nCategories ? calloc(nCategories, sizeof *list) : NULL;
    if (nCategories && !list) {
        LOG_ERROR(g, "fmi3SetDebugLogging: out of memory");
        return fmi3Error;
    }
    for (i = 0; i < nCategories; i++)
        if (!(list[i] = copy_string(categories[i]))) {
            free_strings(list, i);
            LOG_ERROR(g, "fmi3SetDebugLogging: out of memory");
            return fmi3Error;
        }
    free_strings(g->categories, g->n_categories);
    g->categories = list;
    g->n_categories = nCategories;
    g->logging_on = loggingOn;
    return fmi3OK;
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    GlueInstance *g = lookup(instance, "fmi3EnterInitializationMode");
    fmi2Status s;
    if (!g || !allowed(g, "fmi3EnterInitializationMode", MASK_ENTER_INIT)) return fmi3Error;
    if (!isfinite(startTime)) {
        LOG_ERROR(g, "fmi3EnterInitializationMode: startTime = %g is not finite", startTime);
        return fmi3Error;
    }
    if (stopTimeDefined && !(stopTime >= startTime)) {
        LOG_ERROR(g, "fmi3EnterInitializationMode: stopTime = %g is before startTime = %g",
                  stopTime, startTime);
        return fmi3Error;
    }
    s = model_setup_experiment(g, toleranceDefined, tolerance, startTime, stopTimeDefined,
                               stopTime);
    if (s == fmi2OK) {
        g->time = startTime;
        s = model_enter_initialization_mode(g);
    }
    if (s == fmi2OK) g->state = GLUE_INIT_MODE;
    return settle(g, s);
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    GlueInstance *g = lookup(instance, "fmi3ExitInitializationMode");
    fmi2Status s;
    if (!g || !allowed(g, "fmi3ExitInitializationMode", MASK_EXIT_INIT)) return fmi3Error;
    s = model_exit_initialization_mode(g);
    if (s == fmi2OK) g->state = GLUE_STEP_COMPLETE;
    return settle(g, s);
}

fmi3Status fmi3Terminate(fmi3Instance instance) {
    GlueInstance *g = lookup(instance, "fmi3Terminate");
    fmi2Status s;
    if (!g || !allowed(g, "fmi3Terminate", MASK_TERMINATE)) return fmi3Error;
    if (g->state == GLUE_ERROR) {
        glue_log(g, fmi2OK, "logAll", "fmi3Terminate: after an error; the model is not called");
        g->state = GLUE_TERMINATED;
        return fmi3OK;
    }
    s = model_terminate(g);
    if (s == fmi2OK) g->state = GLUE_TERMINATED;
    return settle(g, s);
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    GlueInstance *g = lookup(instance, "fmi3Reset");
    fmi2Status s;
    if (!g || !allowed(g, "fmi3Reset", MASK_RESET)) return fmi3Error;
    s = model_reset(g);
    if (s == fmi2OK) {
        g->state = GLUE_INSTANTIATED;
        g->time = 0.0;
        g->terminate_requested = 0;
    }
    return settle(g, s);
}

/* ------------------------------------------------------------------- getting and setting */

/* FMI 3 wants exactly one independent variable: "time", value reference n_vars (the first one
   after the backend's table; fmu_src/native_fmi3.py writes the same), read-only, its value the
   instance's time (the start time, then the end of the last successful step). The backend never
   sees it. */
static char time_name[] = "time";
static const GlueVar time_var = {time_name, GLUE_REAL, GLUE_INDEPENDENT, GLUE_CONTINUOUS, 0};

/* Check a whole get/set call before the model sees any of it. `type` < 0: an FMI 3 type none of
   our variables has (named by `type_name`). */
static int check_refs(GlueInstance *g, const char *function, int type, const char *type_name,
                      const fmi3ValueReference vr[], size_t nvr, const void *values,
                      size_t nvalues, int setting) {
    size_t i;
    const char *model = g->model_name ? g->model_name : "this FMU";
    if (nvalues != nvr) {
        LOG_ERROR(g, "%s: nValues = %zu but nValueReferences = %zu (all variables of %s are "
                     "scalars)", function, nvalues, nvr, model);
        return 0;
    }
    if (nvr == 0) return 1;
    if (!vr) {
        LOG_ERROR(g, "%s: valueReferences[] is NULL but nValueReferences = %zu", function, nvr);
        return 0;
    }
    if (!values) {
        LOG_ERROR(g, "%s: values[] is NULL but nValues = %zu", function, nvr);
        return 0;
    }
    for (i = 0; i < nvr; i++) {
        const GlueVar *v;
        unsigned long r = (unsigned long)vr[i];
        if (r == g->n_vars) {                  /* the independent variable, see time_var */
            v = &time_var;
        } else if (r > g->n_vars || !g->vars[r].name) {
            LOG_ERROR(g, "%s: value reference %lu (valueReferences[%zu]) is not a variable of %s",
                      function, r, i, model);
            return 0;
        } else {
            v = &g->vars[r];
        }
        if ((int)v->type != type) {
            LOG_ERROR(g, "%s: value reference %lu (valueReferences[%zu]) is '%s', %s variable, "
                         "not %s", function, r, i, v->name, type_phrase(v->type), type_name);
            return 0;
        }
        if (!setting) continue;
        if (v->causality != GLUE_PARAMETER && v->causality != GLUE_INPUT) {
            LOG_ERROR(g, "%s: '%s' (value reference %lu) is %s and cannot be set", function,
                      v->name, r, causality_phrase(v->causality));
            return 0;
        }
        if (v->variability == GLUE_CONSTANT || !v->settable) {
            LOG_ERROR(g, "%s: '%s' (value reference %lu) is %s that cannot be set (%s)", function,
                      v->name, r, causality_phrase(v->causality),
                      v->variability == GLUE_CONSTANT ? "a constant" : "no setter");
            return 0;
        }
        if (g->state == GLUE_STEP_COMPLETE && v->causality == GLUE_PARAMETER &&
            v->variability != GLUE_TUNABLE) {
            LOG_ERROR(g, "%s: '%s' (value reference %lu) is a parameter of variability %s: it "
                         "can be set only before fmi3ExitInitializationMode, not in state '%s' "
                         "(fmi3Reset, then set it and initialise again)",
                      function, v->name, r, variability_name(v->variability),
                      state_name(g->state));
            return 0;
        }
        if (type == GLUE_STRING) {
            const char *s = ((const fmi3String *)values)[i];
            if (!s) {
                LOG_ERROR(g, "%s: values[%zu] for '%s' (value reference %lu) is NULL", function,
                          i, v->name, r);
                return 0;
            }
            if (!utf8_valid(s)) {
                LOG_ERROR(g, "%s: values[%zu] for '%s' (value reference %lu) is not valid UTF-8",
                          function, i, v->name, r);
                return 0;
            }
        }
    }
    return 1;
}

static fmi3Status get_values(fmi3Instance instance, const char *function, int type,
                             const char *type_name, const fmi3ValueReference vr[], size_t nvr,
                             void *values, size_t nvalues) {
    GlueInstance *g = lookup(instance, function);
    if (!g || !allowed(g, function, MASK_GET)) return fmi3Error;
    if (!check_refs(g, function, type, type_name, vr, nvr, values, nvalues, 0)) return fmi3Error;
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
            return settle(g, s);
        }
    }
    return settle(g, model_get(g, (GlueType)type, (const fmi2ValueReference *)vr, nvr, values));
}

static fmi3Status set_values(fmi3Instance instance, const char *function, int type,
                             const char *type_name, const fmi3ValueReference vr[], size_t nvr,
                             const void *values, size_t nvalues) {
    GlueInstance *g = lookup(instance, function);
    if (!g || !allowed(g, function, MASK_SET)) return fmi3Error;
    if (!check_refs(g, function, type, type_name, vr, nvr, values, nvalues, 1)) return fmi3Error;
    if (nvr == 0) return fmi3OK;
    return settle(g, model_set(g, (GlueType)type, (const fmi2ValueReference *)vr, nvr, values));
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
    GlueInstance *g = lookup(instance, "fmi3GetBoolean");
    fmi2Boolean *tmp;
    fmi2Status s;
    size_t i;
    if (!g || !allowed(g, "fmi3GetBoolean", MASK_GET)) return fmi3Error;
    if (!check_refs(g, "fmi3GetBoolean", GLUE_BOOLEAN, "a Boolean", valueReferences,
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
    return settle(g, s);
}

fmi3Status fmi3SetBoolean(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Boolean values[], size_t nValues) {
    GlueInstance *g = lookup(instance, "fmi3SetBoolean");
    fmi2Boolean *tmp;
    fmi2Status s;
    size_t i;
    if (!g || !allowed(g, "fmi3SetBoolean", MASK_SET)) return fmi3Error;
    if (!check_refs(g, "fmi3SetBoolean", GLUE_BOOLEAN, "a Boolean", valueReferences,
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
    return settle(g, s);
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
    GlueInstance *g = lookup(instance, "fmi3DoStep");
    fmi2Status s;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!g || !allowed(g, "fmi3DoStep", MASK_DO_STEP)) return fmi3Error;
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
    return settle(g, s);
}

/* ------------------------------------------------------- what this FMU does not provide */

static fmi3Status not_supported(fmi3Instance instance, const char *function, const char *why) {
    GlueInstance *g = lookup(instance, function);
    if (!g) return fmi3Error;
    LOG_ERROR(g, "%s: not supported by %s (%s)", function,
              g->model_name ? g->model_name : "this FMU", why);
    return fmi3Error;
}

#define NO_EVENT_MODE "a co-simulation FMU without event mode (hasEventMode = false)"
#define NO_ME "co-simulation only, no model exchange"
#define NO_SE "co-simulation only, no scheduled execution"
#define NO_STATE "canGetAndSetFMUState = false"
#define NO_SERIAL "canSerializeFMUState = false"
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

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)FMUState;
    return not_supported(instance, "fmi3GetFMUState", NO_STATE);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    (void)FMUState;
    return not_supported(instance, "fmi3SetFMUState", NO_STATE);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    (void)FMUState;
    return not_supported(instance, "fmi3FreeFMUState", NO_STATE);
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    (void)FMUState;
    (void)size;
    return not_supported(instance, "fmi3SerializedFMUStateSize", NO_SERIAL);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    (void)FMUState;
    (void)serializedState;
    (void)size;
    return not_supported(instance, "fmi3SerializeFMUState", NO_SERIAL);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    (void)serializedState;
    (void)size;
    (void)FMUState;
    return not_supported(instance, "fmi3DeserializeFMUState", NO_SERIAL);
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
