/* ato_line.c -- LineController (models/ato/line.py) in the C core, and its running state as bytes
 * (the FMU states of fmu_src/c/native_ato_state.c); see ato_line.h. */
#include "rc_fp_contract.h"
#include "ato_line.h"
#include "rc_bytes.h"

#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define REPR_SIZE 40

rc_status ato_line_init(ato_line *line, int n, const rc_ato_span *spans, const double *dwell_s,
                        const double *boarding_t, const rc_ato_car *car, const ato_tuning *tuning,
                        ato_controller *controllers, double *departures, char *msg)
{
    memset(line, 0, sizeof *line);
    if (msg != NULL)
        msg[0] = '\0';
    rc_error err;
    if (ato_tuning_validate(tuning, NULL, &err) != RC_OK) {
        if (msg != NULL)
            snprintf(msg, ATO_TEXT_SIZE, "%s", err.msg);
        return RC_BAD_CONFIG;
    }
    if (n < 1) {
        if (msg != NULL)
            snprintf(msg, ATO_TEXT_SIZE, "a line needs at least one span");
        return RC_BAD_CONFIG;
    }
    for (int i = 0; i < n; i++) {
        char rd[REPR_SIZE], rb[REPR_SIZE];
        rc_repr(dwell_s[i], rd, sizeof rd);
        rc_repr(boarding_t[i], rb, sizeof rb);
        if (!(isfinite(dwell_s[i]) && isfinite(boarding_t[i]))) {
            if (msg != NULL)
                snprintf(msg, ATO_TEXT_SIZE, "span %d: dwell_s = %s s and boarding_t = %s t must "
                         "be finite", i + 1, rd, rb);
            return RC_BAD_CONFIG;
        }
        if (i > 0 && dwell_s[i] <= 0.0) {
            if (msg != NULL)
                snprintf(msg, ATO_TEXT_SIZE, "span %d: dwell_s = %s s: the standstill at the "
                         "station before it must be > 0", i + 1, rd);
            return RC_BAD_CONFIG;
        }
    }
    line->controllers = controllers;
    line->dwell_s = dwell_s;
    line->boarding_t = boarding_t;
    line->departures = departures;
    for (int i = 0; i < n; i++) {
        char inner[ATO_TEXT_SIZE];
        rc_status rc = ato_controller_init(&line->controllers[i], &spans[i], car, tuning, inner);
        if (rc != RC_OK) {
            if (msg != NULL)
                snprintf(msg, ATO_TEXT_SIZE, "span %d: %.*s", i + 1, ATO_TEXT_SIZE - 32, inner);
            line->n = i;
            ato_line_free(line);
            return rc;
        }
    }
    line->n = n;
    return RC_OK;
}

void ato_line_free(ato_line *line)
{
    for (int i = 0; i < line->n; i++)
        ato_controller_free(&line->controllers[i]);
    line->n = 0;
}

/* _restarted: the estimator has recognised the station stops up to span k's departure */
static int restarted(const ato_line *line, double stops)
{
    if (!isfinite(stops) || !line->has_stops0)
        return 0;
    return stops - line->stops0 >= line->k;
}

static ato_line_step line_step(double t, int span, ato_command cmd, int dwell, double payload)
{
    ato_line_step st;
    st.t = t;
    st.span = span;
    st.command = cmd;
    st.dwell = dwell;
    st.payload_change = payload;
    return st;
}

/* the holding brake at a station: AtoCommand(0, hold_brake x brake_force_max, HOLD, 0) */
static ato_command hold(const ato_controller *ctrl)
{
    ato_command cmd;
    cmd.traction = 0.0;
    cmd.brake = ctrl->tuning.hold_brake * ctrl->car->brake_force_max;
    cmd.mode = ATO_MODE_HOLD;
    cmd.planned_speed = 0.0;
    cmd.ep_stage = 0;
    return cmd;
}

