/* native_ato_state.c -- the FMU states of the native AtoController (native_ato.c's instance,
 * native_ato.h), as native_state.c is for RailCar and RailCarEstimator.
 *
 * canGetAndSetFMUstate and canSerializeFMUstate are "true": NAT_STATE_OPS at the end of this
 * file is behind glue_common.c's state calls, which add header, token, checksum and the
 * glue's own fields. The model's part is everything the controller's future outputs and log
 * depend on: every variable's value (the inputs of the next step, the outputs published, the
 * parameters), the start time and time, whether the line is built; then the line's
 * configuration as built (span 1 and line.profile's spans: stop, length, schedule, limits;
 * the grade with its integral; the car; dwells and boardings), the events logged so far, and
 * the line's running state, models/core/ato_line.c's ato_line_state_*: the line struct, the
 * departures, and each controller whole -- its struct's byte image (tuning, supervisor with its
 * windows and latch, plans' envelope and supervision curve, the relay, the blended car, the
 * episodes, the events ring: every number of it, nothing picked field by field), its course,
 * and its planner's buffer block (hints, traces, the plan in force).
 * Why this design (byte images with the pointers re-set) and not the others:
 * - a replay of the inputs since initialisation grows without bound (a 24 h line) and replays
 *   re-plans; this state's size is fixed by the line (spans, grid), not by how long it ran;
 * - a rebuild (ato_line_init) plus copied numbers would re-read the profile files (they may
 *   have changed or be absent where the state is restored) and run every span's first plan;
 *   here nothing is read from files and no plan is made: the bytes are the numbers. Only each
 *   span's grid is made again (rc_ato_course_init, from the saved span and car, as the
 *   controller made it) and it must equal the saved grid number for number;
 * - one serializer per field would have to be kept in step with every struct; an image cannot
 *   forget a number. What it must not carry are pointers: ato_line.c lists every pointer field
 *   of a controller (zeroed in the image, so that equal states give equal bytes) and re-sets
 *   each on reading -- span, car, the course's and planner's blocks as ato_controller_init and
 *   rc_ato_planner_init set them (the planner's block comes from rc_ato_planner_init and
 *   rc_ato_planner_relink lays it out with the same code),
 *   and the three that move while planning (work/spare/best, the plan's car and envelope) from
 *   a code naming their target. A new pointer field must join that list; the fingerprint
 *   (state_layout) changes with every size and offset the bytes rely on.
 * Reading checks every count against the bytes left and against the structs before it
 * allocates (span and limit rows, grade rows, the grid and its numbers, the planner block's
 * size for that grid, the traces' lengths within their capacities, the span running, the events logged, the
 * texts ended, the verdicts' subjects), builds the whole line aside and only then swaps it in:
 * a refused state (logged as "<function>: the FMU state is corrupt or of another build
 * (<what>)") leaves the model as it was. Allocation happens in get/set/serialize only, never in
 * a step; no globals.
 * The bytes are written and read with models/core/rc_bytes.h (the one byte writer and reader).
 */
#include <limits.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "native_ato.h"
#include "native_state_read.h"
#include "rc_bytes.h"

/* The model's part of an FMU state (NAT_STATE_OPS; the glue adds its header, the token, its own
   fields and the checksum). Numbers in the machine's representation, in this order:
     nvars                                   uint32
     every Real, every Integer               double[nvars], fmi2Integer[nvars]
     the start time, the time                double, double
     every String                            uint64 length (NO_STRING: the start value) + bytes
     built                                   uint32; then, if so, the line's configuration:
       spans n                               uint32
       the grade                             uint64 rows + double[3 rows] (distances, grades,
                                             its integral)
       the car                               uint64 size + rc_ato_car
       the limits of all spans               uint64 rows
       each span                             length, schedule, stop; uint64 rows + distances,
                                             speeds
       dwells, boardings                     double[n] each
       events logged so far                  int64[n] (by span)
     and its running state                   uint64 size + ato_line_state_write's bytes
   See the header above for why this is complete. */

#define NO_STRING UINT64_MAX

