/* glue_common.c -- the part of the FMI 2.0 and FMI 3.0 glues that no standard owns (see
 * glue_common.h): registry, state rules, value-reference checks, logging, resource locations,
 * FMU states (get/set/free, serialize/deserialize: header, checks, checksum).
 * Compile these sources with -ffp-contract=off (GCC ignores #pragma STDC FP_CONTRACT): the model
 * core is bit-identical to the Python reference only without fused multiply-adds (its own .c
 * files also turn contraction off, models/core/rc_fp_contract.h).
 * Portable to Windows (mingw-w64, MSVC): no thread library there (see the lock below), and
 * size_t is printed as %llu of a cast, because msvcrt's printf has no %zu.
 */
#define _POSIX_C_SOURCE 200809L

#include <math.h>
#include <stdarg.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "glue_common.h"

#include <sys/stat.h>
#ifdef _MSC_VER
#include <direct.h>
#define getcwd _getcwd
#define S_ISREG(mode) (((mode) & _S_IFMT) == _S_IFREG)
#else
#include <unistd.h>
#endif

/* The registry's lock: a slim reader/writer lock on Windows (kernel32 since Vista, statically
   initialised, no thread library to ship), a POSIX mutex elsewhere. */
#ifdef _WIN32
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
static SRWLOCK registry_lock = SRWLOCK_INIT;
#define REGISTRY_LOCK() AcquireSRWLockExclusive(&registry_lock)
#define REGISTRY_UNLOCK() ReleaseSRWLockExclusive(&registry_lock)
#else
#include <pthread.h>
static pthread_mutex_t registry_lock = PTHREAD_MUTEX_INITIALIZER;
#define REGISTRY_LOCK() pthread_mutex_lock(&registry_lock)
#define REGISTRY_UNLOCK() pthread_mutex_unlock(&registry_lock)
#endif

#define LOG_ERROR(g, ...) glue_log((g), GLUE_STATUS_ERROR, "logStatusError", __VA_ARGS__)

/* ------------------------------------------------------------------------------- registry */

/* Live instances of this library. Looked up by pointer value only, so a stale or garbage
   pointer is recognised without being read. A handful of instances: a linear scan is enough. */
static GlueInstance **registry;
static size_t registry_count, registry_capacity;

int gc_register(GlueInstance *g) {
    int ok = 1;
    REGISTRY_LOCK();
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
    REGISTRY_UNLOCK();
    return ok;
}