ato_line_step ato_line_demands(ato_line *line, double t, const double *inputs,
                               double station_stops)
{
    if (!line->has_stops0 && isfinite(station_stops)) {
        line->has_stops0 = 1;
        line->stops0 = station_stops;
    }
    ato_controller *ctrl = &line->controllers[line->k];
    if (line->has_dwell_from) {                 /* standing at a station between spans */
        int next = line->k + 1;
        if (t - line->dwell_from < line->dwell_s[next] - 1e-9) {
            double boarding = line->boarded ? 0.0 : line->boarding_t[next];
            line->boarded = 1;
            return line_step(t, line->k, hold(ctrl), 1, boarding);
        }
        if (!isfinite(inputs[ATO_IN_POSITION]))      /* the shift needs a position: hold on */
            return line_step(t, line->k, hold(ctrl), 1, 0.0);
        line->has_dwell_from = 0;
        line->boarded = 0;
        line->k += 1;
        ctrl = &line->controllers[line->k];
        line->has_offset = 1;
        line->offset = inputs[ATO_IN_POSITION];
    }
    double view[ATO_N_ALL_INPUTS];
    const double *seen = inputs;
    if (line->has_offset) {
        if (restarted(line, station_stops)) {
            line->has_offset = 0;
        } else {
            memcpy(view, inputs, sizeof view);
            view[ATO_IN_POSITION] = inputs[ATO_IN_POSITION] - line->offset;
            seen = view;
        }
    }
    if (line->n_departures == line->k)
        line->departures[line->n_departures++] = t;
    ato_command cmd = ato_controller_demands(ctrl, t, seen);
    if (ato_controller_finished(ctrl) && !line->finished) {
        if (line->k == line->n - 1) {
            line->finished = 1;
        } else {
            line->has_dwell_from = 1;
            line->dwell_from = t;
        }
    }
    return line_step(t, line->k, cmd, 0, 0.0);
}

/* ------------------------------------------------------------------ FMU states
 * The line's running state as bytes (see ato_line.h). Each struct is written as its byte image
 * (so no number can be forgotten) with every pointer field zeroed; reading copies the image and
 * then sets every pointer field again: the ones fixed at construction from the caller's room
 * (span, car, the line's arrays); the course, made again by rc_ato_course_init from the span
 * and car and held to the saved nodes, grades and limits number for number (a build that
 * computes another grid is refused); the planner's block, allocated by rc_ato_planner_init for
 * that course, filled with the saved numbers and pointed into by rc_ato_planner_relink (the
 * same layout code); the ones that move while planning from a small code written beside the
 * image. Memory is allocated only by those two set-up functions, never in a step. */

/* the pointer fields of an ato_controller (offsets); all are zeroed in its image. The list's
   length is counted from the list itself, so a field added here cannot outgrow an array. */
#define TRACE_AT(k, field) \
    (offsetof(ato_controller, planner.bufs) + (size_t)(k) * sizeof(rc_ato_trace) + \
     offsetof(rc_ato_trace, field))
#define TRACE_POINTERS(k) \
    TRACE_AT(k, s), TRACE_AT(k, q), TRACE_AT(k, t), TRACE_AT(k, wF), TRACE_AT(k, wR), \
    TRACE_AT(k, mode), TRACE_AT(k, coast_x), TRACE_AT(k, coast_end)

static const size_t CTRL_POINTERS[] = {
    offsetof(ato_controller, span),
    offsetof(ato_controller, car),
    offsetof(ato_controller, course.s),
    offsetof(ato_controller, course.g),
    offsetof(ato_controller, course.qlim),
    offsetof(ato_controller, planner.c),
    offsetof(ato_controller, planner.block),
    offsetof(ato_controller, planner.hint_has),
    offsetof(ato_controller, planner.hint_has_slope),
    offsetof(ato_controller, planner.hint_x),
    offsetof(ato_controller, planner.hint_slope),
    offsetof(ato_controller, planner.qU),
    offsetof(ato_controller, planner.fall0),
    offsetof(ato_controller, planner.fall1),
    TRACE_POINTERS(0),
    TRACE_POINTERS(1),
    TRACE_POINTERS(2),
    offsetof(ato_controller, planner.work),
    offsetof(ato_controller, planner.spare),
    offsetof(ato_controller, planner.best),
    offsetof(ato_controller, planner.coast_x),
    offsetof(ato_controller, planner.coast_end),
    offsetof(ato_controller, planner.car),
    offsetof(ato_controller, planner.plan.coast_x),
    offsetof(ato_controller, planner.plan.coast_end),
    offsetof(ato_controller, planner.plan.s),
    offsetof(ato_controller, planner.plan.v),
    offsetof(ato_controller, planner.plan.t),
    offsetof(ato_controller, planner.plan.mode),
    offsetof(ato_controller, planner.plan.qU),
};
#define N_CTRL_POINTERS ((int)(sizeof CTRL_POINTERS / sizeof CTRL_POINTERS[0]))
/* three traces' pointers are in bufs[0..2]: a fourth buffer must join the list */
typedef char ctrl_pointers_name_every_trace[
    sizeof ((rc_ato_planner *)0)->bufs / sizeof(rc_ato_trace) == 3 ? 1 : -1];