static void put_model(rc_byte_sink *s, GlueInstance *g) {
    const nat_instance *m = MODEL(g);
    int vr, k;
    rc_put_u32(s, NAT_NVARS);
    rc_put(s, m->real, sizeof m->real);
    rc_put(s, m->integer, sizeof m->integer);
    rc_put_double(s, m->start_time);
    rc_put_double(s, m->time);
    for (vr = 0; vr < NAT_NVARS; vr++) {
        const char *str = m->string[vr];
        rc_put_u64(s, str ? (uint64_t)strlen(str) : NO_STRING);
        if (str) rc_put(s, str, strlen(str));
    }
    rc_put_u32(s, (uint32_t)m->built);
    if (!m->built) return;
    rc_put_u32(s, (uint32_t)m->n_spans);
    rc_put_u64(s, (uint64_t)m->span.grade.n);
    rc_put(s, m->grade_block, 3 * (size_t)m->span.grade.n * sizeof(double));
    rc_put_u64(s, sizeof m->car);
    rc_put(s, &m->car, sizeof m->car);
    {
        uint64_t rows = 0;
        for (k = 0; k < m->n_spans; k++) rows += (uint64_t)m->spans[k].n_limits;
        rc_put_u64(s, rows);
    }
    for (k = 0; k < m->n_spans; k++) {
        const rc_ato_span *sp = &m->spans[k];
        rc_put_double(s, sp->length);
        rc_put_double(s, sp->schedule);
        rc_put_double(s, sp->stop);
        rc_put_u64(s, (uint64_t)sp->n_limits);
        rc_put(s, sp->limit_distances, (size_t)sp->n_limits * sizeof(double));
        rc_put(s, sp->limit_speeds, (size_t)sp->n_limits * sizeof(double));
    }
    rc_put(s, m->line.dwell_s, (size_t)m->n_spans * sizeof(double));
    rc_put(s, m->line.boarding_t, (size_t)m->n_spans * sizeof(double));
    for (k = 0; k < m->n_spans; k++) {
        int64_t logged = m->logged[k];
        rc_put(s, &logged, sizeof logged);
    }
    {
        size_t line_size = ato_line_state_size(&m->line);
        rc_put_u64(s, line_size);
        if (s->p) ato_line_state_write(&m->line, s->p + s->n);
        s->n += line_size;
    }
}

static size_t state_size(GlueInstance *g) {
    rc_byte_sink s = {NULL, 0};
    put_model(&s, g);
    return s.n;
}

static void state_write(GlueInstance *g, unsigned char *out) {
    rc_byte_sink s = {NULL, 0};
    s.p = out;
    put_model(&s, g);
}

/* count doubles, allocated and read; NULL (logged) when they are not all there */
static double *take_doubles(rc_byte_source *r, uint64_t count, const char *what) {
    double *block;
    if (!r->ok) return NULL;
    if (count > (uint64_t)(r->end - r->p) / sizeof(double)) {
        rc_bytes_refuse(r, what);
        return NULL;
    }
    if (!(block = malloc(count ? (size_t)count * sizeof(double) : 1))) {
        native_state_no_memory(r);
        return NULL;
    }
    rc_take(r, block, (size_t)count * sizeof(double), what);
    return block;
}

/* the line's configuration and running state into st (its controllers point at st->car until
   state_read moves st into the instance) */
static int take_line(rc_byte_source *r, nat_instance *st) {
    uint64_t grade_rows, car_size, limit_rows, used_rows = 0;
    uint32_t n;
    int k;
    n = rc_take_u32(r, "span count");
    grade_rows = rc_take_u64(r, "grade rows");
    if (!r->ok) return 0;
    /* each span takes at least 4 doubles and a count below: n is bounded by the bytes */
    if (n < 1 || n > (uint64_t)(r->end - r->p) / (5 * sizeof(double)))
        return rc_bytes_refuse(r, "span count");
    if (grade_rows < 1 || grade_rows > LONG_MAX / 3) return rc_bytes_refuse(r, "grade rows");
    st->grade_block = take_doubles(r, 3 * grade_rows, "grade");
    car_size = rc_take_u64(r, "car size");
    if (r->ok && car_size != sizeof st->car) return rc_bytes_refuse(r, "car size");
    rc_take(r, &st->car, sizeof st->car, "car");
    limit_rows = rc_take_u64(r, "limit rows");
    if (r->ok && (limit_rows < n || limit_rows > (uint64_t)(r->end - r->p) / sizeof(double)))
        return rc_bytes_refuse(r, "limit rows");
    if (!r->ok) return 0;
    st->n_spans = (int)n;
    st->spans = calloc(n, sizeof *st->spans);
    st->line_block = calloc(5 * (size_t)n, sizeof(double));
    st->controllers = calloc(n, sizeof *st->controllers);
    st->logged = calloc(n, sizeof *st->logged);
    st->limit_block = malloc(2 * (size_t)limit_rows * sizeof(double));
    if (!st->spans || !st->line_block || !st->controllers || !st->logged || !st->limit_block)
        return native_state_no_memory(r);
    for (k = 0; k < (int)n && r->ok; k++) {
        rc_ato_span *sp = &st->spans[k];
        uint64_t rows;
        double *at = st->limit_block + 2 * used_rows;
        rc_take(r, &sp->length, sizeof sp->length, "span");
        rc_take(r, &sp->schedule, sizeof sp->schedule, "span");
        rc_take(r, &sp->stop, sizeof sp->stop, "span");
        rows = rc_take_u64(r, "span limit rows");
        if (r->ok && (rows < 1 || rows > limit_rows - used_rows))
            return rc_bytes_refuse(r, "span limit rows");
        rc_take(r, at, (size_t)rows * sizeof(double), "span limits");
        rc_take(r, at + rows, (size_t)rows * sizeof(double), "span limits");
        used_rows += rows;
        sp->n_limits = (int)rows;
        sp->limit_distances = at;
        sp->limit_speeds = at + rows;
        sp->grade.n = (long)grade_rows;
        sp->grade.distances = st->grade_block;
        sp->grade.grades = st->grade_block + grade_rows;
        sp->grade.cum = st->grade_block + 2 * grade_rows;
    }
    if (r->ok && used_rows != limit_rows) return rc_bytes_refuse(r, "limit rows");
    rc_take(r, st->line_block, n * sizeof(double), "dwells");
    rc_take(r, st->line_block + n, n * sizeof(double), "boardings");
    for (k = 0; k < (int)n && r->ok; k++) {
        int64_t logged = 0;
        rc_take(r, &logged, sizeof logged, "events logged");
        if (r->ok && logged < 0) return rc_bytes_refuse(r, "events logged");
        st->logged[k] = (long)logged;
    }
    {
        uint64_t line_size = rc_take_u64(r, "line size");
        size_t used = 0;
        char why[ATO_TEXT_SIZE];
        if (!r->ok) return 0;
        if (line_size != (uint64_t)(r->end - r->p)) return rc_bytes_refuse(r, "line size");
        if (ato_line_state_read(&st->line, (int)n, st->spans, st->line_block, st->line_block + n,
                                &st->car, st->controllers, st->line_block + 2 * n, r->p,
                                (size_t)line_size, &used, why) != RC_OK) {
            if (!strcmp(why, "out of memory")) return native_state_no_memory(r);
            return rc_bytes_refuse(r, why);
        }
        st->built = 1;             /* from here on drop_line frees the controllers' grids */
        r->p += used;
    }
    st->span = st->spans[0];
    for (k = 0; k < (int)n; k++)   /* every step logs all events so far (and a step's loop runs
                                      over those not yet logged: no more) */
        if (st->logged[k] != st->controllers[k].n_events) return rc_bytes_refuse(r, "events logged");
    return 1;
}

