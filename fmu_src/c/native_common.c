/* native_common.c -- see native_common.h: the parts of the native FMU backends that are the
 * same for RailCar and RailCarEstimator (fmu_src/adapter.py's behaviour, without Python). */
#define _POSIX_C_SOURCE 200809L

#include "native_common.h"

#include <limits.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

GLUE_EXPORT const char *railcar_fmu_binary_id(void) { return NATIVE_BINARY_ID; }

const char *native_string(const native_values *v, int vr) {
    return v->string[vr] ? v->string[vr] : v->md->vars[vr].start_string;
}

void native_start_values(native_values *v) {
    int vr;
    for (vr = 0; vr < v->md->nvars; vr++) {
        const native_var *var = &v->md->vars[vr];
        free(v->string[vr]);
        v->string[vr] = NULL;
        v->real[vr] = var->type == GLUE_REAL ? var->start : 0.0;
        v->integer[vr] = var->type == GLUE_INTEGER ? (fmi2Integer)var->start : 0;
    }
    v->start_time = 0.0;
}

static fmi2Status out_of_memory(GlueInstance *g, const char *where) {
    glue_log(g, fmi2Error, "logStatusError", "%s: out of memory", where);
    return fmi2Error;
}

fmi2Status native_instantiate(GlueInstance *g, const native_model *md, native_values *v) {
    int vr, k;
    size_t n = (size_t)md->nvars;
    v->md = md;
    v->real = calloc(n, sizeof *v->real);
    v->integer = calloc(n, sizeof *v->integer);
    v->string = calloc(n, sizeof *v->string);
    if (!v->real || !v->integer || !v->string || !glue_set_model_name(g, md->model_name)
        || !glue_alloc_vars(g, n))
        return out_of_memory(g, "fmi2Instantiate");
    for (vr = 0; vr < md->nvars; vr++) {
        GlueVar *gv = &g->vars[vr];
        size_t len = strlen(md->vars[vr].name) + 1;
        if (!(gv->name = malloc(len))) return out_of_memory(g, "fmi2Instantiate");
        memcpy(gv->name, md->vars[vr].name, len);
        gv->type = md->vars[vr].type;
        gv->causality = md->vars[vr].causality;
        gv->variability = md->vars[vr].variability;
        gv->settable = gv->causality == GLUE_PARAMETER || gv->causality == GLUE_INPUT;
    }
    for (k = 0; k < md->ncategories; k++)
        if (!glue_add_category(g, md->categories[k])) return out_of_memory(g, "fmi2Instantiate");
    native_start_values(v);
    return fmi2OK;
}

void native_free(native_values *v) {
    int vr;
    if (v->string)
        for (vr = 0; vr < v->md->nvars; vr++) free(v->string[vr]);
    free(v->string);
    free(v->integer);
    free(v->real);
    v->string = NULL;
    v->integer = NULL;
    v->real = NULL;
}

