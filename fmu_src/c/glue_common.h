/* glue_common.h -- what the FMI 2.0 glue (fmi2_glue.c) and the FMI 3.0 glue (fmi3_glue.c) share,
 * in no standard's types (plain C, statuses as ints with FMI's values):
 *   - the instance a backend sees (GlueInstance: its variables, state, time, log settings) and
 *     the services the glue offers the backend (glue_log, glue_alloc_vars, ...; see fmi2_glue.h
 *     for the backend's side);
 *   - what both glues do the same way: the registry of live instances (a pointer that is not
 *     live is refused without being read), the state rules and their messages, value-reference
 *     checks, debug-log categories, log filtering and formatting, UTF-8 checks, resource
 *     locations, reading the token in <resources>/../modelDescription.xml, and FMU states
 *     (their registry, serialized form and checks; the model's part is the backend's).
 * A glue names its standard's words in a GlueStandard (they appear in its messages) and reaches
 * the host's logger through a GlueLogSink; the entry points and the calls of the backend stay in
 * the glue. One registry per shared library: a binary links one glue.
 */
#ifndef GLUE_COMMON_H
#define GLUE_COMMON_H

#include <stddef.h>
#include <stdint.h>

/* Statuses as FMI 2.0 and FMI 3.0 both number them (fmi2OK .. fmi2Fatal = fmi3OK .. fmi3Fatal;
   each glue checks its own at compile time). */
enum {
    GLUE_STATUS_OK, GLUE_STATUS_WARNING, GLUE_STATUS_DISCARD, GLUE_STATUS_ERROR,
    GLUE_STATUS_FATAL
};

/* States of a synchronous co-simulation slave (FMI 2.0 section 4.2.4; FMI 3.0's step mode is
   GLUE_STEP_COMPLETE). */
typedef enum {
    GLUE_INSTANTIATED = 1 << 0,
    GLUE_INIT_MODE = 1 << 1,
    GLUE_STEP_COMPLETE = 1 << 2,
    GLUE_TERMINATED = 1 << 3,
    GLUE_ERROR = 1 << 4,
    GLUE_FATAL = 1 << 5
} GlueState;

/* The states in which each call is allowed, in both standards. Deviations, on purpose:
   - terminate is also accepted in the error state (hosts clean up with terminate + free);
   - a discarded step leaves the instance in step mode, not step failed: our backends change
     nothing when they discard, so the host may retry or go on. */
#define GLUE_ANY_STATE \
    (GLUE_INSTANTIATED | GLUE_INIT_MODE | GLUE_STEP_COMPLETE | GLUE_TERMINATED | GLUE_ERROR)
#define GLUE_MASK_ENTER_INIT GLUE_INSTANTIATED
#define GLUE_MASK_EXIT_INIT GLUE_INIT_MODE
#define GLUE_MASK_DO_STEP GLUE_STEP_COMPLETE
#define GLUE_MASK_TERMINATE (GLUE_STEP_COMPLETE | GLUE_ERROR)
#define GLUE_MASK_RESET GLUE_ANY_STATE
#define GLUE_MASK_GET (GLUE_INIT_MODE | GLUE_STEP_COMPLETE | GLUE_TERMINATED | GLUE_ERROR)
#define GLUE_MASK_SET (GLUE_INSTANTIATED | GLUE_INIT_MODE | GLUE_STEP_COMPLETE)

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

/* The words of one FMI version in the glue's messages. */
typedef struct {
    const char *prefix;         /* "fmi2": the entry points are <prefix>Reset, ... */
    const char *handle;         /* what the standard calls an instance pointer: "component" */
    const char *step_state;     /* GLUE_STEP_COMPLETE's name: "step complete", "step mode" */
    const char *type_phrase[4]; /* by GlueType: "a Real", "an Integer", "a Boolean", "a String" */
    const char *vr_array, *vr_count;          /* get/set arguments: "vr", "nvr" */
    const char *values_array, *values_count;  /* "value", "nvr" */
    int time_variable;          /* value reference n_vars is "time", the independent variable
                                   (FMI 3); its value is the glue's to give */
} GlueStandard;

struct GlueInstance;
struct GlueStateOps;
/* The glue's way to the host's logger: `message` is the text as it is (not a format). */
typedef void (*GlueLogSink)(struct GlueInstance *g, int status, const char *category,
                            const char *message);

/* One instance. The glue owns every field but `model`, which is the backend's. A glue's own
   instance type has a GlueInstance first and adds what only its standard has. */