static void zero_pointers(unsigned char *image, const size_t *at, int n)
{
    for (int i = 0; i < n; i++)
        memset(image + at[i], 0, sizeof(void *));
}

/* the trace a planner's work / spare / best points at: 0..2 (bufs), 3 for anything else */
static uint32_t trace_code(const rc_ato_planner *p, const rc_ato_trace *tr)
{
    for (uint32_t k = 0; k < 3; k++)
        if (tr == &p->bufs[k])
            return k;
    return 3;
}

/* planner.car: 0 none, 1 the configured car, 2 car_now (the only cars a plan is made for) */
static uint32_t car_code(const ato_controller *c)
{
    const rc_ato_plancar *car = c->planner.car;
    return car == NULL ? 0 : car == &c->configured ? 1 : car == &c->car_now ? 2 : 3;
}

/* planner.plan.qU: 0 none, 1 the controller's envelope, 2 the planner's */
static uint32_t envelope_code(const ato_controller *c)
{
    const double *qU = c->planner.plan.qU;
    return qU == NULL ? 0 : qU == c->qU ? 1 : qU == c->planner.qU ? 2 : 3;
}

static void put_controller(rc_byte_sink *s, const ato_controller *c)
{
    const rc_ato_course *co = &c->course;
    unsigned char *image;
    rc_put_u64(s, sizeof *c);
    if ((image = rc_put(s, c, sizeof *c)) != NULL)
        zero_pointers(image, CTRL_POINTERS, N_CTRL_POINTERS);
    rc_put_u32(s, trace_code(&c->planner, c->planner.work));
    rc_put_u32(s, trace_code(&c->planner, c->planner.spare));
    rc_put_u32(s, trace_code(&c->planner, c->planner.best));
    rc_put_u32(s, car_code(c));
    rc_put_u32(s, envelope_code(c));
    rc_put_u64(s, (uint64_t)co->n);
    rc_put(s, co->s, sizeof(double) * (size_t)co->n);
    rc_put(s, co->g, sizeof(double) * (size_t)(co->n - 1));
    rc_put(s, co->qlim, sizeof(double) * (size_t)co->n);
    rc_put_u64(s, rc_ato_planner_block_size(co));
    rc_put(s, c->planner.block, rc_ato_planner_block_size(co));
}

static size_t put_line(rc_byte_sink *s, const ato_line *line)
{
    ato_line image;
    memcpy(&image, line, sizeof image);           /* padding too: equal lines, equal bytes */
    image.controllers = NULL;
    image.dwell_s = image.boarding_t = NULL;
    image.departures = NULL;
    rc_put_u64(s, sizeof image);
    rc_put(s, &image, sizeof image);
    rc_put(s, line->departures, sizeof(double) * (size_t)line->n);
    for (int i = 0; i < line->n; i++)
        put_controller(s, &line->controllers[i]);
    return s->n;
}

size_t ato_line_state_size(const ato_line *line)
{
    rc_byte_sink s = {NULL, 0};
    return put_line(&s, line);
}

void ato_line_state_write(const ato_line *line, unsigned char *out)
{
    rc_byte_sink s = {out, 0};
    put_line(&s, line);
}

/* ---- reading */

/* the first problem, in the source's msg (context; may be NULL): "<what>" */
static void say_what(rc_byte_source *r, const char *what)
{
    if (r->context != NULL)
        snprintf((char *)r->context, ATO_TEXT_SIZE, "%s", what);
}

static int has_end(const char *text)
{
    return memchr(text, '\0', ATO_TEXT_SIZE) != NULL;
}

/* a verdict's subject: none, an input, or one of supervision.h's (a step indexes with it) */
static int subject_sane(int subject)
{
    return subject == ATO_SUBJECT_NONE || (subject >= 0 && subject < ATO_N_ALL_INPUTS) ||
           subject == ATO_SUBJECT_TIME || subject == ATO_SUBJECT_CONSISTENCY ||
           subject == ATO_SUBJECT_RECOVERY;
}

