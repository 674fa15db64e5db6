/* native_railcar.c -- the glue's backend for a RailCar FMU without Python (issue 18): the
 * model_* functions of fmi2_glue.h on the C core's rc_chain (models/core/railcar.h).
 *
 * It behaves as the pythonfmu slave fmu_src/railcar.py behind pyslave.c does:
 * - every variable holds its start value (native_railcar_table.h, generated from
 *   fmu_src/variables.py) after fmi2Instantiate and fmi2Reset; outputs read before
 *   initialisation are those start values;
 * - fmi2ExitInitializationMode builds the chain as fmu_src/adapter.py does, in its order: the
 *   profiles (load_profiles: track.grade_profile, then track.speed_profile; a relative path is
 *   looked up in resources/ first, then the working directory), then the whole configuration
 *   checked by rc_chain_validate (RailCarChain's messages; the options only the pythonfmu
 *   RailCar.fmu runs are refused naming the parameter and value), then rc_chain_init. A failure
 *   is fmi2Error with "initialisation failed: <message>", as adapter.initialise words it;
 * - fmi2DoStep is rc_chain_step with the inputs; a rejected step is fmi2Discard logged as
 *   "step discarded: <message>" (adapter.guarded_step), nothing changed; a step that let the
 *   innovation gate refuse measurements logs guarded_step's warning.
 * The flat configuration (rc_chain_config_from_values) is filled from the table's mapping of
 * each of its numbers to a parameter, the start time or a constant.
 *
 * Differences from the pythonfmu FMU: a step the core cannot compute (RC_MATH, where Python
 * raises ZeroDivisionError or OverflowError and guarded_step discards the step) is fmi2Error
 * here, since the chain's state is then not known to be unchanged.
 */
#define _POSIX_C_SOURCE 200809L

#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <unistd.h>

#include "fmi2_glue.h"
#include "native_railcar_table.h"
#include "profile.h"
#include "railcar.h"
#include "validate.h"

/* Marker: which binary this is (pyslave.c exports the same function). */
#define BINARY_ID "railcar-fmu fmi2 binary 1: C99 FMI 2.0 glue + native C core backend"

GLUE_EXPORT const char *railcar_fmu_binary_id(void) { return BINARY_ID; }

/* the table's outputs must be the core's */
typedef char nrc_outputs_match_the_core[NRC_NOUTPUTS == RC_CHAIN_OUTPUTS ? 1 : -1];

typedef struct {
    double real[NRC_NVARS];            /* Real values by value reference */
    fmi2Integer integer[NRC_NVARS];    /* Integer values */
    char *string[NRC_NVARS];           /* String values (malloc'd; NULL = the start value) */
    double start_time;                 /* fmi2SetupExperiment's startTime */
    rc_chain *chain;                   /* after a successful fmi2ExitInitializationMode */
    double outputs[RC_CHAIN_OUTPUTS];
} Native;

#define MODEL(g) ((Native *)(g)->model)

static const char *string_value(const Native *m, int vr) {
    return m->string[vr] ? m->string[vr] : NRC_VARS[vr].start_string;
}

static void drop_chain(Native *m) {
    if (m->chain) {
        rc_chain_free(m->chain);
        free(m->chain);
        m->chain = NULL;
    }
}

/* Every variable back to its start value, no chain, start time 0 (a fresh pythonfmu slave). */
static void start_values(Native *m) {
    int vr;
    drop_chain(m);
    for (vr = 0; vr < NRC_NVARS; vr++) {
        free(m->string[vr]);
        m->string[vr] = NULL;
        m->real[vr] = NRC_VARS[vr].type == GLUE_REAL ? NRC_VARS[vr].start : 0.0;
        m->integer[vr] = NRC_VARS[vr].type == GLUE_INTEGER ? (fmi2Integer)NRC_VARS[vr].start : 0;
    }
    m->start_time = 0.0;
}

fmi2Status model_instantiate(GlueInstance *g) {
    Native *m = calloc(1, sizeof *m);
    int vr, k;
    g->model = m;
    if (!m || !glue_set_model_name(g, "RailCar") || !glue_alloc_vars(g, NRC_NVARS)) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return fmi2Error;
    }
    for (vr = 0; vr < NRC_NVARS; vr++) {
        GlueVar *v = &g->vars[vr];
        size_t n = strlen(NRC_VARS[vr].name) + 1;
        if (!(v->name = malloc(n))) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
            return fmi2Error;
        }
        memcpy(v->name, NRC_VARS[vr].name, n);
        v->type = NRC_VARS[vr].type;
        v->causality = NRC_VARS[vr].causality;
        v->variability = NRC_VARS[vr].variability;
        v->settable = v->causality == GLUE_PARAMETER || v->causality == GLUE_INPUT;
    }
    for (k = 0; k < NRC_NCATEGORIES; k++)
        if (!glue_add_category(g, NRC_LOG_CATEGORIES[k])) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
            return fmi2Error;
        }
    start_values(m);
    return fmi2OK;
}

