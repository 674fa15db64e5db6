/* ato_line.h -- the ATO over several spans in one continuous run: the C twin of
 * models/ato/line.py's LineController (one ato_controller per span, the holding brake of each
 * station's dwell, the boarding at its start, filter.position shifted by the distance at departure
 * until the estimator has recognised the station stop), bit-identical to it.
 *
 * The caller's (outliving the line): the spans, the car, the dwells and boardings, and the room
 * for n controllers and n departures (ato_controller is large: allocate it); nothing is allocated
 * per step.
 * Units: s [m], V [m/s], t [s], force [N], mass [t].
 */
#ifndef RAILCAR_ATO_LINE_H
#define RAILCAR_ATO_LINE_H

#include <stddef.h>
#include <stdint.h>

#include "ato_controller.h"

/* LineStep: the span (0-based), the command, a station dwell's holding brake, the passengers
 * boarding now [t] */
typedef struct {
    double t;
    int span;
    ato_command command;
    int dwell;
    double payload_change;
} ato_line_step;

typedef struct {
    int n;                       /* spans */
    ato_controller *controllers; /* n, the caller's */
    const double *dwell_s, *boarding_t; /* n each, the caller's */
    double *departures;          /* [s] each span's first command (n_departures; the caller's) */
    int n_departures;
    int k;                       /* the span running or (dwell) just finished */
    int finished;
    int has_dwell_from, boarded, has_offset, has_stops0;
    double dwell_from, offset, stops0;
} ato_line;

/* LineController(spans, car, tuning): RC_OK, or the refusal with Python's ValueError text in msg
 * (ATO_TEXT_SIZE; may be NULL): "a line needs at least one span", a LineError's "span k: ..." (a
 * dwell or boarding not finite, a dwell <= 0 before a second or later span, the span's
 * AtoController refusal), or the tuning's own (AtoTuning's, before any span). Nothing is left
 * allocated then. controllers and departures: room for n each. */
rc_status ato_line_init(ato_line *line, int n, const rc_ato_span *spans, const double *dwell_s,
                        const double *boarding_t, const rc_ato_car *car, const ato_tuning *tuning,
                        ato_controller *controllers, double *departures, char *msg);
void ato_line_free(ato_line *line);

/* LineController.demands: inputs in ALL_INPUTS order (NaN where absent), station_stops
 * est.station_stops (NaN where absent) */
ato_line_step ato_line_demands(ato_line *line, double t, const double *inputs,
                               double station_stops);

/* FMU states (fmu_src/c/native_ato_state.c): the line's running state as bytes -- the line, its
 * departures, and each controller whole (its struct, its course, its planner's buffers: the
 * plans, hints, traces, events, supervision) -- in this machine's representation (the reader of
 * another machine's or build's bytes is the caller's to refuse: ato_line_state_layout is a
 * fingerprint of the sizes and offsets they rely on). Not in the bytes: the spans, car, dwells
 * and boardings (the caller saves its configuration itself).
 * size: the bytes write writes. read: a line from `size` bytes at `in` into the caller's room
 * (as for ato_line_init: the spans, car, dwells and boardings the line was made with, room for
 * n controllers and n departures); RC_OK with *used the bytes read, or RC_BAD_CONFIG with what
 * is wrong in msg (ATO_TEXT_SIZE; "out of memory" too) and nothing left allocated. It never
 * reads outside in[0 .. size - 1] and checks every count a step relies on before use; each
 * controller's grid is made again (rc_ato_course_init) and must be the saved one, its planner's
 * buffers come from rc_ato_planner_init (ato_line_free frees them). */
size_t ato_line_state_size(const ato_line *line);
void ato_line_state_write(const ato_line *line, unsigned char *out);
rc_status ato_line_state_read(ato_line *line, int n, const rc_ato_span *spans,
                              const double *dwell_s, const double *boarding_t,
                              const rc_ato_car *car, ato_controller *controllers,
                              double *departures, const unsigned char *in, size_t size,
                              size_t *used, char *msg);
uint32_t ato_line_state_layout(void);

#endif