/* the numbers a step indexes or prints with: within their bounds */
static int controller_sane(const ato_controller *c, int n_limits)
{
    const rc_ato_course *co = &c->course;
    const rc_ato_planner *p = &c->planner;
    if (co->n < 2 || co->n > ATO_MAX_NODES || co->i_relay < 0 || co->i_relay >= co->n ||
        co->n_limits != n_limits)
        return 0;
    if (c->n_events < 0 || c->phase < ATO_PHASE_RUN || c->phase > ATO_PHASE_HOLD ||
        c->settle < -1 || c->settle > 1 || p->n_trials < 0 || p->n_trials > RC_ATO_MAX_TRIALS)
        return 0;
    const ato_supervisor *sup = &c->supervisor;
    if (!has_end(sup->problem.text) || !has_end(sup->gate.text) ||
        !has_end(sup->dead_problem.text) || !subject_sane(sup->problem.subject) ||
        !subject_sane(sup->gate.subject) || !subject_sane(sup->dead_problem.subject))
        return 0;
    for (int k = 0; k < ATO_EVENT_RING; k++)
        if (!has_end(c->events[k].text))
            return 0;
    return 1;
}

/* the counts of the planner's buffers (after rc_ato_planner_relink set their capacities) */
static int planner_sane(const rc_ato_planner *p)
{
    for (int k = 0; k < 3; k++) {
        const rc_ato_trace *tr = &p->bufs[k];
        if (tr->n < 0 || tr->n > tr->cap || tr->n_coasts < 0 || tr->n_coasts > tr->coast_cap)
            return 0;
    }
    return p->plan.n >= 0 && p->plan.n <= p->bufs[0].cap && p->plan.n_coasts >= 0 &&
           p->plan.n_coasts <= p->coast_cap;
}

static void release_controller(ato_controller *c)
{
    free(c->course.s);
    free(c->planner.block);
    c->course.s = NULL;
    c->planner.block = NULL;
}

static int take_controller(rc_byte_source *r, ato_controller *c, const rc_ato_span *span,
                           const rc_ato_car *car)
{
    if (rc_take_u64(r, "controller size") != sizeof *c)
        return rc_bytes_refuse(r, "controller size");
    if (!rc_take(r, c, sizeof *c, "controller"))
        return 0;
    /* from here on, release frees what is set */
    zero_pointers((unsigned char *)c, CTRL_POINTERS, N_CTRL_POINTERS);
    uint32_t work = rc_take_u32(r, "planner traces"), spare = rc_take_u32(r, "planner traces");
    uint32_t best = rc_take_u32(r, "planner traces"), car_is = rc_take_u32(r, "planner car");
    uint32_t envelope_is = rc_take_u32(r, "plan envelope");
    uint64_t nodes = rc_take_u64(r, "course nodes");
    if (!r->ok)
        return 0;
    if (work > 2 || spare > 2 || best > 2 || car_is > 2 || envelope_is > 2)
        return rc_bytes_refuse(r, "controller pointer codes");
    if (!controller_sane(c, span->n_limits))
        return rc_bytes_refuse(r, "controller counts");
    /* the course: made again from the span and car as the controller made it (its own
       allocation: rc_ato_course_init's), then held to the saved one number for number */
    rc_ato_course saved = c->course;
    rc_error err;
    if (nodes != (uint64_t)saved.n ||
        (3 * nodes - 1) > (uint64_t)(r->end - r->p) / sizeof(double))
        return rc_bytes_refuse(r, "course nodes");
    if (rc_ato_course_init(&c->course, span, car, saved.h, saved.margin, saved.v_relay,
                           saved.a_ep, ATO_MAX_NODES, &err) != RC_OK) {
        c->course.s = NULL;
        return rc_bytes_refuse(r, "course: not the one of this span and car");
    }
    size_t row = sizeof(double) * (size_t)nodes;
    const rc_ato_course *co = &c->course;
    if (co->n != saved.n || co->i_relay != saved.i_relay || co->n_limits != saved.n_limits ||
        memcmp(&co->stop, &saved.stop, sizeof co->stop) != 0 ||
        memcmp(&co->d_relay, &saved.d_relay, sizeof co->d_relay) != 0 ||
        memcmp(co->s, r->p, row) != 0 || memcmp(co->g, r->p + row, row - sizeof(double)) != 0 ||
        memcmp(co->qlim, r->p + 2 * row - sizeof(double), row) != 0) {
        release_controller(c);
        return rc_bytes_refuse(r, "course: not the one of this span and car");
    }
    r->p += 3 * row - sizeof(double);
    /* the planner's block: rc_ato_planner_init allocates one for this course (as at
       construction), the saved numbers go in, rc_ato_planner_relink points into it */
    size_t block_size = rc_ato_planner_block_size(co);
    if (rc_take_u64(r, "planner block size") != block_size)
        rc_bytes_refuse(r, "planner block size");
    if (r->ok && block_size > (size_t)(r->end - r->p))
        rc_bytes_refuse(r, "planner block");
    if (!r->ok) {
        release_controller(c);
        return 0;
    }
    rc_ato_planner room;
    if (rc_ato_planner_init(&room, co, c->planner.tol, c->planner.v_min, NULL) != RC_OK) {
        release_controller(c);
        return rc_bytes_refuse(r, "out of memory");
    }
    void *block = room.block;
    rc_take(r, block, block_size, "planner block");
    rc_ato_planner_relink(&c->planner, &c->course, block);
    c->span = span;
    c->car = car;
    c->planner.work = &c->planner.bufs[work];
    c->planner.spare = &c->planner.bufs[spare];
    c->planner.best = &c->planner.bufs[best];
    c->planner.car = car_is == 0 ? NULL : car_is == 1 ? &c->configured : &c->car_now;
    c->planner.plan.qU = envelope_is == 0 ? NULL : envelope_is == 1 ? c->qU : c->planner.qU;
    if (!planner_sane(&c->planner))
        rc_bytes_refuse(r, "planner counts");
    if (!r->ok) {
        release_controller(c);
        return 0;
    }
    return 1;
}