void model_free(GlueInstance *g) {
    Native *m = MODEL(g);
    int vr;
    if (!m) return;
    drop_chain(m);
    for (vr = 0; vr < NRC_NVARS; vr++) free(m->string[vr]);
    free(m);
    g->model = NULL;
}

fmi2Status model_reset(GlueInstance *g) {
    start_values(MODEL(g));
    return fmi2OK;
}

fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time) {
    (void)tolerance_defined;
    (void)tolerance;
    (void)stop_time_defined;
    (void)stop_time;
    MODEL(g)->start_time = start_time;
    return fmi2OK;
}

fmi2Status model_enter_initialization_mode(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_terminate(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

/* ------------------------------------------------------------------------- initialisation */

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

/* adapter.resolve_profile_path: absolute as it is; else resources/<raw> if that is a file;
   else <cwd>/<raw>. malloc'd; NULL when out of memory. */
static char *resolve_profile_path(const char *raw, const char *resources) {
    char *candidate, *cwd;
    size_t size;
    if (raw[0] == '/') {
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

/* load_profiles' reading of one parameter: RC_OK with the profile (n 0: the parameter is empty),
   or RC_BAD_CONFIG with `message` (the profile's own, malloc'd; NULL if none could be made). */
static int read_profile(GlueInstance *g, int vr, rc_profile_kind kind, rc_profile *out) {
    const char *raw = string_value(MODEL(g), vr);
    char *path;
    int status;
    memset(out, 0, sizeof *out);
    if (!raw[0]) return RC_OK;
    path = resolve_profile_path(raw, g->resources);
    if (!path) {
        snprintf(out->err.msg, sizeof out->err.msg, "%s: out of memory", NRC_VARS[vr].name);
        return RC_BAD_CONFIG;
    }
    status = rc_profile_read_file(path, NRC_VARS[vr].name, raw, kind, out);
    free(path);
    return status;
}

static void log_init_failure(GlueInstance *g, const char *message) {
    glue_log(g, fmi2Error, "logStatusError", "fmi2ExitInitializationMode: initialisation failed: "
             "%s", message);
}

static void log_profile_failure(GlueInstance *g, rc_profile *p) {
    log_init_failure(g, p->message ? p->message : p->err.msg);
}

fmi2Status model_exit_initialization_mode(GlueInstance *g) {
    Native *m = MODEL(g);
    double values[NRC_NCONFIG];
    rc_chain_config cfg;
    rc_profile grade, speed;
    rc_error err;
    static const double level_distance = 0.0, level_grade = 0.0;   /* GradeProfile.level() */
    fmi2Status status = fmi2Error;
    int k;
    long expected;

    drop_chain(m);
    for (k = 0; k < NRC_NCONFIG; k++) {
        int vr = NRC_CONFIG_VR[k];
        values[k] = vr == NRC_CONFIG_CONSTANT ? NRC_CONFIG_CONST[k]
                  : vr == NRC_CONFIG_START_TIME ? m->start_time
                  : NRC_VARS[vr].type == GLUE_INTEGER ? (double)m->integer[vr]
                  : m->real[vr];
    }
    memset(&cfg, 0, sizeof cfg);
    expected = rc_chain_config_from_values(&cfg, values, NRC_NCONFIG);
    if (expected != 0) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2ExitInitializationMode: the C core expects "
                 "%ld configuration values, this FMU has %d (rebuild it)", expected, NRC_NCONFIG);
        return fmi2Error;
    }

    /* load_profiles: the grade profile first, then the speed profile */
    if (read_profile(g, NRC_VR_GRADE_PROFILE, RC_PROFILE_GRADE, &grade) != RC_OK) {
        log_profile_failure(g, &grade);
        rc_profile_free(&grade);
        return fmi2Error;
    }
    if (read_profile(g, NRC_VR_SPEED_PROFILE, RC_PROFILE_SPEED, &speed) != RC_OK) {
        log_profile_failure(g, &speed);
        rc_profile_free(&speed);
        rc_profile_free(&grade);
        return fmi2Error;
    }
    if (grade.n > 0) {
        cfg.grade_distances = grade.distances;
        cfg.grades = grade.values;
        cfg.grade_n = grade.n;
    } else {
        cfg.grade_distances = &level_distance;
        cfg.grades = &level_grade;
        cfg.grade_n = 1;
    }
    cfg.speed_distances = speed.n > 0 ? speed.distances : NULL;
    cfg.speeds = speed.n > 0 ? speed.values : NULL;
    cfg.speed_n = speed.n;

    err.msg[0] = '\0';
    if (rc_chain_validate(&cfg, (long)m->integer[NRC_VR_SLOPE_WINDOW], speed.n > 0, &err)
        != RC_OK) {
        log_init_failure(g, err.msg);
    } else if (!(m->chain = malloc(sizeof *m->chain))) {
        log_init_failure(g, "out of memory");
    } else if (rc_chain_init(m->chain, &cfg, &err) != RC_OK) {   /* copies the profiles */
        free(m->chain);
        m->chain = NULL;
        log_init_failure(g, err.msg);
    } else {
        int i;
        rc_chain_outputs(m->chain, m->outputs);
        for (i = 0; i < NRC_NOUTPUTS; i++) {
            int vr = NRC_OUTPUT_VRS[i];
            if (NRC_VARS[vr].type == GLUE_INTEGER) m->integer[vr] = (fmi2Integer)m->outputs[i];
            else m->real[vr] = m->outputs[i];
        }
        status = fmi2OK;
    }
    rc_profile_free(&speed);
    rc_profile_free(&grade);
    return status;
}

/* -------------------------------------------------------------------------------- stepping */

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    Native *m = MODEL(g);
    rc_error err;
    rc_status s;
    fmi2Integer rejected;
    int i;
    if (!m->chain) {              /* the glue allows doStep only after a successful init */
        glue_log(g, fmi2Error, "logStatusError", "doStep refused: the instance is not "
                 "initialised (call exitInitializationMode first; after a failed "
                 "initialisation, reset or free the instance)");
        return fmi2Error;
    }
    rejected = m->integer[NRC_VR_FILTER_REJECTED];
    err.msg[0] = '\0';
    s = rc_chain_step(m->chain, current_time, step_size, m->real[NRC_INPUT_VRS[0]],
                      m->real[NRC_INPUT_VRS[1]], m->real[NRC_INPUT_VRS[2]],
                      m->real[NRC_INPUT_VRS[3]], &err);
    if (s == RC_REJECTED) {
        glue_log(g, fmi2Discard, "logStatusDiscard", "step discarded: %s", err.msg);
        return fmi2Discard;
    }
    if (s != RC_OK) {
        glue_log(g, fmi2Error, "logStatusError", "step failed: %s", err.msg);
        return fmi2Error;
    }
    rc_chain_outputs(m->chain, m->outputs);
    for (i = 0; i < NRC_NOUTPUTS; i++) {
        int vr = NRC_OUTPUT_VRS[i];
        if (NRC_VARS[vr].type == GLUE_INTEGER) m->integer[vr] = (fmi2Integer)m->outputs[i];
        else m->real[vr] = m->outputs[i];
    }
    if (m->integer[NRC_VR_FILTER_REJECTED] != rejected) {
        fmi2Integer now = m->integer[NRC_VR_FILTER_REJECTED];
        glue_log(g, fmi2Warning, "logStatusWarning", "%ld measurement(s) refused by the "
                 "innovation gate in this step (a spike, a dropout; filter.rejected = %ld)",
                 (long)now - (long)rejected, (long)now);
    }
    return fmi2OK;
}

/* ------------------------------------------------------------------- getting and setting */

fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values) {
    Native *m = MODEL(g);
    size_t i, total = 0;
    char *space;
    switch (type) {
    case GLUE_REAL:
        for (i = 0; i < nvr; i++) ((fmi2Real *)values)[i] = m->real[vr[i]];
        return fmi2OK;
    case GLUE_INTEGER:
        for (i = 0; i < nvr; i++) ((fmi2Integer *)values)[i] = m->integer[vr[i]];
        return fmi2OK;
    case GLUE_STRING:
        for (i = 0; i < nvr; i++) total += strlen(string_value(m, (int)vr[i])) + 1;
        space = glue_string_space(g, total ? total : 1);
        if (!space) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2GetString: out of memory");
            return fmi2Error;
        }
        for (i = 0; i < nvr; i++) {   /* valid until the next call on this instance */
            const char *s = string_value(m, (int)vr[i]);
            size_t n = strlen(s) + 1;
            memcpy(space, s, n);
            ((fmi2String *)values)[i] = space;
            space += n;
        }
        return fmi2OK;
    case GLUE_BOOLEAN:
        break;                        /* no Boolean variables: the glue refused the call */
    }
    return fmi2Error;
}

fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values) {
    Native *m = MODEL(g);
    size_t i;
    switch (type) {
    case GLUE_REAL:
        for (i = 0; i < nvr; i++) m->real[vr[i]] = ((const fmi2Real *)values)[i];
        return fmi2OK;
    case GLUE_INTEGER:
        for (i = 0; i < nvr; i++) m->integer[vr[i]] = ((const fmi2Integer *)values)[i];
        return fmi2OK;
    case GLUE_STRING:
        for (i = 0; i < nvr; i++) {
            const char *s = ((const fmi2String *)values)[i];
            size_t n = strlen(s) + 1;
            char *copy = malloc(n);
            if (!copy) {
                glue_log(g, fmi2Error, "logStatusError", "fmi2SetString: out of memory");
                return fmi2Error;
            }
            memcpy(copy, s, n);
            free(m->string[vr[i]]);
            m->string[vr[i]] = copy;
        }
        return fmi2OK;
    case GLUE_BOOLEAN:
        break;
    }
    return fmi2Error;
}
