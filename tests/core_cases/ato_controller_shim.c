/* ato_controller_shim.c -- a ctypes face of the C ATO controller (models/core/ato_controller.c) for
 * tests/model_tests/core/test_core_ato_controller.py. One handle: copies of the span's and car's
 * arrays and the controller. Built as a program (-DSHIM_MAIN) it replays a file of calls for the
 * sanitizers. */
#include "rc_fp_contract.h"
#include "ato_controller.h"

#include <stdio.h>
#include <stdlib.h>
#include <string.h>

typedef struct {
    double *grade_d, *grade_g, *grade_cum, *lim_d, *lim_v;
    rc_ato_span span;
    rc_ato_car car;
    ato_controller ctrl;
} shim;

static double *copy(const double *x, int n)
{
    double *out = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    if (out != NULL && n > 0)
        memcpy(out, x, sizeof(double) * (size_t)n);
    return out;
}

static void free_arrays(shim *h)
{
    free(h->grade_d);
    free(h->grade_g);
    free(h->grade_cum);
    free(h->lim_d);
    free(h->lim_v);
}

int shim_sizes(void) { return ATO_TEXT_SIZE; }

/* span3: (length, schedule, stop); car: CarTraction's 18 fields in declaration order; tuning:
 * AtoTuning's ATO_N_TUNING_FIELDS values in its order. NULL on a refusal: *status and msg
 * (ATO_TEXT_SIZE) say why. */
void *shim_new(const double *span3, const double *grade_d, const double *grade_g, int n_grade,
               const double *lim_d, const double *lim_v, int n_lim, const double *car,
               const double *tuning, int *status, char *msg)
{
    shim *h = calloc(1, sizeof *h);
    if (h == NULL)
        return NULL;
    h->grade_d = copy(grade_d, n_grade);
    h->grade_g = copy(grade_g, n_grade);
    h->grade_cum = copy(grade_g, n_grade);
    h->lim_d = copy(lim_d, n_lim);
    h->lim_v = copy(lim_v, n_lim);
    h->span.length = span3[0];
    h->span.schedule = span3[1];
    h->span.stop = span3[2];
    h->span.grade.n = n_grade;
    h->span.grade.distances = h->grade_d;
    h->span.grade.grades = h->grade_g;
    h->span.grade.cum = h->grade_cum;
    rc_ato_grade_init(&h->span.grade);
    h->span.n_limits = n_lim;
    h->span.limit_distances = h->lim_d;
    h->span.limit_speeds = h->lim_v;
    rc_ato_car *c = &h->car;
    double *fields[18] = {&c->mass, &c->A0, &c->A1, &c->A2, &c->gamma, &c->length,
                          &c->traction_force_max, &c->traction_power_max, &c->brake_force_max,
                          &c->regen_force_max, &c->regen_power_max, &c->regen_fade_speed,
                          &c->regen_off_speed, &c->mech_force_max, &c->adhesion_mass_fraction,
                          &c->adhesion_factor, &c->eta_f, &c->eta};
    for (int k = 0; k < 18; k++)
        *fields[k] = car[k];
    ato_tuning tn;
    ato_tuning_defaults(&tn);
    for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = ato_tuning_field_at(k);
        char *at = (char *)&tn + f->offset;
        if (f->kind == ATO_FIELD_REAL)
            *(double *)at = tuning[k];
        else
            *(int *)at = (int)tuning[k];
    }
    *status = ato_controller_init(&h->ctrl, &h->span, &h->car, &tn, msg);
    if (*status != RC_OK) {
        free_arrays(h);
        free(h);
        return NULL;
    }
    return h;
}

void shim_free(void *hv)
{
    shim *h = hv;
    ato_controller_free(&h->ctrl);
    free_arrays(h);
    free(h);
}

/* one demands call: out = (traction, brake, mode, planned_speed, ep_stage, finished, n_events) */
void shim_demands(void *hv, double t, const double *inputs, double *out)
{
    shim *h = hv;
    ato_command cmd = ato_controller_demands(&h->ctrl, t, inputs);
    out[0] = cmd.traction;
    out[1] = cmd.brake;
    out[2] = cmd.mode;
    out[3] = cmd.planned_speed;
    out[4] = cmd.ep_stage;
    out[5] = ato_controller_finished(&h->ctrl);
    out[6] = (double)h->ctrl.n_events;
}

/* event k: its t, code and text (ATO_TEXT_SIZE); -1 when it has left the ring */
int shim_event(void *hv, long k, double *t, char *text)
{
    const ato_event *e = ato_controller_event(&((shim *)hv)->ctrl, k);
    if (e == NULL)
        return -1;
    *t = e->t;
    memcpy(text, e->text, ATO_TEXT_SIZE);
    return (int)e->code;
}

/* the state the tests read: phase, replans, aim_offset, gate, w_m, w_r, using, relay.stop */
void shim_state(void *hv, double *out)
{
    const ato_controller *c = &((shim *)hv)->ctrl;
    out[0] = c->phase;
    out[1] = (double)c->replans;
    out[2] = c->aim_offset;
    out[3] = c->gate;
    out[4] = c->w_m;
    out[5] = c->w_r;
    out[6] = c->using_estimates;
    out[7] = c->relay.stop;
}

#ifdef SHIM_MAIN
/* a file of doubles: the span/car/tuning header (3, n_grade, grades d, g, n_lim, d, v, 18 car, 40
 * tuning), then per call t and ATO_N_ALL_INPUTS inputs; prints each command's fields */
int main(int argc, char **argv)
{
    if (argc != 2)
        return 2;
    FILE *f = fopen(argv[1], "rb");
    if (f == NULL)
        return 2;
    static double buf[1 << 22];
    size_t n = fread(buf, sizeof(double), sizeof buf / sizeof buf[0], f);
    fclose(f);
    size_t p = 0;
    const double *span3 = buf;
    p += 3;
    int n_grade = (int)buf[p++];
    const double *gd = buf + p, *gg = buf + p + n_grade;
    p += 2 * (size_t)n_grade;
    int n_lim = (int)buf[p++];
    const double *ld = buf + p, *lv = buf + p + n_lim;
    p += 2 * (size_t)n_lim;
    const double *car = buf + p;
    p += 18;
    const double *tuning = buf + p;
    p += ATO_N_TUNING_FIELDS;
    int status;
    char msg[ATO_TEXT_SIZE];
    void *h = shim_new(span3, gd, gg, n_grade, ld, lv, n_lim, car, tuning, &status, msg);
    if (h == NULL) {
        printf("refused %d %s\n", status, msg);
        return 0;
    }
    double out[7];
    while (p + 1 + ATO_N_ALL_INPUTS <= n) {
        shim_demands(h, buf[p], buf + p + 1, out);
        p += 1 + ATO_N_ALL_INPUTS;
        printf("%a %a %d %a %d %d %ld\n", out[0], out[1], (int)out[2], out[3], (int)out[4],
               (int)out[5], (long)out[6]);
    }
    shim_free(h);
    return 0;
}
#endif