rc_status ato_line_state_read(ato_line *line, int n, const rc_ato_span *spans,
                              const double *dwell_s, const double *boarding_t,
                              const rc_ato_car *car, ato_controller *controllers,
                              double *departures, const unsigned char *in, size_t size,
                              size_t *used, char *msg)
{
    rc_byte_source r;
    int done = 0;
    if (msg != NULL)
        msg[0] = '\0';
    rc_bytes_source(&r, in, size, say_what, msg);
    memset(line, 0, sizeof *line);
    if (rc_take_u64(&r, "line size") != sizeof *line)
        rc_bytes_refuse(&r, "line size");
    rc_take(&r, line, sizeof *line, "line");
    if (r.ok && (line->n != n || line->k < 0 || line->k >= n || line->n_departures < 0 ||
                 line->n_departures > n))
        rc_bytes_refuse(&r, "line counts");
    if (r.ok && (size_t)n > (size_t)(r.end - r.p) / sizeof(double))
        rc_bytes_refuse(&r, "departures");
    rc_take(&r, departures, sizeof(double) * (size_t)(r.ok ? n : 0), "departures");
    for (; r.ok && done < n; done++)
        if (!take_controller(&r, &controllers[done], &spans[done], car))
            break;
    if (!r.ok) {
        for (int i = 0; i < done; i++)
            release_controller(&controllers[i]);
        memset(line, 0, sizeof *line);
        return RC_BAD_CONFIG;
    }
    line->controllers = controllers;
    line->dwell_s = dwell_s;
    line->boarding_t = boarding_t;
    line->departures = departures;
    *used = (size_t)(r.p - in);
    return RC_OK;
}

uint32_t ato_line_state_layout(void)
{
    const size_t *at = CTRL_POINTERS;
    size_t n = (size_t)N_CTRL_POINTERS;
    size_t sizes[] = {sizeof(ato_line), sizeof(ato_controller), sizeof(rc_ato_planner),
                      sizeof(rc_ato_course), sizeof(rc_ato_trace), sizeof(ato_supervisor),
                      sizeof(ato_event), sizeof(long), (size_t)ATO_MAX_NODES,
                      (size_t)ATO_EVENT_RING, (size_t)ATO_TEXT_SIZE};
    uint32_t h = 2166136261u;                       /* FNV-1a over the sizes and offsets */
    for (size_t i = 0; i < sizeof sizes / sizeof sizes[0] + n; i++) {
        size_t v = i < sizeof sizes / sizeof sizes[0] ? sizes[i]
                                                        : at[i - sizeof sizes / sizeof sizes[0]];
        for (int b = 0; b < 8; b++) {
            h ^= (uint32_t)((uint64_t)v >> (8 * b)) & 0xffu;
            h *= 16777619u;
        }
    }
    return h;
}