static void free_staged(nat_instance *st) {
    int vr;
    nat_drop_line(st);
    for (vr = 0; vr < NAT_NVARS; vr++) free(st->string[vr]);
    free(st);
}

static int state_read(GlueInstance *g, const char *function, const unsigned char *in, size_t n,
                      int commit) {
    nat_instance *m = MODEL(g), *st = calloc(1, sizeof *st);
    rc_byte_source r;
    uint32_t built;
    int vr;
    native_state_reader who;
    native_state_source(&r, &who, g, function, in, n);
    if (!st) return native_state_no_memory(&r);
    if (rc_take_u32(&r, "variable count") != NAT_NVARS) rc_bytes_refuse(&r, "variable count");
    rc_take(&r, st->real, sizeof st->real, "Real values");
    rc_take(&r, st->integer, sizeof st->integer, "Integer values");
    rc_take(&r, &st->start_time, sizeof st->start_time, "start time");
    rc_take(&r, &st->time, sizeof st->time, "time");
    for (vr = 0; vr < NAT_NVARS && r.ok; vr++) {
        uint64_t len = rc_take_u64(&r, "string length");
        if (!r.ok || len == NO_STRING) continue;
        if (len > (uint64_t)(r.end - r.p)) {
            rc_bytes_refuse(&r, "string length");
        } else if (!(st->string[vr] = malloc((size_t)len + 1))) {
            native_state_no_memory(&r);
        } else {
            rc_take(&r, st->string[vr], (size_t)len, "string");
            st->string[vr][len] = '\0';
            if (strlen(st->string[vr]) != len) rc_bytes_refuse(&r, "string with a NUL");
        }
    }
    built = rc_take_u32(&r, "built flag");
    if (r.ok && built > 1) rc_bytes_refuse(&r, "built flag");
    if (r.ok && built) take_line(&r, st);
    if (r.ok && r.p != r.end) rc_bytes_refuse(&r, "bytes left over");
    if (!r.ok || !commit) {
        free_staged(st);
        return r.ok;
    }
    /* all read: now the instance changes (nothing can fail from here) */
    nat_drop_line(m);
    for (vr = 0; vr < NAT_NVARS; vr++) free(m->string[vr]);
    memcpy(st->input_vr, m->input_vr, sizeof st->input_vr);
    *m = *st;
    /* the car moved into the instance with the rest; nothing else pointed into st */
    for (vr = 0; vr < m->n_spans; vr++) m->controllers[vr].car = &m->car;
    free(st);
    return 1;
}

/* FNV-1a over the sizes the bytes rely on, and the line's own fingerprint */
static uint32_t state_layout(void) {
    size_t sizes[] = {NAT_NVARS, sizeof(fmi2Integer), sizeof(rc_ato_car), sizeof(rc_ato_span),
                      sizeof(long)};
    uint32_t h = ato_line_state_layout();
    size_t i;
    int b;
    for (i = 0; i < sizeof sizes / sizeof sizes[0]; i++)
        for (b = 0; b < 8; b++) {
            h ^= (uint32_t)((uint64_t)sizes[i] >> (8 * b)) & 0xffu;
            h *= 16777619u;
        }
    return h;
}

const GlueStateOps NAT_STATE_OPS = {state_size, state_write, state_read, state_layout};
