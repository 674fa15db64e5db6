/* span_driver.c -- see span_driver.h: harness/run/span_scenario.py's AtoDriver inside
 * harness/run/driver.py's drive() in C, each expression in the Python's operand order. */
#include "rc_fp_contract.h"
#include "span_driver.h"
#include "scenario_driver.h"
#include "ato_closed_loop.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>


/* The header's numbers into s, checked */
static rc_status read_header(rc_span_script *s, const double *v, long n, rc_error *err)
{
    if (n < RC_SPAN_HEADER + RC_SPAN_CAR_FIELDS + ATO_N_TUNING_FIELDS)
        return rc_refuse(err, RC_BAD_CONFIG, "span script: expected at least %d values (the header, the car and the "
                      "tuning), got %ld", RC_SPAN_HEADER + RC_SPAN_CAR_FIELDS + ATO_N_TUNING_FIELDS, n);
    long wind, spans;
    rc_status st = rc_script_read_timing(v, &s->step_s, &s->duration_s, &s->stop_after_last_phase,
                                         err);
    if (st != RC_OK)
        return st;
    if ((st = rc_script_read_count(v[3], "span script", "wind steps", &wind, err)) != RC_OK)
        return st;
    if ((spans = rc_script_count(v[4])) < 1 || spans > 10000)
        return rc_refuse_value(err, "span script: the number of ", "spans",
                               "must be a whole number in 1..10000", v[4]);
    s->n_wind = wind;
    s->n_spans = (int)spans;
    return rc_script_count_steps(s->step_s, s->duration_s, &s->steps, err);
}

/* The doubles the arrays need (the spans' and the wind's), or -1 with err naming what is wrong */
static long arrays_needed(const rc_span_script *s, const double *v, long n, rc_error *err)
{
    long at = RC_SPAN_HEADER + RC_SPAN_CAR_FIELDS + ATO_N_TUNING_FIELDS, need = 2 * s->n_spans;
    for (int i = 0; i < s->n_spans; i++) {
        if (at + RC_SPAN_FIELDS > n) {
            rc_refuse(err, RC_BAD_CONFIG, "span script: span[%d] is missing (%ld values given)", i, n);
            return -1;
        }
        long nl = rc_script_count(v[at + 5]), ng = rc_script_count(v[at + 6]);
        char where[64];
        snprintf(where, sizeof where, "span[%d]: the number of ", i);
        if (nl < 1) {
            rc_refuse_value(err, where, "limits", "must be a whole number >= 1", v[at + 5]);
            return -1;
        }
        if (ng < 1) {
            rc_refuse_value(err, where, "grade rows", "must be a whole number >= 1", v[at + 6]);
            return -1;
        }
        at += RC_SPAN_FIELDS + 2 * nl + 2 * ng;
        need += 2 * nl + 3 * ng;
    }
    if (n != at + 2 * s->n_wind) {
        rc_refuse(err, RC_BAD_CONFIG, "span script: expected %ld values for %d spans and %ld wind steps, got %ld",
               at + 2 * s->n_wind, s->n_spans, s->n_wind, n);
        return -1;
    }
    return need + 2 * s->n_wind;
}

rc_status rc_span_script_init(rc_span_script *s, const double *values, long n, rc_error *err)
{
    memset(s, 0, sizeof *s);
    if (err)
        err->msg[0] = '\0';
    rc_status st = read_header(s, values, n, err);
    if (st != RC_OK)
        return st;
    long need = arrays_needed(s, values, n, err);
    if (need < 0)
        return RC_BAD_CONFIG;
    s->spans = calloc((size_t)s->n_spans, sizeof *s->spans);
    s->arrays = malloc(sizeof *s->arrays * (size_t)need);
    if (!s->spans || !s->arrays) {
        rc_span_script_free(s);
        return rc_refuse(err, RC_BAD_CONFIG, "span script: out of memory");
    }
    const double *v = values + RC_SPAN_HEADER;
    ato_car_from_values(&s->car, v);
    v += RC_SPAN_CAR_FIELDS;
    ato_tuning_from_values(&s->tuning, v);
    v += ATO_N_TUNING_FIELDS;
    double *a = s->arrays;
    s->dwell_s = a;
    s->boarding_t = a + s->n_spans;
    a += 2 * s->n_spans;
    for (int i = 0; i < s->n_spans; i++) {
        rc_ato_span *sp = &s->spans[i];
        long nl = (long)v[5], ng = (long)v[6];
        sp->length = v[0];
        sp->schedule = v[1];
        sp->stop = v[2];
        s->dwell_s[i] = v[3];
        s->boarding_t[i] = v[4];
        v += RC_SPAN_FIELDS;
        memcpy(a, v, sizeof *a * (size_t)(2 * nl + 2 * ng));
        sp->n_limits = (int)nl;
        sp->limit_distances = a;
        sp->limit_speeds = a + nl;
        sp->grade.distances = a + 2 * nl;
        sp->grade.grades = a + 2 * nl + ng;
        sp->grade.n = ng;
        for (long j = 0; j < ng; j++)
            if (!isfinite(sp->grade.distances[j]) || !isfinite(sp->grade.grades[j])
                    || (j > 0 && !(sp->grade.distances[j] > sp->grade.distances[j - 1]))) {
                char where[64];
                snprintf(where, sizeof where, "span[%d]: grade row %ld", i, j);
                rc_span_script_free(s);
                return rc_refuse(err, RC_BAD_CONFIG, "%s must be finite with increasing distances", where);
            }
        double *cum = a + 2 * nl + 2 * ng;
        rc_grade_cumulate(sp->grade.distances, sp->grade.grades, ng, cum);
        sp->grade.cum = cum;
        v += 2 * nl + 2 * ng;
        a += 2 * nl + 3 * ng;
    }
    s->wind = a;
    memcpy(s->wind, v, sizeof *a * (size_t)(2 * s->n_wind));
    st = rc_wind_schedule_check(s->wind, s->n_wind, err);
    if (st != RC_OK)
        rc_span_script_free(s);
    return st;
}

