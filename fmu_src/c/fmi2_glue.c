/* fmi2_glue.c -- FMI 2.0 co-simulation entry points: registry, state machine, checks, logging.
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

#include <math.h>
#include <pthread.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"

/* ------------------------------------------------------------------------------- registry */

/* Live instances of this library. Looked up by pointer value only, so a stale or garbage
   pointer is recognised without being read. A handful of instances: a linear scan is enough. */
static pthread_mutex_t registry_lock = PTHREAD_MUTEX_INITIALIZER;
static GlueInstance **registry;
static size_t registry_count, registry_capacity;

static int registry_add(GlueInstance *g) {
    int ok = 1;
    pthread_mutex_lock(&registry_lock);
    if (registry_count == registry_capacity) {
        size_t cap = registry_capacity ? 2 * registry_capacity : 8;
        GlueInstance **grown = realloc(registry, cap * sizeof *grown);
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

/* Find `c` among the live instances; with `remove`, take it out (fmi2FreeInstance). */
static GlueInstance *registry_find(const void *c, int remove) {
    GlueInstance *found = NULL;
    size_t i;
    if (!c) return NULL;
    pthread_mutex_lock(&registry_lock);
    for (i = 0; i < registry_count; i++) {
        if ((const void *)registry[i] == c) {
            found = registry[i];
            if (remove) {
                registry[i] = registry[--registry_count];
                if (registry_count == 0) {   /* nothing left behind if the host unloads us */
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

/* No instance to log through: stderr is the only place left to say why the call failed. */
static GlueInstance *lookup(fmi2Component c, const char *function) {
    GlueInstance *g = registry_find(c, 0);
    if (!g)
        fprintf(stderr, "[fmi2] %s: component %p is not a live instance of this FMU "
                        "(NULL, already freed, or never created); returning fmi2Error\n",
                function, c);
    return g;
}

/* ------------------------------------------------------------------------------ logging */

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
    if (status >= fmi2Warning) return 1;          /* warnings and errors always reach the host */
    if (!g->logging_on) return 0;
    if (g->n_categories == 0) return 1;
    for (i = 0; i < g->n_categories; i++)
        if (strcmp(g->categories[i], "logAll") == 0 ||
            (category && strcmp(g->categories[i], category) == 0))
            return 1;
    return 0;
}

void glue_log_text(GlueInstance *g, fmi2Status status, const char *category, const char *message) {
    if (!category) category = glue_status_category(status);
    if (!glue_log_wanted(g, status, category)) return;
    /* The logger is printf-like, but some hosts (fmpy's Python logger among them) print the
     * format without applying it, and a "%s" format then shows as "%s": pass the text itself as
     * the format, each '%' doubled, and no arguments. A printf-like host prints the text; one
     * that prints the format shows "%%" for a literal '%' (the harness undoes that). */
    const char *text = message ? message : "", *p;
    size_t percents = 0, len = 0;
    for (p = text; *p; p++, len++) percents += *p == '%';
    char *escaped = NULL;
    if (percents) {
        escaped = malloc(len + percents + 1);          /* rare: a message with a '%' */
        if (!escaped) return;
        char *q = escaped;
        for (p = text; *p; p++) {
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
    if (n >= (int)sizeof small) {                 /* long message: one allocation, then freed */
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
    case GLUE_STEP_COMPLETE: return "step complete";
    case GLUE_TERMINATED: return "terminated";
    case GLUE_ERROR: return "error";
    case GLUE_FATAL: return "fatal";
    }
    return "?";
}

static const char *type_phrase(GlueType t) {
    return t == GLUE_INTEGER ? "an Integer" : t == GLUE_REAL ? "a Real"
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

/* "allowed in: instantiated, initialization mode" for a state mask */
static void describe_mask(int mask, char *out, size_t size) {
    static const GlueState all[] = {GLUE_INSTANTIATED, GLUE_INIT_MODE, GLUE_STEP_COMPLETE,
                                    GLUE_TERMINATED, GLUE_ERROR};
    size_t i, used = 0;
    out[0] = '\0';
    for (i = 0; i < sizeof all / sizeof all[0]; i++) {
        if (!(mask & (int)all[i])) continue;
        int n = snprintf(out + used, size - used, "%s%s", used ? ", " : "", state_name(all[i]));
        if (n < 0 || (size_t)n >= size - used) break;
        used += (size_t)n;
    }
}

/* Is `function` allowed in the instance's state? If not, say so (the state does not change). */
static int allowed(GlueInstance *g, const char *function, int mask) {
    char where[128];
    if ((int)g->state & mask) return 1;
    describe_mask(mask, where, sizeof where);
    LOG_ERROR(g, "%s: not allowed in state '%s' (allowed in: %s)", function, state_name(g->state),
              where);
    return 0;
}

/* The model's answer decides the state: a failing model is in the error state from now on. */
static fmi2Status settle(GlueInstance *g, fmi2Status s) {
    if (s == fmi2Fatal) g->state = GLUE_FATAL;
    else if (s == fmi2Error) g->state = GLUE_ERROR;
    return s;
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

static int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

/* fmuResourceLocation (a file: URI; a plain absolute path is accepted too) -> a path, no
   trailing slash. NULL if it is not a local file location. */
static char *resource_path(const char *uri) {
    const char *p = uri;
    char *out, *q;
    size_t n;
    if (!uri) return NULL;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0) p += 9;
        if (*p != '/') return NULL;               /* file://host/... : not on this machine */
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    }
    if (*p != '/') return NULL;
    out = malloc(strlen(p) + 1);
    if (!out) return NULL;
    for (q = out; *p; p++) {
        int hi, lo;
        if (*p == '%' && (hi = hex_value(p[1])) >= 0 && (lo = hex_value(p[2])) >= 0) {
            *q++ = (char)(hi * 16 + lo);
            p += 2;
        } else {
            *q++ = *p;
        }
    }
    *q = '\0';
    n = strlen(out);
    while (n > 1 && out[n - 1] == '/') out[--n] = '\0';
    return out;
}

/* The GUID in <resources>/../modelDescription.xml. 1: equal, 0: differs (logged), -1: could not
   be read (not an error: a host may extract only what it needs). */
static int check_guid(GlueInstance *g, const char *guid) {
    char head[8192], *root, *attr, *end, *path;
    size_t n, len = strlen(g->resources);
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
    attr = strstr(root, " guid=\"");
    if (!attr || (end && attr > end)) return -1;
    attr += 7;
    end = strchr(attr, '"');
    if (!end) return -1;
    if ((size_t)(end - attr) == strlen(guid) && strncmp(attr, guid, (size_t)(end - attr)) == 0)
        return 1;
    *end = '\0';
    LOG_ERROR(g, "fmi2Instantiate: fmuGUID '%s' is not the GUID of this FMU's "
                 "modelDescription.xml ('%s')", guid, attr);
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

static void free_instance(GlueInstance *g) {
    size_t i;
    for (i = 0; i < g->n_vars; i++) free(g->vars[i].name);
    free(g->vars);
    free_strings(g->categories, g->n_categories);
    free_strings(g->known_categories, g->n_known_categories);
    free(g->strings);
    free(g->instance_name);
    free(g->model_name);
    free(g->resources);
    free(g);
}

/* ------------------------------------------------------------------ common FMI 2.0 functions */

/* States in which each call is allowed (FMI 2.0 section 4.2.4). Deviations, on purpose:
   - fmi2Terminate is also accepted in the error state (hosts clean up with terminate + free);
   - a discarded step leaves the instance in step complete, not step failed: our slaves change
     nothing when they discard, so the host may retry or go on (README); fmi2Terminated says
     the slave would rather stop, for masters that cannot. */
#define ANY_STATE (GLUE_INSTANTIATED | GLUE_INIT_MODE | GLUE_STEP_COMPLETE | GLUE_TERMINATED | GLUE_ERROR)
#define MASK_SETUP GLUE_INSTANTIATED
#define MASK_ENTER_INIT GLUE_INSTANTIATED
#define MASK_EXIT_INIT GLUE_INIT_MODE
#define MASK_DO_STEP GLUE_STEP_COMPLETE
#define MASK_TERMINATE (GLUE_STEP_COMPLETE | GLUE_ERROR)
#define MASK_RESET ANY_STATE
#define MASK_GET (GLUE_INIT_MODE | GLUE_STEP_COMPLETE | GLUE_TERMINATED | GLUE_ERROR)
#define MASK_SET (GLUE_INSTANTIATED | GLUE_INIT_MODE | GLUE_STEP_COMPLETE)
#define MASK_STATUS (GLUE_STEP_COMPLETE | GLUE_TERMINATED)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    GlueInstance *g = calloc(1, sizeof *g);
    if (!g) return NULL;
    if (functions) {               /* copied: the host's struct need not outlive this call */
        g->logger = functions->logger;
        g->env = functions->componentEnvironment;
    }
    g->logging_on = loggingOn != fmi2False;
    g->visible = visible != fmi2False;
    g->state = GLUE_INSTANTIATED;
    g->instance_name = copy_string(instanceName ? instanceName : "");
    if (!g->instance_name) goto fail;
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
    g->resources = resource_path(fmuResourceLocation);
    if (!g->resources) {
        LOG_ERROR(g, "fmi2Instantiate: fmuResourceLocation '%s' is not a file: URI of a local "
                     "folder", fmuResourceLocation ? fmuResourceLocation : "(NULL)");
        goto fail;
    }
    if (check_guid(g, fmuGUID) == 0) goto fail;
    if (model_instantiate(g) != fmi2OK) {
        model_free(g);
        goto fail;
    }
    if (!registry_add(g)) {
        LOG_ERROR(g, "fmi2Instantiate: out of memory");
        model_free(g);
        goto fail;
    }
    return g;
fail:
    free_instance(g);
    return NULL;
}

void fmi2FreeInstance(fmi2Component c) {
    GlueInstance *g = registry_find(c, 1);   /* out of the registry first: a second free is a no-op */
    if (!g) {
        if (c)
            fprintf(stderr, "[fmi2] fmi2FreeInstance: component %p is not a live instance of "
                            "this FMU (already freed?); nothing done\n", c);
        return;
    }
    model_free(g);
    free_instance(g);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    GlueInstance *g = lookup(c, "fmi2SetDebugLogging");
    char **copy = NULL;
    size_t i, k;
    if (!g) return fmi2Error;
    if (nCategories > 0 && !categories) {
        LOG_ERROR(g, "fmi2SetDebugLogging: categories[] is NULL but nCategories = %zu",
                  nCategories);
        return fmi2Error;
    }
    for (i = 0; i < nCategories; i++) {      /* check all before changing anything */
        int known = g->n_known_categories == 0;
        if (!categories[i]) {
            LOG_ERROR(g, "fmi2SetDebugLogging: categories[%zu] is NULL", i);
            return fmi2Error;
        }
        for (k = 0; k < g->n_known_categories && !known; k++)
            known = strcmp(categories[i], g->known_categories[k]) == 0;
        if (!known) {
            LOG_ERROR(g, "fmi2SetDebugLogging: '%s' is not a log category of %s", categories[i],
                      g->model_name ? g->model_name : "this FMU");
            return fmi2Error;
        }
    }
    if (loggingOn && nCategories > 0) {
        copy = calloc(nCategories, sizeof *copy);
        for (i = 0; copy && i < nCategories; i++)
            if (!(copy[i] = copy_string(categories[i]))) {
                free_strings(copy, i);
                copy = NULL;
            }
        if (!copy) {
            LOG_ERROR(g, "fmi2SetDebugLogging: out of memory");
            return fmi2Error;
        }
    }
    free_strings(g->categories, g->n_categories);
    g->categories = copy;
    g->n_categories = copy ? nCategories : 0;
    g->logging_on = loggingOn != fmi2False;   /* off: every debug category off */
    return fmi2OK;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    GlueInstance *g = lookup(c, "fmi2SetupExperiment");
    fmi2Status s;
    if (!g || !allowed(g, "fmi2SetupExperiment", MASK_SETUP)) return fmi2Error;
    if (!isfinite(startTime)) {
        LOG_ERROR(g, "fmi2SetupExperiment: startTime = %g is not finite", startTime);
        return fmi2Error;
    }
    if (stopTimeDefined && !(stopTime >= startTime)) {
        LOG_ERROR(g, "fmi2SetupExperiment: stopTime = %g is before startTime = %g", stopTime,
                  startTime);
        return fmi2Error;
    }
    s = model_setup_experiment(g, toleranceDefined != fmi2False, tolerance, startTime,
                               stopTimeDefined != fmi2False, stopTime);
    if (s == fmi2OK) g->time = startTime;
    return settle(g, s);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    GlueInstance *g = lookup(c, "fmi2EnterInitializationMode");
    fmi2Status s;
    if (!g || !allowed(g, "fmi2EnterInitializationMode", MASK_ENTER_INIT)) return fmi2Error;
    s = model_enter_initialization_mode(g);
    if (s == fmi2OK) g->state = GLUE_INIT_MODE;
    return settle(g, s);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    GlueInstance *g = lookup(c, "fmi2ExitInitializationMode");
    fmi2Status s;
    if (!g || !allowed(g, "fmi2ExitInitializationMode", MASK_EXIT_INIT)) return fmi2Error;
    s = model_exit_initialization_mode(g);
    if (s == fmi2OK) g->state = GLUE_STEP_COMPLETE;
    return settle(g, s);
}

fmi2Status fmi2Terminate(fmi2Component c) {
    GlueInstance *g = lookup(c, "fmi2Terminate");
    fmi2Status s;
    if (!g || !allowed(g, "fmi2Terminate", MASK_TERMINATE)) return fmi2Error;
    if (g->state == GLUE_ERROR) {     /* the model failed: nothing to wind down, only to free */
        glue_log(g, fmi2OK, "logAll", "fmi2Terminate: after an error; the model is not called");
        g->state = GLUE_TERMINATED;
        return fmi2OK;
    }
    s = model_terminate(g);
    if (s == fmi2OK) g->state = GLUE_TERMINATED;
    return settle(g, s);
}

fmi2Status fmi2Reset(fmi2Component c) {
    GlueInstance *g = lookup(c, "fmi2Reset");
    fmi2Status s;
    if (!g || !allowed(g, "fmi2Reset", MASK_RESET)) return fmi2Error;
    s = model_reset(g);
    if (s == fmi2OK) {
        g->state = GLUE_INSTANTIATED;
        g->time = 0.0;
        g->terminate_requested = 0;
    }
    return settle(g, s);
}

/* ------------------------------------------------------------------- getting and setting */

/* Check a whole get/set call before the model sees any of it. */
static int check_refs(GlueInstance *g, const char *function, GlueType type,
                      const fmi2ValueReference vr[], size_t nvr, const void *values, int setting) {
    size_t i;
    const char *model = g->model_name ? g->model_name : "this FMU";
    if (nvr == 0) return 1;
    if (!vr) {
        LOG_ERROR(g, "%s: vr[] is NULL but nvr = %zu", function, nvr);
        return 0;
    }
    if (!values) {
        LOG_ERROR(g, "%s: value[] is NULL but nvr = %zu", function, nvr);
        return 0;
    }
    for (i = 0; i < nvr; i++) {
        const GlueVar *v;
        unsigned r = (unsigned)vr[i];
        if (r >= g->n_vars || !g->vars[r].name) {
            LOG_ERROR(g, "%s: value reference %u (vr[%zu]) is not a variable of %s", function, r,
                      i, model);
            return 0;
        }
        v = &g->vars[r];
        if (v->type != type) {
            LOG_ERROR(g, "%s: value reference %u (vr[%zu]) is '%s', %s variable, not %s",
                      function, r, i, v->name, type_phrase(v->type), type_phrase(type));
            return 0;
        }
        if (!setting) continue;
        if (v->causality != GLUE_PARAMETER && v->causality != GLUE_INPUT) {
            LOG_ERROR(g, "%s: '%s' (value reference %u) is %s and cannot be set", function,
                      v->name, r, causality_phrase(v->causality));
            return 0;
        }
        if (v->variability == GLUE_CONSTANT || !v->settable) {
            LOG_ERROR(g, "%s: '%s' (value reference %u) is %s that cannot be set (%s)", function,
                      v->name, r, causality_phrase(v->causality),
                      v->variability == GLUE_CONSTANT ? "a constant" : "no setter");
            return 0;
        }
        if (g->state == GLUE_STEP_COMPLETE && v->causality == GLUE_PARAMETER &&
            v->variability != GLUE_TUNABLE) {
            LOG_ERROR(g, "%s: '%s' (value reference %u) is a parameter of variability %s: it can "
                         "be set only before fmi2ExitInitializationMode, not in state '%s' "
                         "(fmi2Reset, then set it and initialise again)",
                      function, v->name, r, variability_name(v->variability),
                      state_name(g->state));
            return 0;
        }
        if (type == GLUE_STRING) {
            const char *s = ((const fmi2String *)values)[i];
            if (!s) {
                LOG_ERROR(g, "%s: value[%zu] for '%s' (value reference %u) is NULL", function, i,
                          v->name, r);
                return 0;
            }
            if (!utf8_valid(s)) {
                LOG_ERROR(g, "%s: value[%zu] for '%s' (value reference %u) is not valid UTF-8",
                          function, i, v->name, r);
                return 0;
            }
        }
    }
    return 1;
}

static fmi2Status get_values(fmi2Component c, const char *function, GlueType type,
                             const fmi2ValueReference vr[], size_t nvr, void *values) {
    GlueInstance *g = lookup(c, function);
    if (!g || !allowed(g, function, MASK_GET)) return fmi2Error;
    if (!check_refs(g, function, type, vr, nvr, values, 0)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    return settle(g, model_get(g, type, vr, nvr, values));
}

static fmi2Status set_values(fmi2Component c, const char *function, GlueType type,
                             const fmi2ValueReference vr[], size_t nvr, const void *values) {
    GlueInstance *g = lookup(c, function);
    if (!g || !allowed(g, function, MASK_SET)) return fmi2Error;
    if (!check_refs(g, function, type, vr, nvr, values, 1)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    return settle(g, model_set(g, type, vr, nvr, values));
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

/* modelDescription.xml: canGetAndSetFMUstate, canSerializeFMUstate, providesDirectional-
   Derivative and canInterpolateInputs are false, maxOutputDerivativeOrder is 0. */
static fmi2Status not_supported(fmi2Component c, const char *function, const char *why) {
    GlueInstance *g = lookup(c, function);
    if (!g) return fmi2Error;
    LOG_ERROR(g, "%s: not supported by %s (%s)", function,
              g->model_name ? g->model_name : "this FMU", why);
    return fmi2Error;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return not_supported(c, "fmi2GetFMUstate", "canGetAndSetFMUstate = false");
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    (void)FMUstate;
    return not_supported(c, "fmi2SetFMUstate", "canGetAndSetFMUstate = false");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    (void)FMUstate;
    return not_supported(c, "fmi2FreeFMUstate", "canGetAndSetFMUstate = false");
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    (void)size;
    return not_supported(c, "fmi2SerializedFMUstateSize", "canSerializeFMUstate = false");
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    (void)FMUstate;
    (void)serializedState;
    (void)size;
    return not_supported(c, "fmi2SerializeFMUstate", "canSerializeFMUstate = false");
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    (void)serializedState;
    (void)size;
    (void)FMUstate;
    return not_supported(c, "fmi2DeSerializeFMUstate", "canSerializeFMUstate = false");
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

/* -------------------------------------------------------------------------- stepping */

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    GlueInstance *g = lookup(c, "fmi2DoStep");
    fmi2Status s;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!g || !allowed(g, "fmi2DoStep", MASK_DO_STEP)) return fmi2Error;
    /* the model judges time and step size itself (a bad one is a discarded step, logged) */
    s = model_do_step(g, currentCommunicationPoint, communicationStepSize);
    if (s == fmi2OK) g->time = currentCommunicationPoint + communicationStepSize;
    /* After a discarded step the slave asks to end the simulation (fmi2Terminated), as pythonfmu
       did: a master that cannot retry stops at fmi2LastSuccessfulTime instead of repeating the
       step forever (fmpy's simulate_fmu). A master that retries or goes on may: nothing changed. */
    if (s == fmi2OK || s == fmi2Discard) g->terminate_requested = s == fmi2Discard;
    return settle(g, s);
}

/* Status queries. doStep is synchronous: there is never a pending step to ask about. */
static GlueInstance *status_call(fmi2Component c, const char *function, const void *value) {
    GlueInstance *g = lookup(c, function);
    if (!g || !allowed(g, function, MASK_STATUS)) return NULL;
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
