/* ato_line.c -- LineController (models/ato/line.py) in the C core; see ato_line.h. */
#include "rc_fp_contract.h"
#include "ato_line.h"

#include <stdio.h>
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
