/* ato_controller_shim.c -- a ctypes face of the C ATO controller (models/core/ato_controller.c) for
 * tests/model_tests/core/test_core_ato_controller.py. One handle: copies of the span's and car's
 * arrays and the controller. Built as a program (-DSHIM_MAIN) it replays a file of calls for the
 * sanitizers. */
#include "rc_fp_contract.h"
#include "ato_controller.h"
#include "ato_line.h"

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
    rc_grade_cumulate(h->grade_d, h->grade_g, n_grade, h->grade_cum);
    h->span.grade.cum = h->grade_cum;
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

/* one demands call: out = (traction, brake, mode, planned_speed, ep_stage, finished, n_events,
 * predicted arrival, replans, using_estimates) */
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
    out[7] = ato_controller_predicted_arrival(&h->ctrl);
    out[8] = (double)h->ctrl.replans;
    out[9] = h->ctrl.using_estimates;
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

/* ---------------------------------------------------------------- the line */

typedef struct {
    int n;
    rc_ato_span *spans;
    double *arrays;              /* every span's grade and limit arrays and grade sums */
    double *dwell, *boarding, *departures;
    ato_controller *controllers;
    rc_ato_car car;
    ato_line line;
} line_shim;

static void car_of(rc_ato_car *c, const double *car)
{
    double *fields[18] = {&c->mass, &c->A0, &c->A1, &c->A2, &c->gamma, &c->length,
                          &c->traction_force_max, &c->traction_power_max, &c->brake_force_max,
                          &c->regen_force_max, &c->regen_power_max, &c->regen_fade_speed,
                          &c->regen_off_speed, &c->mech_force_max, &c->adhesion_mass_fraction,
                          &c->adhesion_factor, &c->eta_f, &c->eta};
    for (int k = 0; k < 18; k++)
        *fields[k] = car[k];
}

static void tuning_of(ato_tuning *tn, const double *tuning)
{
    ato_tuning_defaults(tn);
    for (int k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = ato_tuning_field_at(k);
        char *at = (char *)tn + f->offset;
        if (f->kind == ATO_FIELD_REAL)
            *(double *)at = tuning[k];
        else
            *(int *)at = (int)tuning[k];
    }
}

static void free_line(line_shim *h)
{
    free(h->spans);
    free(h->arrays);
    free(h->dwell);
    free(h->boarding);
    free(h->departures);
    free(h->controllers);
    free(h);
}

/* flat: per span (length, schedule, stop, n_grade, distances, grades, n_limits, distances,
 * speeds, dwell_s, boarding_t), n_flat doubles in all */
void *shim_line_new(int n, const double *flat, int n_flat, const double *car,
                    const double *tuning, int *status, char *msg)
{
    line_shim *h = calloc(1, sizeof *h);
    if (h == NULL)
        return NULL;
    h->n = n;
    h->spans = calloc((size_t)(n > 0 ? n : 1), sizeof(rc_ato_span));
    h->arrays = malloc(sizeof(double) * (size_t)(2 * n_flat + 1));
    double *dwell = h->dwell = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    double *boarding = h->boarding = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    h->departures = malloc(sizeof(double) * (size_t)(n > 0 ? n : 1));
    h->controllers = calloc((size_t)(n > 0 ? n : 1), sizeof(ato_controller));
    memcpy(h->arrays, flat, sizeof(double) * (size_t)n_flat);
    double *cum = h->arrays + n_flat;
    int p = 0;
    for (int i = 0; i < n; i++) {
        rc_ato_span *s = &h->spans[i];
        const double *a = h->arrays;
        s->length = a[p];
        s->schedule = a[p + 1];
        s->stop = a[p + 2];
        int ng = (int)a[p + 3];
        p += 4;
        s->grade.n = ng;
        s->grade.distances = a + p;
        s->grade.grades = a + p + ng;
        rc_grade_cumulate(a + p, a + p + ng, ng, cum + p);
        s->grade.cum = cum + p;
        p += 2 * ng;
        int nl = (int)a[p++];
        s->n_limits = nl;
        s->limit_distances = a + p;
        s->limit_speeds = a + p + nl;
        p += 2 * nl;
        dwell[i] = a[p];
        boarding[i] = a[p + 1];
        p += 2;
    }
    car_of(&h->car, car);
    ato_tuning tn;
    tuning_of(&tn, tuning);
    *status = ato_line_init(&h->line, n, h->spans, dwell, boarding, &h->car, &tn, h->controllers,
                            h->departures, msg);
    if (*status != RC_OK) {
        free_line(h);
        return NULL;
    }
    return h;
}