void rc_span_script_free(rc_span_script *s)
{
    free(s->spans);
    free(s->arrays);
    s->spans = NULL;
    s->arrays = s->dwell_s = s->boarding_t = s->wind = NULL;
}

/* The events AtoController._log logs (logger models.ato.controller): the ones recorded once per
 * episode */
static int logged(ato_event_code code)
{
    return code == ATO_EV_INPUT || code == ATO_EV_RECOVERY || code == ATO_EV_ESTIMATES
           || code == ATO_EV_REPLAN_FAILED || code == ATO_EV_OVERSPEED || code == ATO_EV_INTERNAL;
}

/* The new events of controller `span` since *seen as log lines, AtoDriver's "span k: " head and
 * LOG.warning("ATO at t = %.2f s: %s", t, reason) */
static void log_events(const ato_controller *c, int span, long *seen, rc_span_output *out)
{
    for (; *seen < c->n_events; (*seen)++) {
        const ato_event *e = ato_controller_event(c, *seen);
        if (e != NULL && !logged(e->code))
            continue;
        if (e != NULL && out->log_lines < out->log_cap) {
            char *line = out->log + RC_SPAN_LOG_SIZE * out->log_lines;
            if (isnan(e->t))          /* Python's "%.2f" % nan, whatever its sign */
                snprintf(line, RC_SPAN_LOG_SIZE, "span %d: ATO at t = nan s: %s", span + 1, e->text);
            else
                snprintf(line, RC_SPAN_LOG_SIZE, "span %d: ATO at t = %.2f s: %s", span + 1, e->t,
                         e->text);
            out->log_lines++;
        } else {                      /* no room, or left the ring: the caller is told */
            out->log_lines = out->log_cap + 1;
        }
    }
}

static void record_step(double *row, const ato_line_step *st)
{
    row[0] = st->t;
    row[1] = (double)st->span;
    row[2] = st->command.traction;
    row[3] = st->command.brake;
    row[4] = (double)st->command.mode;
    row[5] = st->command.planned_speed;
    row[6] = (double)st->command.ep_stage;
    row[7] = (double)st->dwell;
    row[8] = st->payload_change;
}

/* The run with the line built (see rc_span_run) */
static rc_status run_line(const rc_span_script *s, ato_line *line, long *seen, rc_chain *chain,
                          rc_span_output *out, rc_error *err)
{
    const double h = s->step_s;
    double *y = out->outputs;
    double reads[ATO_N_ALL_INPUTS];
    rc_chain_outputs(chain, y);
    out->rows = 1;
    double payload = 0.0;
    for (long k = 0; k < s->steps; k++) {
        double t = (double)k * h;
        for (int i = 0; i < ATO_N_ALL_INPUTS; i++)
            reads[i] = y[ATO_LOOP_INPUT_OUTPUTS[i]];
        ato_line_step st = ato_line_demands(line, t, reads, y[RC_SPAN_STATION_STOPS]);
        record_step(out->steps + RC_SPAN_STEP_FIELDS * out->calls, &st);
        out->calls++;
        log_events(&line->controllers[st.span], st.span, &seen[st.span], out);
        payload += st.payload_change;
        if (line->finished && s->stop_after_last_phase) {
            out->finished = 1;
            break;
        }
        double *u = out->inputs + RC_SPAN_INPUTS * k;
        u[0] = st.command.traction;
        u[1] = st.command.brake;
        u[2] = rc_wind_schedule_at(s->wind, s->n_wind, t);
        u[3] = payload;
        y += RC_CHAIN_OUTPUTS;
        rc_status rc = rc_script_advance(chain, k, t, h, u, y, err);
        if (rc != RC_OK)
            return rc;
        out->rows++;
    }
    return RC_OK;
}

rc_status rc_span_run(const rc_span_script *s, rc_chain *chain, rc_span_output *out, rc_error *err)
{
    if (err)
        err->msg[0] = '\0';
    out->rows = out->calls = out->log_lines = 0;
    out->finished = 0;
    int n = s->n_spans;
    ato_controller *controllers = malloc(sizeof *controllers * (size_t)n);
    double *departures = malloc(sizeof *departures * (size_t)n);
    long *seen = calloc((size_t)n, sizeof *seen);
    if (!controllers || !departures || !seen) {
        free(controllers);
        free(departures);
        free(seen);
        return rc_refuse(err, RC_BAD_CONFIG, "span run: out of memory");
    }
    ato_line line;
    char msg[ATO_TEXT_SIZE];
    rc_status st = ato_line_init(&line, n, s->spans, s->dwell_s, s->boarding_t, &s->car, &s->tuning,
                                 controllers, departures, msg);
    if (st == RC_OK) {
        st = run_line(s, &line, seen, chain, out, err);
        ato_line_free(&line);
    } else if (err) {
        snprintf(err->msg, sizeof err->msg, "%.*s", (int)sizeof err->msg - 1, msg);
    }
    free(controllers);
    free(departures);
    free(seen);
    return st;
}