typedef struct GlueInstance {
    char *instance_name;
    char *model_name;           /* set by the backend, for messages */
    char *resources;            /* file-system path of the FMU's resources folder */
    char *token;                /* the GUID (FMI 2) / instantiationToken (FMI 3) it was made with;
                                   FMU states carry it (one FMU's state is refused by another) */
    int visible;
    const GlueStandard *standard;

    GlueLogSink log_sink;       /* NULL: no logging */
    int logging_on;             /* debug-level (OK) messages pass only when this is set */
    char **categories;          /* enabled debug categories (setDebugLogging); 0 = all */
    size_t n_categories;
    char **known_categories;    /* the model's LogCategories; 0 = accept any */
    size_t n_known_categories;

    GlueState state;
    double time;                /* end of the last successful step (lastSuccessfulTime) */
    int terminate_requested;    /* FMI 2: after a discarded step, until a step succeeds */

    GlueVar *vars;              /* indexed by value reference */
    size_t n_vars;

    char *strings;              /* getString results point in here until the next call */
    size_t strings_size;

    void *model;                /* the backend's data */
    const struct GlueStateOps *state_ops;   /* set by the backend; NULL: no FMU states */
} GlueInstance;

/* ---- FMU states (get/set/free, serialize/deserialize) ----
 * A backend that can save and restore its model sets GlueInstance.state_ops in model_instantiate
 * (NULL, as pyslave.c leaves it: every state call answers "not supported"). The model's part of
 * a state is a byte string the backend writes and reads; the glue puts around it a header (magic,
 * format version, byte order, type sizes, the FMU's token, the backend's layout fingerprint, the
 * total length), its own fields (state, time, terminate request) and a checksum. An FMU state in
 * memory IS that byte string: getFMUstate serializes, setFMUstate reads it back through the same
 * checks, so a state restored from bytes and one kept in memory take one path. */
typedef struct GlueStateOps {
    size_t (*size)(GlueInstance *g);                      /* bytes write() writes now */
    void (*write)(GlueInstance *g, unsigned char *out);   /* exactly size() bytes */
    /* Check the model's part (n bytes) and, with `commit`, make it the model's state. 0 when
       it is refused (logged, naming `function` and what is wrong) or memory runs out: the model
       is unchanged then. May allocate; never reads outside in[0..n-1]. */
    int (*read)(GlueInstance *g, const char *function, const unsigned char *in, size_t n,
                int commit);
    uint32_t (*layout)(void);   /* fingerprint of the type sizes and offsets the bytes rely on */
} GlueStateOps;

/* ---- services of the glue to the backend ---- */

/* Log a printf-style message; debug-level messages (status OK) only pass when logging is on
   and `category` is enabled, warnings and worse always pass. */