fmi2Status native_get(GlueInstance *g, const native_values *v, GlueType type,
                      const fmi2ValueReference vr[], size_t nvr, void *values) {
    size_t i, total = 0;
    char *space;
    switch (type) {
    case GLUE_REAL:
        for (i = 0; i < nvr; i++) ((fmi2Real *)values)[i] = v->real[vr[i]];
        return fmi2OK;
    case GLUE_INTEGER:
        for (i = 0; i < nvr; i++) ((fmi2Integer *)values)[i] = v->integer[vr[i]];
        return fmi2OK;
    case GLUE_STRING:
        for (i = 0; i < nvr; i++) total += strlen(native_string(v, (int)vr[i])) + 1;
        space = glue_string_space(g, total ? total : 1);
        if (!space) return out_of_memory(g, "fmi2GetString");
        for (i = 0; i < nvr; i++) {   /* valid until the next call on this instance */
            const char *s = native_string(v, (int)vr[i]);
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

fmi2Status native_set(GlueInstance *g, native_values *v, GlueType type,
                      const fmi2ValueReference vr[], size_t nvr, const void *values) {
    size_t i;
    switch (type) {
    case GLUE_REAL:
        for (i = 0; i < nvr; i++) v->real[vr[i]] = ((const fmi2Real *)values)[i];
        return fmi2OK;
    case GLUE_INTEGER:
        for (i = 0; i < nvr; i++) v->integer[vr[i]] = ((const fmi2Integer *)values)[i];
        return fmi2OK;
    case GLUE_STRING:
        for (i = 0; i < nvr; i++) {
            const char *s = ((const fmi2String *)values)[i];
            size_t n = strlen(s) + 1;
            char *copy = malloc(n);
            if (!copy) return out_of_memory(g, "fmi2SetString");
            memcpy(copy, s, n);
            free(v->string[vr[i]]);
            v->string[vr[i]] = copy;
        }
        return fmi2OK;
    case GLUE_BOOLEAN:
        break;
    }
    return fmi2Error;
}

void native_config_values(const native_values *v, double *out) {
    const native_model *md = v->md;
    int k;
    for (k = 0; k < md->nconfig; k++) {
        int vr = md->config_vr[k];
        out[k] = vr == NATIVE_CONFIG_CONSTANT ? md->config_const[k]
               : vr == NATIVE_CONFIG_START_TIME ? v->start_time
               : md->vars[vr].type == GLUE_INTEGER ? (double)v->integer[vr]
               : v->real[vr];
    }
}

void native_store_outputs(native_values *v, const double *outputs) {
    int i;
    for (i = 0; i < v->md->noutputs; i++) {
        int vr = v->md->output_vrs[i];
        if (v->md->vars[vr].type == GLUE_INTEGER) v->integer[vr] = (fmi2Integer)outputs[i];
        else v->real[vr] = outputs[i];
    }
}

/* ------------------------------------------------------------------------------ profiles */

/* load_profiles' reading of one parameter: RC_OK with the profile (n 0: the parameter is empty),
   or RC_BAD_CONFIG with the profile's message. */
static int read_profile(GlueInstance *g, const native_values *v, int vr, rc_profile_kind kind,
                        rc_profile *out) {
    const char *raw = native_string(v, vr);
    const char *name = v->md->vars[vr].name;
    char *path;
    int status;
    memset(out, 0, sizeof *out);
    if (!raw[0]) return RC_OK;
    path = gc_resolve_profile_path(raw, g->resources);
    if (!path) {
        snprintf(out->err.msg, sizeof out->err.msg, "%s: out of memory", name);
        return RC_BAD_CONFIG;
    }
    status = rc_profile_read_file(path, name, raw, kind, out);
    free(path);
    return status;
}

/* "fmi2ExitInitializationMode: initialisation failed: <message>" (fmi3... in an FMI 3 FMU) */
static void log_init_failure(GlueInstance *g, const char *message) {
    glue_log(g, fmi2Error, "logStatusError", "%sExitInitializationMode: initialisation failed: "
             "%s", g->standard->prefix, message);
}

/* load_profiles: the grade profile, then the speed profile (n 0: the parameter is empty).
   1, or 0 logged as adapter.initialise words it; the caller frees both whatever the result. */
static int read_profiles(GlueInstance *g, const native_values *v, rc_profile *grade,
                         rc_profile *speed) {
    memset(speed, 0, sizeof *speed);
    if (read_profile(g, v, v->md->vr_grade_profile, RC_PROFILE_GRADE, grade) != RC_OK) {
        log_init_failure(g, grade->message ? grade->message : grade->err.msg);
        return 0;
    }
    if (read_profile(g, v, v->md->vr_speed_profile, RC_PROFILE_SPEED, speed) != RC_OK) {
        log_init_failure(g, speed->message ? speed->message : speed->err.msg);
        return 0;
    }
    return 1;
}

/* one profile into the configuration's fields at offsets `at_x`, `at_y` and `at_n` */
static void set_profile(void *cfg, size_t at_x, size_t at_y, size_t at_n, const double *x,
                        const double *y, long n) {
    char *base = cfg;
    *(const double **)(void *)(base + at_x) = x;
    *(const double **)(void *)(base + at_y) = y;
    *(long *)(void *)(base + at_n) = n;
}

/* the configuration built, profiles read and the result checked: a new chain, or NULL (logged) */
static void *new_chain(GlueInstance *g, native_values *v, const native_chain_kind *kind,
                       void *cfg, double *outputs) {
    static const double level_distance = 0.0, level_grade = 0.0;   /* GradeProfile.level() */
    const native_profile_offsets *at = &kind->profiles;
    rc_profile grade, speed;
    rc_error err;
    void *chain = NULL;

    if (!read_profiles(g, v, &grade, &speed)) {
        rc_profile_free(&speed);
        rc_profile_free(&grade);
        return NULL;
    }
    if (grade.n > 0)
        set_profile(cfg, at->grade_distances, at->grades, at->grade_n, grade.distances,
                    grade.values, grade.n);
    else
        set_profile(cfg, at->grade_distances, at->grades, at->grade_n, &level_distance,
                    &level_grade, 1);
    set_profile(cfg, at->speed_distances, at->speeds, at->speed_n,
                speed.n > 0 ? speed.distances : NULL, speed.n > 0 ? speed.values : NULL, speed.n);

    err.msg[0] = '\0';
    if (kind->validate(cfg, (long)v->integer[kind->vr_slope_window], speed.n > 0, &err) != RC_OK) {
        log_init_failure(g, err.msg);
    } else if (!(chain = malloc(kind->chain_size))) {
        log_init_failure(g, "out of memory");
    } else if (kind->init(chain, cfg, &err) != RC_OK) {           /* copies the profiles */
        free(chain);
        chain = NULL;
        log_init_failure(g, err.msg);
    } else if (kind->outputs(chain, outputs)) {         /* EstimatorChain: none before a step */
        native_store_outputs(v, outputs);
    }
    rc_profile_free(&speed);
    rc_profile_free(&grade);
    return chain;
}

void *native_build_chain(GlueInstance *g, native_values *v, const native_chain_kind *kind,
                         double *outputs) {
    /* the flat configuration, then est.slope_window (models/core/config.c's optional value) */
    double *values = malloc((size_t)(v->md->nconfig + 1) * sizeof *values);
    void *cfg = calloc(1, kind->config_size);
    void *chain = NULL;
    long expected;
    if (!values || !cfg) {
        log_init_failure(g, "out of memory");
    } else {
        native_config_values(v, values);
        values[v->md->nconfig] = (double)v->integer[kind->vr_slope_window];
        expected = kind->config_from_values(cfg, values, v->md->nconfig + 1);
        if (expected != 0)
            glue_log(g, fmi2Error, "logStatusError", "%sExitInitializationMode: the C core "
                     "expects %ld configuration values, this FMU has %d (rebuild it)",
                     g->standard->prefix, expected, v->md->nconfig);
        else
            chain = new_chain(g, v, kind, cfg, outputs);
    }
    free(cfg);
    free(values);
    return chain;
}

/* ------------------------------------------------------------------------------- stepping */

fmi2Status native_not_initialised(GlueInstance *g) {
    glue_log(g, fmi2Error, "logStatusError", "doStep refused: the instance is not "
             "initialised (call exitInitializationMode first; after a failed "
             "initialisation, reset or free the instance)");
    return fmi2Error;
}

fmi2Status native_step_status(GlueInstance *g, rc_status s, const rc_error *err) {
    if (s == RC_OK) return fmi2OK;
    if (s == RC_REJECTED) {
        glue_log(g, fmi2Discard, "logStatusDiscard", "step discarded: %s", err->msg);
        return fmi2Discard;
    }
    glue_log(g, fmi2Error, "logStatusError", "step failed: %s", err->msg);
    return fmi2Error;
}

void native_gate_warning(GlueInstance *g, const native_values *v, fmi2Integer before) {
    fmi2Integer now = v->integer[v->md->vr_rejected];
    if (now != before)
        glue_log(g, fmi2Warning, "logStatusWarning", "%ld measurement(s) refused by the "
                 "innovation gate in this step (a spike, a dropout; filter.rejected = %ld)",
                 (long)now - (long)before, (long)now);
}

/* ------------------------------------------------- the model_* lifecycle of every backend */

static void drop_chain(native_instance *m) {
    if (m->chain) {
        NATIVE_BACKEND.kind->free_chain(m->chain);
        free(m->chain);
        m->chain = NULL;
    }
}

fmi2Status model_instantiate(GlueInstance *g) {
    native_instance *m = calloc(1, sizeof *m);
    g->model = m;
    if (m) m->outputs = calloc((size_t)NATIVE_BACKEND.md->noutputs, sizeof *m->outputs);
    if (!m || !m->outputs) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return fmi2Error;                       /* the glue calls model_free next */
    }
    g->state_ops = &NATIVE_STATE_OPS;
    return native_instantiate(g, NATIVE_BACKEND.md, &m->v);
}

void model_free(GlueInstance *g) {
    native_instance *m = g->model;
    if (!m) return;
    drop_chain(m);
    native_free(&m->v);
    free(m->outputs);
    free(m);
    g->model = NULL;
}

fmi2Status model_reset(GlueInstance *g) {
    native_instance *m = g->model;
    drop_chain(m);
    native_start_values(&m->v);
    return fmi2OK;
}

fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time) {
    (void)tolerance_defined;
    (void)tolerance;
    (void)stop_time_defined;
    (void)stop_time;
    ((native_instance *)g->model)->v.start_time = start_time;
    return fmi2OK;
}

fmi2Status model_enter_initialization_mode(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_exit_initialization_mode(GlueInstance *g) {
    native_instance *m = g->model;
    if (!NATIVE_BACKEND.kind) return fmi2OK;    /* nothing to build */
    drop_chain(m);
    m->chain = native_build_chain(g, &m->v, NATIVE_BACKEND.kind, m->outputs);
    return m->chain ? fmi2OK : fmi2Error;
}

fmi2Status model_terminate(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values) {
    return native_get(g, &((native_instance *)g->model)->v, type, vr, nvr, values);
}

fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values) {
    return native_set(g, &((native_instance *)g->model)->v, type, vr, nvr, values);
}