/* Find `handle` among the live instances; with `remove`, take it out (freeInstance). */
static GlueInstance *registry_find(const void *handle, int remove) {
    GlueInstance *found = NULL;
    size_t i;
    if (!handle) return NULL;
    REGISTRY_LOCK();
    for (i = 0; i < registry_count; i++) {
        if ((const void *)registry[i] == handle) {
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
    REGISTRY_UNLOCK();
    return found;
}

GlueInstance *gc_unregister(const void *handle) {
    return registry_find(handle, 1);
}

/* No instance to log through: stderr is the only place left to say why the call failed. */
GlueInstance *gc_lookup(const GlueStandard *standard, const void *handle, const char *function) {
    GlueInstance *g = registry_find(handle, 0);
    if (!g)
        fprintf(stderr, "[%s] %s: %s %p is not a live instance of this FMU "
                        "(NULL, already freed, or never created); returning %sError\n",
                standard->prefix, function, standard->handle, handle, standard->prefix);
    return g;
}

/* The live FMU states of this library, as the instances above: a state pointer is recognised by
   its value alone. A state belongs to the instance that made it (freed with it). */
typedef struct {
    GlueInstance *owner;
    unsigned char *bytes;       /* the serialized state (gc_get_state's format below) */
    size_t size;
} GlueFMUState;

static GlueFMUState **live_states;
static size_t live_states_count, live_states_capacity;

static int state_register(GlueFMUState *st) {
    int ok = 1;
    REGISTRY_LOCK();
    if (live_states_count == live_states_capacity) {
        size_t cap = live_states_capacity ? 2 * live_states_capacity : 8;
        GlueFMUState **grown = realloc(live_states, cap * sizeof *grown);
        if (grown) {
            live_states = grown;
            live_states_capacity = cap;
        } else {
            ok = 0;
        }
    }
    if (ok) live_states[live_states_count++] = st;
    REGISTRY_UNLOCK();
    return ok;
}

static void drop_live_state(size_t i) {           /* with the lock held */
    live_states[i] = live_states[--live_states_count];
    if (live_states_count == 0) {
        free(live_states);
        live_states = NULL;
        live_states_capacity = 0;
    }
}

/* `handle` among the live states (NULL if not); with `remove`, taken out */
static GlueFMUState *state_find(const void *handle, int remove) {
    GlueFMUState *found = NULL;
    size_t i;
    if (!handle) return NULL;
    REGISTRY_LOCK();
    for (i = 0; i < live_states_count; i++) {
        if ((const void *)live_states[i] == handle) {
            found = live_states[i];
            if (remove) drop_live_state(i);
            break;
        }
    }
    REGISTRY_UNLOCK();
    return found;
}

static void free_states_of(GlueInstance *g) {
    size_t i = 0;
    REGISTRY_LOCK();
    while (i < live_states_count) {
        GlueFMUState *st = live_states[i];
        if (st->owner == g) {
            drop_live_state(i);
            free(st->bytes);
            free(st);
        } else {
            i++;
        }
    }
    REGISTRY_UNLOCK();
}

/* ------------------------------------------------------------------------------ logging */

const char *glue_status_category(int status) {
    switch (status) {
    case GLUE_STATUS_WARNING: return "logStatusWarning";
    case GLUE_STATUS_DISCARD: return "logStatusDiscard";
    case GLUE_STATUS_ERROR: return "logStatusError";
    case GLUE_STATUS_FATAL: return "logStatusFatal";
    default: return "logAll";
    }
}

int glue_log_wanted(const GlueInstance *g, int status, const char *category) {
    size_t i;
    if (!g || !g->log_sink) return 0;
    if (status >= GLUE_STATUS_WARNING) return 1;  /* warnings and errors always reach the host */
    if (!g->logging_on) return 0;
    if (g->n_categories == 0) return 1;
    for (i = 0; i < g->n_categories; i++)
        if (strcmp(g->categories[i], "logAll") == 0 ||
            (category && strcmp(g->categories[i], category) == 0))
            return 1;
    return 0;
}

void glue_log_text(GlueInstance *g, int status, const char *category, const char *message) {
    if (!category) category = glue_status_category(status);
    if (!glue_log_wanted(g, status, category)) return;
    g->log_sink(g, status, category, message ? message : "");
}

void glue_log(GlueInstance *g, int status, const char *category, const char *fmt, ...) {
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

/* ----------------------------------------------------------------- services to the backend */

char *gc_copy_string(const char *s) {
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

int glue_alloc_vars(GlueInstance *g, size_t n) {
    g->vars = calloc(n ? n : 1, sizeof *g->vars);
    g->n_vars = g->vars ? n : 0;
    return g->vars != NULL;
}

int glue_set_model_name(GlueInstance *g, const char *name) {
    char *copy = gc_copy_string(name);
    if (!copy) return 0;
    free(g->model_name);
    g->model_name = copy;
    return 1;
}

int glue_add_category(GlueInstance *g, const char *name) {
    char **grown = realloc(g->known_categories, (g->n_known_categories + 1) * sizeof *grown);
    if (!grown) return 0;
    g->known_categories = grown;
    if (!(grown[g->n_known_categories] = gc_copy_string(name))) return 0;
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

/* ------------------------------------------------------------------------------ instances */

int gc_init_instance(GlueInstance *g, const GlueStandard *standard, GlueLogSink sink,
                     const char *instance_name, int logging_on, int visible) {
    g->standard = standard;
    g->log_sink = sink;
    g->logging_on = logging_on;
    g->visible = visible;
    g->state = GLUE_INSTANTIATED;
    g->instance_name = gc_copy_string(instance_name);
    return g->instance_name != NULL;
}

void gc_free_instance(GlueInstance *g) {
    size_t i;
    for (i = 0; i < g->n_vars; i++) free(g->vars[i].name);
    free(g->vars);
    free_strings(g->categories, g->n_categories);
    free_strings(g->known_categories, g->n_known_categories);
    free(g->strings);
    free(g->instance_name);
    free(g->model_name);
    free(g->resources);
    free(g->token);
    free_states_of(g);
    free(g);
}

/* --------------------------------------------------------------------------- the states */

static const char *state_name(const GlueInstance *g, GlueState s) {
    switch (s) {
    case GLUE_INSTANTIATED: return "instantiated";
    case GLUE_INIT_MODE: return "initialization mode";
    case GLUE_STEP_COMPLETE: return g->standard->step_state;
    case GLUE_TERMINATED: return "terminated";
    case GLUE_ERROR: return "error";
    case GLUE_FATAL: return "fatal";
    }
    return "?";
}

/* "instantiated, initialization mode" for a state mask */
static void describe_mask(const GlueInstance *g, int mask, char *out, size_t size) {
    static const GlueState all[] = {GLUE_INSTANTIATED, GLUE_INIT_MODE, GLUE_STEP_COMPLETE,
                                    GLUE_TERMINATED, GLUE_ERROR};
    size_t i, used = 0;
    out[0] = '\0';
    for (i = 0; i < sizeof all / sizeof all[0]; i++) {
        int n;
        if (!(mask & (int)all[i])) continue;
        n = snprintf(out + used, size - used, "%s%s", used ? ", " : "", state_name(g, all[i]));
        if (n < 0 || (size_t)n >= size - used) break;
        used += (size_t)n;
    }
}

GlueInstance *gc_enter(const GlueStandard *standard, const void *handle, const char *function,
                       int mask) {
    char where[128];
    GlueInstance *g = gc_lookup(standard, handle, function);
    if (!g || ((int)g->state & mask)) return g;
    describe_mask(g, mask, where, sizeof where);
    LOG_ERROR(g, "%s: not allowed in state '%s' (allowed in: %s)", function,
              state_name(g, g->state), where);
    return NULL;
}

void gc_not_supported(const GlueStandard *standard, const void *handle, const char *function,
                      const char *why) {
    GlueInstance *g = gc_lookup(standard, handle, function);
    if (g)
        LOG_ERROR(g, "%s: not supported by %s (%s)", function,
                  g->model_name ? g->model_name : "this FMU", why);
}

int gc_settle(GlueInstance *g, int status) {
    if (status == GLUE_STATUS_FATAL) g->state = GLUE_FATAL;
    else if (status == GLUE_STATUS_ERROR) g->state = GLUE_ERROR;
    return status;
}

int gc_finish(GlueInstance *g, int status, GlueState next) {
    if (status == GLUE_STATUS_OK) g->state = next;
    return gc_settle(g, status);
}

int gc_finish_reset(GlueInstance *g, int status) {
    if (status == GLUE_STATUS_OK) {
        g->state = GLUE_INSTANTIATED;
        g->time = 0.0;
        g->terminate_requested = 0;
    }
    return gc_settle(g, status);
}

int gc_terminate_after_error(GlueInstance *g, const char *function) {
    if (g->state != GLUE_ERROR) return 0;
    glue_log(g, GLUE_STATUS_OK, "logAll", "%s: after an error; the model is not called", function);
    g->state = GLUE_TERMINATED;
    return 1;
}

int gc_check_times(GlueInstance *g, const char *function, double start_time,
                   int stop_time_defined, double stop_time) {
    if (!isfinite(start_time)) {
        LOG_ERROR(g, "%s: startTime = %g is not finite", function, start_time);
        return 0;
    }
    if (stop_time_defined && !(stop_time >= start_time)) {
        LOG_ERROR(g, "%s: stopTime = %g is before startTime = %g", function, stop_time,
                  start_time);
        return 0;
    }
    return 1;
}

int gc_set_debug_logging(GlueInstance *g, const char *function, int logging_on, size_t n,
                         const char *const categories[], const char *owner) {
    char **copy = NULL;
    size_t i, k;
    if (n > 0 && !categories) {
        LOG_ERROR(g, "%s: categories[] is NULL but nCategories = %llu", function,
                  (unsigned long long)n);
        return 0;
    }
    for (i = 0; i < n; i++) {                /* check all before changing anything */
        int known = g->n_known_categories == 0;
        if (!categories[i]) {
            LOG_ERROR(g, "%s: categories[%llu] is NULL", function, (unsigned long long)i);
            return 0;
        }
        for (k = 0; k < g->n_known_categories && !known; k++)
            known = strcmp(categories[i], g->known_categories[k]) == 0;
        if (!known) {
            LOG_ERROR(g, "%s: '%s' is not a log category of %s", function, categories[i], owner);
            return 0;
        }
    }
    if (logging_on && n > 0) {            /* logging off: the categories do not matter */
        copy = calloc(n, sizeof *copy);
        for (i = 0; copy && i < n; i++)
            if (!(copy[i] = gc_copy_string(categories[i]))) {
                free_strings(copy, i);
                copy = NULL;
            }
        if (!copy) {
            LOG_ERROR(g, "%s: out of memory", function);
            return 0;
        }
    }
    free_strings(g->categories, g->n_categories);
    g->categories = copy;
    g->n_categories = copy ? n : 0;
    g->logging_on = logging_on;             /* off: every debug category off */
    return 1;
}

/* ------------------------------------------------------------------- getting and setting */

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

/* With GlueStandard.time_variable: "time", value reference n_vars (the first one after the
   backend's table; fmu_src/build/model_description.py writes the same), read-only. The backend never sees
   it; the glue gives its value (the instance's time). */
static char time_name[] = "time";
static const GlueVar time_var = {time_name, GLUE_REAL, GLUE_INDEPENDENT, GLUE_CONTINUOUS, 0};

/* The settable checks of one variable (vr r, index i of the call): 0 logged. */
static int check_settable(GlueInstance *g, const char *function, const GlueVar *v,
                          unsigned long r, size_t i, int type, const void *values) {
    const GlueStandard *std = g->standard;
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
        LOG_ERROR(g, "%s: '%s' (value reference %lu) is a parameter of variability %s: it can "
                     "be set only before %sExitInitializationMode, not in state '%s' "
                     "(%sReset, then set it and initialise again)",
                  function, v->name, r, variability_name(v->variability), std->prefix,
                  state_name(g, g->state), std->prefix);
        return 0;
    }
    if (type == GLUE_STRING) {
        const char *s = ((const char *const *)values)[i];
        if (!s) {
            LOG_ERROR(g, "%s: %s[%llu] for '%s' (value reference %lu) is NULL", function,
                      std->values_array, (unsigned long long)i, v->name, r);
            return 0;
        }
        if (!utf8_valid(s)) {
            LOG_ERROR(g, "%s: %s[%llu] for '%s' (value reference %lu) is not valid UTF-8",
                      function, std->values_array, (unsigned long long)i, v->name, r);
            return 0;
        }
    }
    return 1;
}

int gc_check_refs(GlueInstance *g, const char *function, int type, const char *type_name,
                  const unsigned int vr[], size_t nvr, const void *values, size_t nvalues,
                  int setting) {
    const GlueStandard *std = g->standard;
    const char *model = g->model_name ? g->model_name : "this FMU";
    size_t i;
    if (!type_name) type_name = type >= 0 && type < 4 ? std->type_phrase[type] : "?";
    if (nvalues != nvr) {
        LOG_ERROR(g, "%s: nValues = %llu but nValueReferences = %llu (all variables of %s are "
                     "scalars)", function, (unsigned long long)nvalues, (unsigned long long)nvr,
                  model);
        return 0;
    }
    if (nvr == 0) return 1;
    if (!vr) {
        LOG_ERROR(g, "%s: %s[] is NULL but %s = %llu", function, std->vr_array, std->vr_count,
                  (unsigned long long)nvr);
        return 0;
    }
    if (!values) {
        LOG_ERROR(g, "%s: %s[] is NULL but %s = %llu", function, std->values_array,
                  std->values_count, (unsigned long long)nvr);
        return 0;
    }
    for (i = 0; i < nvr; i++) {
        const GlueVar *v;
        unsigned long r = (unsigned long)vr[i];
        if (std->time_variable && r == g->n_vars) {
            v = &time_var;
        } else if (r >= g->n_vars || !g->vars[r].name) {
            LOG_ERROR(g, "%s: value reference %lu (%s[%llu]) is not a variable of %s", function,
                      r, std->vr_array, (unsigned long long)i, model);
            return 0;
        } else {
            v = &g->vars[r];
        }
        if ((int)v->type != type) {
            LOG_ERROR(g, "%s: value reference %lu (%s[%llu]) is '%s', %s variable, not %s",
                      function, r, std->vr_array, (unsigned long long)i, v->name, std->type_phrase[v->type],
                      type_name);
            return 0;
        }
        if (setting && !check_settable(g, function, v, r, i, type, values)) return 0;
    }
    return 1;
}

/* ------------------------------------------------------------------- the FMU's files */

static int hex_value(char c) {
    if (c >= '0' && c <= '9') return c - '0';
    if (c >= 'a' && c <= 'f') return c - 'a' + 10;
    if (c >= 'A' && c <= 'F') return c - 'A' + 10;
    return -1;
}

int gc_is_drive_path(const char *p) {
    return ((p[0] >= 'A' && p[0] <= 'Z') || (p[0] >= 'a' && p[0] <= 'z')) && p[1] == ':' &&
           (p[2] == '/' || p[2] == '\\');
}

int gc_is_absolute_path(const char *p) {
#ifdef _WIN32
    return gc_is_drive_path(p) || p[0] == '/' || p[0] == '\\';
#else
    return p[0] == '/';
#endif
}

char *gc_resource_path(const char *location, int decode) {
    const char *p = location;
    char *out, *q;
    size_t n;
    if (!location) return NULL;
    if (strncmp(p, "file://", 7) == 0) {
        p += 7;
        if (strncmp(p, "localhost/", 10) == 0) p += 9;
    } else if (strncmp(p, "file:", 5) == 0) {
        p += 5;
    }
#ifdef _WIN32
    /* "file:///C:/dir" names C:/dir; FMI 3 passes "C:\\dir\\" as it is */
    if (p[0] == '/' && gc_is_drive_path(p + 1)) p++;
    if (!gc_is_drive_path(p) && *p != '/' && *p != '\\') return NULL;
#else
    if (*p != '/') return NULL;                 /* relative, or file://host/...: not here */
#endif
    out = malloc(strlen(p) + 1);
    if (!out) return NULL;
    for (q = out; *p; p++) {
        int hi, lo;
        if (decode && *p == '%' && (hi = hex_value(p[1])) >= 0 && (lo = hex_value(p[2])) >= 0) {
            *q++ = (char)(hi * 16 + lo);
            p += 2;
        } else {
            *q++ = *p;
        }
    }
    *q = '\0';
    n = strlen(out);
    while (n > 1 && (out[n - 1] == '/' || out[n - 1] == GC_PATH_SEPARATOR)) out[--n] = '\0';
    return out;
}

int gc_description_attribute(const char *resources, const char *attribute, char *out,
                             size_t size) {
    static const char tail[] = "/../modelDescription.xml";
    char key[64], *root, *attr, *end, *path;
    size_t n, len = strlen(resources);
    int key_len = snprintf(key, sizeof key, " %s=\"", attribute);
    FILE *f;
    if (size < 2 || key_len < 0 || (size_t)key_len >= sizeof key) return -1;
    path = malloc(len + sizeof tail);
    if (!path) return -1;
    memcpy(path, resources, len);
    memcpy(path + len, tail, sizeof tail);
    f = fopen(path, "rb");
    free(path);
    if (!f) return -1;
    n = fread(out, 1, size - 1, f);
    fclose(f);
    out[n] = '\0';
    root = strstr(out, "<fmiModelDescription");
    if (!root) return -1;
    end = strchr(root, '>');
    attr = strstr(root, key);
    if (!attr || (end && attr > end)) return -1;
    attr += key_len;
    end = strchr(attr, '"');
    if (!end) return -1;
    *end = '\0';
    memmove(out, attr, (size_t)(end - attr) + 1);
    return 1;
}

/* ------------------------------------------------------------------------------ FMU states */

/* The serialized FMU state, every number in the writer's byte order (checked, not converted):
 *    0  magic "RCFMUST\0"                        8 bytes
 *    8  format version (GC_STATE_VERSION)        uint32
 *   12  byte-order mark 0x01020304               uint32
 *   16  sizeof double, long, void *, int, size_t, then 3 zero bytes
 *   24  the backend's layout fingerprint          uint32
 *   28  token length L                            uint32
 *   32  total length of the byte string           uint64
 *   40  the token (L bytes, no NUL)
 *  +0   glue: state, terminate_requested (uint32 each), time (double)
 *  +16  model part length M                       uint64, then M bytes (the backend's)
 *  end  FNV-1a 64 of every byte before it        uint64
 */
#define GC_STATE_MAGIC "RCFMUST"
#define GC_STATE_VERSION 1u
#define GC_STATE_BOM 0x01020304u
#define GC_STATE_FIXED 40u                      /* bytes before the token */
#define GC_STATE_OVERHEAD (GC_STATE_FIXED + 16u + 8u + 8u)   /* all but token and model part */

static const unsigned char state_sizes[8] = {
    (unsigned char)sizeof(double), (unsigned char)sizeof(long), (unsigned char)sizeof(void *),
    (unsigned char)sizeof(int), (unsigned char)sizeof(size_t), 0, 0, 0
};

static uint64_t fnv1a64(const unsigned char *p, size_t n) {
    uint64_t h = 0xcbf29ce484222325u;
    size_t i;
    for (i = 0; i < n; i++) {
        h ^= p[i];
        h *= 0x100000001b3u;
    }
    return h;
}

static unsigned char *put(unsigned char *out, const void *value, size_t n) {
    memcpy(out, value, n);
    return out + n;
}

static uint32_t get_u32(const unsigned char *p) {
    uint32_t v;
    memcpy(&v, p, sizeof v);
    return v;
}

static uint64_t get_u64(const unsigned char *p) {
    uint64_t v;
    memcpy(&v, p, sizeof v);
    return v;
}

static const char *state_token(const GlueInstance *g) {
    return g->token ? g->token : "";
}

/* The instance's state serialized into a new allocation (*size bytes); NULL logged when out of
   memory or too large to describe. */
static unsigned char *serialize_instance(GlueInstance *g, const char *function, size_t *size) {
    const char *token = state_token(g);
    size_t token_len = strlen(token), model_len = g->state_ops->size(g), total;
    unsigned char *bytes, *p;
    uint32_t u32;
    uint64_t u64;
    double time = g->time;
    if (token_len > UINT32_MAX || model_len > (size_t)-1 - GC_STATE_OVERHEAD - token_len) {
        LOG_ERROR(g, "%s: the state is too large to serialize", function);
        return NULL;
    }
    total = GC_STATE_OVERHEAD + token_len + model_len;
    if (!(bytes = malloc(total))) {
        LOG_ERROR(g, "%s: out of memory (%llu bytes for the FMU state)", function,
                  (unsigned long long)total);
        return NULL;
    }
    p = put(bytes, GC_STATE_MAGIC, 8);          /* with its NUL */
    u32 = GC_STATE_VERSION;
    p = put(p, &u32, 4);
    u32 = GC_STATE_BOM;
    p = put(p, &u32, 4);
    p = put(p, state_sizes, 8);
    u32 = g->state_ops->layout();
    p = put(p, &u32, 4);
    u32 = (uint32_t)token_len;
    p = put(p, &u32, 4);
    u64 = total;
    p = put(p, &u64, 8);
    p = put(p, token, token_len);
    u32 = (uint32_t)g->state;
    p = put(p, &u32, 4);
    u32 = (uint32_t)g->terminate_requested;
    p = put(p, &u32, 4);
    p = put(p, &time, 8);
    u64 = model_len;
    p = put(p, &u64, 8);
    g->state_ops->write(g, p);
    p += model_len;
    u64 = fnv1a64(bytes, (size_t)(p - bytes));
    put(p, &u64, 8);
    *size = total;
    return bytes;
}

#define REFUSE_STATE(...)                                                                     \
    do {                                                                                      \
        LOG_ERROR(g, __VA_ARGS__);                                                            \
        return 0;                                                                             \
    } while (0)

/* Check a serialized state against this instance (header, checksum, token, layout, then the
   backend's part) and, with `commit`, make it the instance's state. 1, or 0 logged (nothing
   changed). Reads nothing outside in[0..size-1]. */
static int read_state(GlueInstance *g, const char *function, const unsigned char *in,
                      size_t size, int commit) {
    const char *token = state_token(g);
    size_t token_len, model_len;
    uint32_t u32, glue_state, terminate;
    uint64_t total, model_len64;
    double time;
    const unsigned char *p;
    if (size < 8 || memcmp(in, GC_STATE_MAGIC, 8) != 0) {
        if (size >= 8)
            REFUSE_STATE("%s: not an FMU state of this FMU (the bytes do not start with the "
                         "magic '" GC_STATE_MAGIC "')", function);
        REFUSE_STATE("%s: %llu bytes are too few for an FMU state (the header alone is %u "
                     "bytes; truncated?)", function, (unsigned long long)size,
                     (unsigned)GC_STATE_FIXED);
    }
    if (size < GC_STATE_FIXED)
        REFUSE_STATE("%s: %llu bytes are too few for an FMU state (the header alone is %u "
                     "bytes; truncated?)", function, (unsigned long long)size,
                     (unsigned)GC_STATE_FIXED);
    if ((u32 = get_u32(in + 12)) != GC_STATE_BOM)
        REFUSE_STATE("%s: the FMU state was written on a machine of another byte order "
                     "(byte-order mark 0x%08lx)", function, (unsigned long)u32);
    if ((u32 = get_u32(in + 8)) != GC_STATE_VERSION)
        REFUSE_STATE("%s: the FMU state has format version %lu; this FMU reads version %u",
                     function, (unsigned long)u32, GC_STATE_VERSION);
    if (memcmp(in + 16, state_sizes, sizeof state_sizes) != 0)
        REFUSE_STATE("%s: the FMU state was written where double, long, void *, int, size_t "
                     "have %u, %u, %u, %u, %u bytes; here they have %u, %u, %u, %u, %u (another "
                     "platform)", function, in[16], in[17], in[18], in[19], in[20],
                     state_sizes[0], state_sizes[1], state_sizes[2], state_sizes[3],
                     state_sizes[4]);
    total = get_u64(in + 32);
    if (total != (uint64_t)size)
        REFUSE_STATE("%s: the FMU state says it is %llu bytes long, but %llu bytes were given "
                     "(%s)", function, (unsigned long long)total, (unsigned long long)size,
                     total > (uint64_t)size ? "truncated" : "trailing bytes");
    token_len = get_u32(in + 28);
    if (size < GC_STATE_OVERHEAD || token_len > size - GC_STATE_OVERHEAD)
        REFUSE_STATE("%s: the FMU state is corrupt (its token length %llu does not fit in its "
                     "%llu bytes)", function, (unsigned long long)token_len,
                     (unsigned long long)size);
    if (get_u64(in + size - 8) != fnv1a64(in, size - 8))
        REFUSE_STATE("%s: the FMU state is corrupt (checksum mismatch over its %llu bytes)",
                     function, (unsigned long long)size);
    if (token_len != strlen(token) || memcmp(in + GC_STATE_FIXED, token, token_len) != 0)
        REFUSE_STATE("%s: the FMU state belongs to another FMU (token '%.*s'); this instance "
                     "of %s has token '%s'", function, (int)(token_len > 200 ? 200 : token_len),
                     (const char *)in + GC_STATE_FIXED,
                     g->model_name ? g->model_name : "this FMU", token);
    if ((u32 = get_u32(in + 24)) != g->state_ops->layout())
        REFUSE_STATE("%s: the FMU state was written by a build of this FMU with another memory "
                     "layout (fingerprint 0x%08lx, this build 0x%08lx)", function,
                     (unsigned long)u32, (unsigned long)g->state_ops->layout());
    p = in + GC_STATE_FIXED + token_len;
    glue_state = get_u32(p);
    terminate = get_u32(p + 4);
    memcpy(&time, p + 8, sizeof time);
    model_len64 = get_u64(p + 16);
    if (model_len64 != (uint64_t)(size - GC_STATE_OVERHEAD - token_len))
        REFUSE_STATE("%s: the FMU state is corrupt (its model part claims %llu bytes, %llu are "
                     "there)", function, (unsigned long long)model_len64,
                     (unsigned long long)(size - GC_STATE_OVERHEAD - token_len));
    model_len = (size_t)model_len64;
    if (glue_state != GLUE_INSTANTIATED && glue_state != GLUE_INIT_MODE &&
        glue_state != GLUE_STEP_COMPLETE && glue_state != GLUE_TERMINATED &&
        glue_state != GLUE_ERROR)
        REFUSE_STATE("%s: the FMU state is corrupt (instance state %lu)", function,
                     (unsigned long)glue_state);
    if (!g->state_ops->read(g, function, p + 24, model_len, commit)) return 0;
    if (commit) {
        g->state = (GlueState)glue_state;
        g->terminate_requested = terminate != 0;
        g->time = time;
    }
    return 1;
}

/* The instance for a state call, with state support; NULL (logged) otherwise. */
static GlueInstance *state_call(const GlueStandard *standard, void *handle,
                                const char *function) {
    GlueInstance *g = gc_enter(standard, handle, function, GLUE_ANY_STATE);
    if (g && !g->state_ops) {
        LOG_ERROR(g, "%s: not supported by %s (it keeps no FMU states)", function,
                  g->model_name ? g->model_name : "this FMU");
        return NULL;
    }
    return g;
}

/* A live state from the host's pointer (NULL logged otherwise). */
static GlueFMUState *live_state(GlueInstance *g, const char *function, const void *handle) {
    GlueFMUState *st = state_find(handle, 0);
    if (!st)
        LOG_ERROR(g, "%s: FMU state %p is not a live FMU state of this FMU (NULL, already "
                     "freed, freed with its instance, or never made)", function, handle);
    return st;
}

/* Store `bytes` in a new state (*state NULL) or in the live state *state. 0 logged. */
static int keep_state(GlueInstance *g, const char *function, void **state,
                      unsigned char *bytes, size_t size) {
    GlueFMUState *st;
    if (*state) {
        if (!(st = live_state(g, function, *state))) {
            free(bytes);
            return 0;
        }
        free(st->bytes);
    } else {
        if (!(st = malloc(sizeof *st))) {
            free(bytes);
            LOG_ERROR(g, "%s: out of memory", function);
            return 0;
        }
        if (!state_register(st)) {
            free(st);
            free(bytes);
            LOG_ERROR(g, "%s: out of memory", function);
            return 0;
        }
        *state = st;
    }
    st->owner = g;
    st->bytes = bytes;
    st->size = size;
    return 1;
}

int gc_get_state(const GlueStandard *standard, void *handle, const char *function, void **state) {
    GlueInstance *g = state_call(standard, handle, function);
    unsigned char *bytes;
    size_t size;
    if (!g) return GLUE_STATUS_ERROR;
    if (!state) {
        LOG_ERROR(g, "%s: the FMUstate argument is NULL", function);
        return GLUE_STATUS_ERROR;
    }
    if (*state && !live_state(g, function, *state)) return GLUE_STATUS_ERROR;
    if (!(bytes = serialize_instance(g, function, &size))) return GLUE_STATUS_ERROR;
    return keep_state(g, function, state, bytes, size) ? GLUE_STATUS_OK : GLUE_STATUS_ERROR;
}

int gc_set_state(const GlueStandard *standard, void *handle, const char *function, void *state) {
    GlueInstance *g = state_call(standard, handle, function);
    GlueFMUState *st;
    if (!g || !(st = live_state(g, function, state))) return GLUE_STATUS_ERROR;
    return read_state(g, function, st->bytes, st->size, 1) ? GLUE_STATUS_OK : GLUE_STATUS_ERROR;
}

int gc_free_state(const GlueStandard *standard, void *handle, const char *function,
                  void **state) {
    GlueInstance *g = state_call(standard, handle, function);
    GlueFMUState *st;
    if (!g) return GLUE_STATUS_ERROR;
    if (!state) {
        LOG_ERROR(g, "%s: the FMUstate argument is NULL", function);
        return GLUE_STATUS_ERROR;
    }
    if (!*state) return GLUE_STATUS_OK;         /* the standard: a NULL state is ignored */
    if (!live_state(g, function, *state)) return GLUE_STATUS_ERROR;
    st = state_find(*state, 1);
    if (st) {
        free(st->bytes);
        free(st);
    }
    *state = NULL;
    return GLUE_STATUS_OK;
}

int gc_state_size(const GlueStandard *standard, void *handle, const char *function, void *state,
                  size_t *size) {
    GlueInstance *g = state_call(standard, handle, function);
    GlueFMUState *st;
    if (!g) return GLUE_STATUS_ERROR;
    if (!size) {
        LOG_ERROR(g, "%s: size is NULL", function);
        return GLUE_STATUS_ERROR;
    }
    if (!(st = live_state(g, function, state))) return GLUE_STATUS_ERROR;
    *size = st->size;
    return GLUE_STATUS_OK;
}

int gc_serialize_state(const GlueStandard *standard, void *handle, const char *function,
                       void *state, unsigned char *out, size_t size) {
    GlueInstance *g = state_call(standard, handle, function);
    GlueFMUState *st;
    if (!g || !(st = live_state(g, function, state))) return GLUE_STATUS_ERROR;
    if (!out) {
        LOG_ERROR(g, "%s: serializedState is NULL", function);
        return GLUE_STATUS_ERROR;
    }
    if (size < st->size) {
        LOG_ERROR(g, "%s: serializedState has %llu bytes, the FMU state needs %llu (its "
                     "serialized size)", function, (unsigned long long)size,
                  (unsigned long long)st->size);
        return GLUE_STATUS_ERROR;
    }
    memcpy(out, st->bytes, st->size);
    return GLUE_STATUS_OK;
}

int gc_deserialize_state(const GlueStandard *standard, void *handle, const char *function,
                         const unsigned char *in, size_t size, void **state) {
    GlueInstance *g = state_call(standard, handle, function);
    unsigned char *bytes;
    if (!g) return GLUE_STATUS_ERROR;
    if (!state) {
        LOG_ERROR(g, "%s: the FMUstate argument is NULL", function);
        return GLUE_STATUS_ERROR;
    }
    if (!in && size > 0) {
        LOG_ERROR(g, "%s: serializedState is NULL but size = %llu", function,
                  (unsigned long long)size);
        return GLUE_STATUS_ERROR;
    }
    if (*state && !live_state(g, function, *state)) return GLUE_STATUS_ERROR;
    if (!read_state(g, function, in ? in : (const unsigned char *)"", size, 0))
        return GLUE_STATUS_ERROR;
    if (!(bytes = malloc(size))) {
        LOG_ERROR(g, "%s: out of memory", function);
        return GLUE_STATUS_ERROR;
    }
    memcpy(bytes, in, size);
    return keep_state(g, function, state, bytes, size) ? GLUE_STATUS_OK : GLUE_STATUS_ERROR;
}

/* ------------------------------------------------------------------------------ profiles */

static char *join_path(const char *a, const char *b) {
    size_t na = strlen(a), nb = strlen(b);
    char *p = malloc(na + 1 + nb + 1);
    if (!p) return NULL;
    memcpy(p, a, na);
    p[na] = '/';
    memcpy(p + na + 1, b, nb + 1);
    return p;
}

static int is_file(const char *path) {
    struct stat st;
    return stat(path, &st) == 0 && S_ISREG(st.st_mode);
}

char *gc_resolve_profile_path(const char *raw, const char *resources) {
    char *candidate, *cwd;
    size_t size;
    if (gc_is_absolute_path(raw)) {
        size = strlen(raw) + 1;
        candidate = malloc(size);
        if (candidate) memcpy(candidate, raw, size);
        return candidate;
    }
    if (resources && resources[0]) {
        candidate = join_path(resources, raw);
        if (!candidate || is_file(candidate)) return candidate;
        free(candidate);
    }
    for (size = 256;; size *= 2) {
        cwd = malloc(size);
        if (!cwd) return NULL;
        if (getcwd(cwd, size)) break;
        free(cwd);
        if (size > 1 << 20) return join_path(".", raw);   /* no working directory to name */
    }
    candidate = join_path(cwd, raw);
    free(cwd);
    return candidate;
}