void glue_log(GlueInstance *g, int status, const char *category, const char *fmt, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
/* Log `message` as it is (no formatting). */
void glue_log_text(GlueInstance *g, int status, const char *category, const char *message);
/* Would a message of this status and category reach the host? (skip building it if not) */
int glue_log_wanted(const GlueInstance *g, int status, const char *category);

/* Allocate the variable table for value references 0 .. n-1 (all empty); 0 on failure. */
int glue_alloc_vars(GlueInstance *g, size_t n);
/* Set the model's name / declare one of its log categories (copied); 0 on failure. */
int glue_set_model_name(GlueInstance *g, const char *name);
int glue_add_category(GlueInstance *g, const char *name);
/* Scratch space for getString results, valid until the next call on the instance. */
char *glue_string_space(GlueInstance *g, size_t size);
/* Category name FMI-style for a status: logStatusOK ... (our LogCategories). */
const char *glue_status_category(int status);

/* ---- what both glues use ---- */

char *gc_copy_string(const char *s);           /* malloc'd copy; NULL for NULL or no memory */

/* A new instance's common fields (the rest zero, as calloc leaves them): state instantiated,
   instance_name copied. 0 when out of memory. */
int gc_init_instance(GlueInstance *g, const GlueStandard *standard, GlueLogSink sink,
                     const char *instance_name, int logging_on, int visible);
/* Free the instance's fields and the instance (`g` is the start of the glue's allocation). */
void gc_free_instance(GlueInstance *g);

/* The registry of live instances: add (0 when out of memory), take out (NULL if `handle` is
   not live), and find for a call (NULL, said on stderr as "[<prefix>] <function>: <handle>
   %p is not a live instance ...": there is no instance to log through). */
int gc_register(GlueInstance *g);
GlueInstance *gc_unregister(const void *handle);
GlueInstance *gc_lookup(const GlueStandard *standard, const void *handle, const char *function);
/* gc_lookup, then: is `function` allowed in the instance's state (`mask`)? If not, logged with
   the state and where it is allowed, and NULL (the state does not change). */
GlueInstance *gc_enter(const GlueStandard *standard, const void *handle, const char *function,
                       int mask);
/* gc_lookup, then "<function>: not supported by <model> (<why>)" logged as an error. */
void gc_not_supported(const GlueStandard *standard, const void *handle, const char *function,
                      const char *why);

/* The FMU-state calls of both standards (FMI 2 fmi2GetFMUstate ..., FMI 3 fmi3GetFMUState ...;
   `function` names the entry point in messages). A state pointer that is not a live state of
   this library is refused without being read. Each returns a GLUE_STATUS_*; failures logged.
   get: *state NULL -> a new state; non-NULL -> that state (a live one) overwritten.
   free: *state NULL -> nothing (OK); else freed and *state set to NULL.
   deserialize: checks the bytes (length, magic, version, byte order, sizes, token, layout,
   checksum, the model's part) and makes a new state (*state non-NULL: that one overwritten).
   States belong to the instance that made them: freeing the instance frees them. */
int gc_get_state(const GlueStandard *standard, void *handle, const char *function, void **state);
int gc_set_state(const GlueStandard *standard, void *handle, const char *function, void *state);
int gc_free_state(const GlueStandard *standard, void *handle, const char *function,
                  void **state);
int gc_state_size(const GlueStandard *standard, void *handle, const char *function, void *state,
                  size_t *size);
int gc_serialize_state(const GlueStandard *standard, void *handle, const char *function,
                       void *state, unsigned char *out, size_t size);
int gc_deserialize_state(const GlueStandard *standard, void *handle, const char *function,
                         const unsigned char *in, size_t size, void **state);

/* A model call's status decides the state: a failing model is in the error (fatal) state from
   now on. gc_finish: on OK the instance moves to `next` first. Both return `status`. */
int gc_settle(GlueInstance *g, int status);
int gc_finish(GlueInstance *g, int status, GlueState next);
/* reset: on OK back to instantiated at time 0; then gc_settle */
int gc_finish_reset(GlueInstance *g, int status);
/* terminate in the error state: the model failed, there is nothing to wind down; logged, the
   instance is terminated and 1 returned. 0 in any other state. */
int gc_terminate_after_error(GlueInstance *g, const char *function);

/* The experiment's times: startTime finite, stopTime (if defined) not before it; 0 logged. */
int gc_check_times(GlueInstance *g, const char *function, double start_time,
                   int stop_time_defined, double stop_time);
/* setDebugLogging: every category known to the model (else nothing changes; `owner` names the
   model in the message), then logging on/off with these categories (none: all). 0 logged. */
int gc_set_debug_logging(GlueInstance *g, const char *function, int logging_on, size_t n,
                         const char *const categories[], const char *owner);
/* Check a whole get/set call before the model sees any of it: nvalues = nvr, arrays not NULL,
   each value reference a variable of `type` (type_name: the call's type; NULL: the standard's
   phrase for `type`; a type < 0 is one none of our variables has), settable when `setting`
   (strings not NULL and valid UTF-8). 0 logged. */
int gc_check_refs(GlueInstance *g, const char *function, int type, const char *type_name,
                  const unsigned int vr[], size_t nvr, const void *values, size_t nvalues,
                  int setting);

/* Windows also separates folders with '\\' (GC_PATH_SEPARATOR; '/' everywhere else). */
#ifdef _WIN32
#define GC_PATH_SEPARATOR '\\'
#else
#define GC_PATH_SEPARATOR '/'
#endif
/* "C:/..." or "C:\\..." (1; else 0), on any machine. */
int gc_is_drive_path(const char *p);
/* An absolute path on this machine: "/..." (on Windows also "\\...", "C:/...", "C:\\..."). */
int gc_is_absolute_path(const char *p);
/* fmu_src/adapter.py's resolve_profile_path: an absolute path as it is; else resources/<raw> if
   that is a file; else <cwd>/<raw>. malloc'd; NULL when out of memory. */
char *gc_resolve_profile_path(const char *raw, const char *resources);
/* A resource location -> a malloc'd path without trailing '/', or NULL if it is not a local
   absolute path: "file:///p", "file://localhost/p", "file:/p" or "/p"; with `decode`, %XX
   escapes are decoded (FMI 2's URI; FMI 3 passes a path). On Windows also "file:///C:/p",
   "C:\\p\\" and "\\\\server\\p". */
char *gc_resource_path(const char *location, int decode);
/* The value of `attribute` (e.g. "guid") of <fmiModelDescription> in
   <resources>/../modelDescription.xml (its first size - 1 bytes) into out[size]: 1, or -1 when
   it cannot be read (not an error: a host may extract only what it needs). */
int gc_description_attribute(const char *resources, const char *attribute, char *out,
                             size_t size);

#endif
