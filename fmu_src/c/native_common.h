/* native_common.h -- what the native FMU backends (native_railcar.c, native_estimator.c) share:
 * the variables' storage by value reference with their start values, instantiate / reset /
 * free, fmi2Get* and fmi2Set*, the flat configuration from the generated tables, the profiles
 * (fmu_src/adapter.py load_profiles) and the messages fmu_src/adapter.py logs (initialise,
 * not_initialised, guarded_step). No Python; reentrant (the state lives in native_values).
 * FMU states of these backends (NATIVE_STATE_OPS) are native_state.c's. */
#ifndef NATIVE_COMMON_H
#define NATIVE_COMMON_H

#include <stddef.h>

#include "fmi2_glue.h"
#include "profile.h"
#include "rc_common.h"

/* Marker: which binary this is (pyslave.c exports the same function). */
#define NATIVE_BINARY_ID "railcar-fmu fmi2 binary 1: C99 FMI 2.0 glue + native C core backend"

typedef struct {                 /* one variable of a generated table, indexed by vr */
    const char *name;
    GlueType type;
    GlueCausality causality;
    GlueVariability variability;
    double start;                /* Real and Integer */
    const char *start_string;    /* String */
} native_var;

/* A flat configuration entry's source: a vr, the start time or a constant */
#define NATIVE_CONFIG_CONSTANT (-1)
#define NATIVE_CONFIG_START_TIME (-2)

typedef struct {                 /* one FMU, from its generated table header */
    const char *model_name;      /* modelIdentifier */
    const native_var *vars;
    int nvars;
    const char *const *categories;
    int ncategories;
    const int *config_vr;        /* index -> vr / NATIVE_CONFIG_* */
    const double *config_const;
    int nconfig;
    int vr_grade_profile, vr_speed_profile;
    const int *output_vrs;       /* the core's output order -> vr */
    int noutputs;
    int vr_rejected;             /* filter.rejected */
} native_model;

typedef struct {                 /* the variables' values of one instance */
    const native_model *md;
    double *real;                /* by vr */
    fmi2Integer *integer;
    char **string;               /* malloc'd; NULL = the start value */
    double start_time;           /* fmi2SetupExperiment's startTime */
} native_values;

/* fmi2Instantiate: allocate v's arrays, the glue's variable table and categories, start values.
   fmi2Error (logged) when out of memory; native_free copes with the half-made result. */
fmi2Status native_instantiate(GlueInstance *g, const native_model *md, native_values *v);
void native_free(native_values *v);
/* every variable back to its start value, start time 0 (a fresh pythonfmu slave) */
void native_start_values(native_values *v);
const char *native_string(const native_values *v, int vr);
fmi2Status native_get(GlueInstance *g, const native_values *v, GlueType type,
                      const fmi2ValueReference vr[], size_t nvr, void *values);
fmi2Status native_set(GlueInstance *g, native_values *v, GlueType type,
                      const fmi2ValueReference vr[], size_t nvr, const void *values);

/* the flat configuration (md->nconfig numbers) from the parameters and the start time */
void native_config_values(const native_values *v, double *out);

/* Where a chain configuration keeps its profiles: offsets of its six profile fields, which
   rc_chain_config and rc_estchain_config both have (NATIVE_PROFILE_OFFSETS(type) fills it). */
typedef struct {
    size_t grade_distances, grades, grade_n, speed_distances, speeds, speed_n;
} native_profile_offsets;
#define NATIVE_PROFILE_OFFSETS(type)                                                          \
    {offsetof(type, grade_distances), offsetof(type, grades), offsetof(type, grade_n),       \
     offsetof(type, speed_distances), offsetof(type, speeds), offsetof(type, speed_n)}

/* One chain type of the C core (rc_chain, rc_estchain) as native_build_chain drives it: the
   `cfg` and `chain` pointers are the backend's configuration and chain types. */
typedef struct {
    size_t config_size, chain_size;
    native_profile_offsets profiles;
    long (*config_from_values)(void *cfg, const double *values, long n);
    rc_status (*validate)(const void *cfg, long slope_window, int has_speed_profile,
                          rc_error *err);
    rc_status (*init)(void *chain, const void *cfg, rc_error *err);   /* copies the profiles */
    int (*outputs)(void *chain, double *out);   /* 0: no outputs yet (EstimatorChain) */
    int vr_slope_window;                        /* est.slope_window, an Integer parameter */
    void (*free_chain)(void *chain);            /* the core's free (not free() itself) */
    /* What an FMU state (native_state.c) must rebuild in a copy of the chain: where the chain
       keeps its configuration (whose profile pointers point into `profiles`), its owned
       profile buffer (double *), its rc_grade_profile and rc_speed_profile (pointing into the
       buffer) and its rc_estimator (NATIVE_CHAIN_LAYOUT(type) fills these offsets) ... */
    size_t at_cfg, at_profiles, at_grade, at_speed, at_est;
    int (*has_estimator)(const void *chain);    /* the rc_estimator is initialised */
    /* ... and the chain's other pointers into itself (offsets; `link` points them again) */
    size_t own_pointers[4];
    int n_own_pointers;
    void (*link)(void *chain);
} native_chain_kind;
#define NATIVE_CHAIN_LAYOUT(type)                                                             \
    offsetof(type, cfg), offsetof(type, profiles), offsetof(type, grade),                    \
    offsetof(type, speed), offsetof(type, est)

/* What a backend .c defines (one per FMU binary, read-only): its variable table and its chain
   type (NULL: no chain, for the benchmarks' no-op). native_common.c implements every model_*
   function of fmi2_glue.h on it but model_do_step, which each backend writes. */
typedef struct {
    const native_model *md;
    const native_chain_kind *kind;
} native_backend;
extern const native_backend NATIVE_BACKEND;

/* The FMU states of every native backend (native_state.c): model_instantiate sets them. */
extern const GlueStateOps NATIVE_STATE_OPS;

typedef struct {                 /* GlueInstance.model of a native FMU */
    native_values v;
    void *chain;                 /* after a successful fmi2ExitInitializationMode */
    double *outputs;             /* md->noutputs, the core's output order */
} native_instance;

/* fmi2ExitInitializationMode of a native backend, in adapter.initialise's order: the flat
   configuration from the parameters and the start time; load_profiles (the grade profile, then
   the speed profile; no grade profile is GradeProfile.level()); the whole configuration checked
   by kind->validate; then a new chain, initialised, its outputs (if it has any yet) stored in
   the variables through `outputs` (md->noutputs doubles). Returns the chain (malloc'd; the
   caller frees it with the core's free, then free()), or NULL after logging fmi2Error as
   adapter.initialise words it ("fmi2ExitInitializationMode: initialisation failed: ..."). */
void *native_build_chain(GlueInstance *g, native_values *v, const native_chain_kind *kind,
                         double *outputs);
/* the core's outputs (md->noutputs, integers as doubles) into the variables */
void native_store_outputs(native_values *v, const double *outputs);
/* adapter.not_initialised */
fmi2Status native_not_initialised(GlueInstance *g);
/* a step's status as adapter.guarded_step reports it: RC_REJECTED -> fmi2Discard "step
   discarded: ...", other failures fmi2Error "step failed: ..." (logged); RC_OK -> fmi2OK */
fmi2Status native_step_status(GlueInstance *g, rc_status s, const rc_error *err);
/* guarded_step's warning when filter.rejected moved from `before` */
void native_gate_warning(GlueInstance *g, const native_values *v, fmi2Integer before);

#endif