void shim_line_free(void *hv)
{
    line_shim *h = hv;
    ato_line_free(&h->line);
    free_line(h);
}

/* out = (t, span, traction, brake, mode, planned_speed, ep_stage, dwell, payload_change,
 * finished, departures) */
void shim_line_demands(void *hv, double t, const double *inputs, double stops, double *out)
{
    line_shim *h = hv;
    ato_line_step st = ato_line_demands(&h->line, t, inputs, stops);
    out[0] = st.t;
    out[1] = st.span;
    out[2] = st.command.traction;
    out[3] = st.command.brake;
    out[4] = st.command.mode;
    out[5] = st.command.planned_speed;
    out[6] = st.command.ep_stage;
    out[7] = st.dwell;
    out[8] = st.payload_change;
    out[9] = h->line.finished;
    out[10] = h->line.n_departures;
}

/* the line's departures [s] (n_departures of them) */
void shim_line_departures(void *hv, double *out)
{
    line_shim *h = hv;
    memcpy(out, h->line.departures, sizeof(double) * (size_t)h->line.n_departures);
}

/* span i's controller's event k as shim_event */
int shim_line_event(void *hv, int i, long k, double *t, char *text)
{
    const ato_event *e = ato_controller_event(&((line_shim *)hv)->line.controllers[i], k);
    if (e == NULL)
        return -1;
    *t = e->t;
    memcpy(text, e->text, ATO_TEXT_SIZE);
    return (int)e->code;
}

long shim_line_n_events(void *hv, int i)
{
    return ((line_shim *)hv)->line.controllers[i].n_events;
}

#ifdef SHIM_MAIN
/* argv[1] "span": a file of doubles, the span/car/tuning header (3, n_grade, grade distances and
 * grades, n_limits, limit distances and speeds, 18 car, ATO_N_TUNING_FIELDS tuning), then per
 * call t and ATO_N_ALL_INPUTS inputs; prints each command's fields.
 * argv[1] "line": n, n_flat, shim_line_new's flat spans, 18 car, tuning, then per call t, the
 * inputs and est.station_stops; prints each step's fields. */
int main(int argc, char **argv)
{
    if (argc != 3)
        return 2;
    FILE *f = fopen(argv[2], "rb");
    if (f == NULL)
        return 2;
    static double buf[1 << 22];
    size_t n = fread(buf, sizeof(double), sizeof buf / sizeof buf[0], f);
    fclose(f);
    size_t p = 0;
    int status;
    char msg[ATO_TEXT_SIZE];
    if (strcmp(argv[1], "line") == 0) {
        int spans = (int)buf[p++];
        int n_flat = (int)buf[p++];
        const double *flat = buf + p;
        p += (size_t)n_flat;
        const double *car = buf + p;
        p += 18;
        const double *tuning = buf + p;
        p += ATO_N_TUNING_FIELDS;
        void *h = shim_line_new(spans, flat, n_flat, car, tuning, &status, msg);
        if (h == NULL) {
            printf("refused %d %s\n", status, msg);
            return 0;
        }
        double out[11];
        while (p + 2 + ATO_N_ALL_INPUTS <= n) {
            shim_line_demands(h, buf[p], buf + p + 1, buf[p + 1 + ATO_N_ALL_INPUTS], out);
            p += 2 + ATO_N_ALL_INPUTS;
            for (int k = 0; k < 11; k++)
                printf(k ? " %a" : "%a", out[k]);
            printf("\n");
        }
        shim_line_free(h);
        return 0;
    }
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
    void *h = shim_new(span3, gd, gg, n_grade, ld, lv, n_lim, car, tuning, &status, msg);
    if (h == NULL) {
        printf("refused %d %s\n", status, msg);
        return 0;
    }
    double out[10];
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
