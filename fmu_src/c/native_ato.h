/* native_ato.h -- what the native AtoController's files share: the instance (native_ato.c
 * builds and steps it, reading its profile files with native_ato_profiles.c) and its FMU states
 * (native_ato_state.c saves and restores it). */
#ifndef NATIVE_ATO_H
#define NATIVE_ATO_H

#include "ato_line.h"
#include "ato_line_profile.h"
#include "fmi2_glue.h"
#include "native_ato_table.h"

typedef struct {
    double real[NAT_NVARS];          /* Real variables by vr */
    fmi2Integer integer[NAT_NVARS];  /* Integer and Boolean variables by vr */
    char *string[NAT_NVARS];         /* malloc'd; NULL: the start value */
    double start_time;               /* fmi2SetupExperiment's */
    double time;                     /* [s] the end of the last step taken */
    int input_vr[ATO_N_ALL_INPUTS];  /* ALL_INPUTS order -> vr */
    /* the line, after a successful initialisation (built) */
    int built;
    double *grade_block;             /* the grade's distances, grades and integral */
    double *limit_block;             /* span 1's limits: distances and speeds */
    rc_ato_span span;                /* span 1 (span.*), as open_ato reads it */
    rc_ato_car car;
    int n_spans;                     /* span 1 and line.profile's rows */
    rc_ato_span *spans;              /* n_spans; the later ones over span 1's grade */
    double *line_block;              /* n_spans each: dwells, boardings, departures, and two
                                        for a later span without limit rows: 0, span.speed_limit */
    ato_line_limits line_limits;     /* line.speed_limit_profile's */
    ato_controller *controllers;     /* n_spans */
    ato_line line;
    long *logged;                    /* n_spans: each controller's events logged so far */
} nat_instance;

#define MODEL(g) ((nat_instance *)(g)->model)

#define NAT_MSG_SIZE ATO_TEXT_SIZE     /* a refusal's message buffer [chars] */

/* String parameter vr's value: the one set, else its start value (native_ato.c) */
const char *nat_string_of(const nat_instance *m, int vr);

/* msg[NAT_MSG_SIZE] printf-formatted (the core's rc_vrefuse); returns 0, a refusal
   (native_ato.c) */
#if defined(__GNUC__)
__attribute__((format(printf, 2, 3)))
#endif
int nat_refuse(char *msg, const char *fmt, ...);

/* frees the line and everything built with it (the instance is unbuilt after; native_ato.c) */
void nat_drop_line(nat_instance *m);

/* the FMU states of the AtoController (native_ato_state.c), set in model_instantiate */
extern const GlueStateOps NAT_STATE_OPS;

#endif
