/* native_ato.c -- the glue's backend for an AtoController FMU without Python (issue 30): the
 * model_* functions of fmi2_glue.h on the C core's LineController (models/core/ato_line.h: one
 * ato_controller.h per span), bit-identical to models/ato.
 *
 * It behaves as the pythonfmu slave fmu_src/ato_controller.py behind pyslave.c does:
 * - every variable holds its start value (native_ato_table.h, generated from
 *   fmu_src/variables.py) after fmi2Instantiate and fmi2Reset;
 * - fmi2ExitInitializationMode checks and builds as ato_controller.py's _build does, in its
 *   order and with its messages: check_span_parameters (span.stop, span.length, span.schedule,
 *   the profile file names), open_ato (span.grade_profile as RailCar reads a grade profile,
 *   span.speed_limit_profile, then Span's, CarTraction's and AtoTuning's checks and span 1's
 *   controller; models' names translated as adapter._fmu_names does: "tuning." is "ato.",
 *   span.limit_speeds[k] the profile's row k + 1 or span.speed_limit), then open_line: a line
 *   of several spans when line.profile names a file (one row per later span: stop, length,
 *   schedule, dwell, boarding; their limits in line.speed_limit_profile; both read by
 *   models/core/ato_line_profile.c with read_line_profile's and read_line_limits' rules and
 *   messages), each later span over span.grade_profile, refusals naming the file, the line and
 *   the span as _line_names does. A failure is fmi2Error with "initialisation failed:
 *   <message>". Then the outputs are the holding brake of span 1;
 * - fmi2DoStep checks the step (models.chain.check_step and the time continuing the last
 *   step's end: fmi2Discard "step discarded: ...", nothing changed), asks the line for the
 *   command (a station's dwell holds the brake, ato.payload adds its boarding, ato.span says
 *   which span runs), publishes it and logs the controllers' new events as warnings
 *   ("t = %.3f s: [span k: ]<text>", the span named on a line of several); fmi2Warning when
 *   the command is the safe brake (ato.mode 9).
 *
 * The profile files (their names checked, span.grade_profile, span.speed_limit_profile, the
 * line files) are read by native_ato_profiles.c. FMU states (canGetAndSetFMUstate and
 * canSerializeFMUstate "true"): native_ato_state.c (the instance, nat_instance, is
 * native_ato.h's).
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "native_ato_profiles.h"
#include "plant.h"
#include "rc_common.h"

#define REPR_SIZE 40
#define NAT_MAX_SPEED 200.0      /* [m/s] models.plant.track.MAX_SPEED, Span's limit bound */
#define NAT_MAX_STEP 3600.0      /* [s] models.chain.MAX_STEP */
#define NAT_CAR_FIELDS 18

GLUE_EXPORT const char *railcar_fmu_binary_id(void) {
    return "railcar-fmu fmi2 binary 1: C99 FMI 2.0 glue + native C core backend";
}


const char *nat_string_of(const nat_instance *m, int vr) {
    return m->string[vr] ? m->string[vr] : NAT_VARS[vr].start_string;
}

static void start_values(nat_instance *m) {
    int vr;
    for (vr = 0; vr < NAT_NVARS; vr++) {
        free(m->string[vr]);
        m->string[vr] = NULL;
        m->real[vr] = NAT_VARS[vr].type == GLUE_REAL ? NAT_VARS[vr].start : 0.0;
        m->integer[vr] = NAT_VARS[vr].type == GLUE_INTEGER || NAT_VARS[vr].type == GLUE_BOOLEAN
                             ? (fmi2Integer)NAT_VARS[vr].start : 0;
    }
    m->start_time = 0.0;
    m->time = 0.0;
}

void nat_drop_line(nat_instance *m) {
    if (m->built) ato_line_free(&m->line);
    m->built = 0;
    free(m->controllers);
    free(m->grade_block);
    free(m->limit_block);
    free(m->spans);
    free(m->line_block);
    free(m->logged);
    ato_line_limits_free(&m->line_limits);
    m->controllers = NULL;
    m->grade_block = NULL;
    m->limit_block = NULL;
    m->spans = NULL;
    m->line_block = NULL;
    m->logged = NULL;
    m->n_spans = 0;
}

/* --------------------------------------------------------------------------- lifecycle */

fmi2Status model_instantiate(GlueInstance *g) {
    nat_instance *m = calloc(1, sizeof *m);
    int vr, k;
    g->model = m;
    g->state_ops = &NAT_STATE_OPS;
    if (!m || !glue_set_model_name(g, "AtoController") || !glue_alloc_vars(g, NAT_NVARS)) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
        return fmi2Error;
    }
    for (vr = 0; vr < NAT_NVARS; vr++) {
        GlueVar *gv = &g->vars[vr];
        size_t len = strlen(NAT_VARS[vr].name) + 1;
        if (!(gv->name = malloc(len))) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
            return fmi2Error;
        }
        memcpy(gv->name, NAT_VARS[vr].name, len);
        gv->type = NAT_VARS[vr].type;
        gv->causality = NAT_VARS[vr].causality;
        gv->variability = NAT_VARS[vr].variability;
        gv->settable = gv->causality == GLUE_PARAMETER || gv->causality == GLUE_INPUT;
    }
    for (k = 0; k < NAT_NCATEGORIES; k++)
        if (!glue_add_category(g, NAT_LOG_CATEGORIES[k])) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: out of memory");
            return fmi2Error;
        }
    for (k = 0; k < ATO_N_ALL_INPUTS; k++) {   /* interface.ALL_INPUTS are the FMU's inputs */
        m->input_vr[k] = -1;
        for (vr = 0; vr < NAT_NVARS; vr++)
            if (NAT_VARS[vr].causality == GLUE_INPUT && !strcmp(NAT_VARS[vr].name, ato_input_name(k)))
                m->input_vr[k] = vr;
        if (m->input_vr[k] < 0) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: the C core's input %s is "
                     "not a variable of this FMU (rebuild it)", ato_input_name(k));
            return fmi2Error;
        }
    }
    start_values(m);
    return fmi2OK;
}

void model_free(GlueInstance *g) {
    nat_instance *m = g->model;
    int vr;
    if (!m) return;
    nat_drop_line(m);
    for (vr = 0; vr < NAT_NVARS; vr++) free(m->string[vr]);
    free(m);
    g->model = NULL;
}

fmi2Status model_reset(GlueInstance *g) {
    nat_instance *m = MODEL(g);
    nat_drop_line(m);
    start_values(m);
    return fmi2OK;
}

fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time) {
    (void)tolerance_defined;
    (void)tolerance;
    (void)stop_time_defined;
    (void)stop_time;
    MODEL(g)->start_time = start_time;
    return fmi2OK;
}

fmi2Status model_enter_initialization_mode(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_terminate(GlueInstance *g) {
    (void)g;
    return fmi2OK;
}

fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values) {
    nat_instance *m = MODEL(g);
    size_t i, total = 0;
    char *space;
    switch (type) {
    case GLUE_REAL:
        for (i = 0; i < nvr; i++) ((fmi2Real *)values)[i] = m->real[vr[i]];
        return fmi2OK;
    case GLUE_INTEGER:
        for (i = 0; i < nvr; i++) ((fmi2Integer *)values)[i] = m->integer[vr[i]];
        return fmi2OK;
    case GLUE_BOOLEAN:
        for (i = 0; i < nvr; i++) ((fmi2Boolean *)values)[i] = m->integer[vr[i]] ? fmi2True : fmi2False;
        return fmi2OK;
    case GLUE_STRING:
        for (i = 0; i < nvr; i++) total += strlen(nat_string_of(m, (int)vr[i])) + 1;
        if (!(space = glue_string_space(g, total ? total : 1))) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2GetString: out of memory");
            return fmi2Error;
        }
        for (i = 0; i < nvr; i++) {   /* valid until the next call on this instance */
            const char *s = nat_string_of(m, (int)vr[i]);
            size_t n = strlen(s) + 1;
            memcpy(space, s, n);
            ((fmi2String *)values)[i] = space;
            space += n;
        }
        return fmi2OK;
    }
    return fmi2Error;
}

fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values) {
    nat_instance *m = MODEL(g);
    size_t i;
    switch (type) {
    case GLUE_REAL:
        for (i = 0; i < nvr; i++) m->real[vr[i]] = ((const fmi2Real *)values)[i];
        return fmi2OK;
    case GLUE_INTEGER:
        for (i = 0; i < nvr; i++) m->integer[vr[i]] = ((const fmi2Integer *)values)[i];
        return fmi2OK;
    case GLUE_BOOLEAN:
        for (i = 0; i < nvr; i++) m->integer[vr[i]] = ((const fmi2Boolean *)values)[i] != fmi2False;
        return fmi2OK;
    case GLUE_STRING:
        for (i = 0; i < nvr; i++) {
            const char *s = ((const fmi2String *)values)[i];
            size_t n = strlen(s) + 1;
            char *copy = malloc(n);
            if (!copy) {
                glue_log(g, fmi2Error, "logStatusError", "fmi2SetString: out of memory");
                return fmi2Error;
            }
            memcpy(copy, s, n);
            free(m->string[vr[i]]);
            m->string[vr[i]] = copy;
        }
        return fmi2OK;
    }
    return fmi2Error;
}

/* ------------------------------------------------------------------------- messages */

int nat_refuse(char *msg, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    rc_vrefuse(msg, NAT_MSG_SIZE, RC_BAD_CONFIG, fmt, ap);
    va_end(ap);
    return 0;
}

static const char *repr(double x, char *buf) {
    rc_repr(x, buf, REPR_SIZE);
    return buf;
}

/* adapter._fmu_names / ato_controller._line_names: "span.limit_speeds[k]" and
   "span.limit_distances[k]" -> "<rows> row k+1" when the limits came from a file (rows: e.g.
   "span.speed_limit_profile", "line.speed_limit_profile span 3"), else "span.speed_limit";
   "tuning." -> "ato." */
static void fmu_names(char *msg, const char *rows) {
    char out[NAT_MSG_SIZE];
    size_t o = 0;
    const char *p = msg;
    while (*p && o + 1 < sizeof out) {
        const char *rest = NULL;
        long k = -1;
        if (!strncmp(p, "span.limit_speeds[", 18)) rest = p + 18;
        else if (!strncmp(p, "span.limit_distances[", 21)) rest = p + 21;
        if (rest && *rest >= '0' && *rest <= '9') {
            char *end;
            k = strtol(rest, &end, 10);
            if (*end == ']') {
                if (rows) o += (size_t)snprintf(out + o, sizeof out - o, "%s row %ld", rows, k + 1);
                else o += (size_t)snprintf(out + o, sizeof out - o, "span.speed_limit");
                if (o >= sizeof out) o = sizeof out - 1;
                p = end + 1;
                continue;
            }
        }
        if (!strncmp(p, "tuning.", 7)) {
            o += (size_t)snprintf(out + o, sizeof out - o, "ato.");
            if (o >= sizeof out) o = sizeof out - 1;
            p += 7;
            continue;
        }
        out[o++] = *p++;
    }
    out[o] = '\0';
    memcpy(msg, out, o + 1);
}

/* ------------------------------------------------------------------------- the checks */

/* check_span_parameters */
static int check_span_parameters(GlueInstance *g, const nat_instance *m, char *msg) {
    static const int profiles[] = {NAT_VR_SPAN_GRADE_PROFILE, NAT_VR_SPAN_SPEED_LIMIT_PROFILE,
                                   NAT_VR_LINE_PROFILE, NAT_VR_LINE_SPEED_LIMIT_PROFILE};
    double stop = m->real[NAT_VR_SPAN_STOP], length = m->real[NAT_VR_SPAN_LENGTH];
    double schedule = m->real[NAT_VR_SPAN_SCHEDULE];
    char r[REPR_SIZE];
    size_t k;
    if (!(isfinite(stop) && stop > 0.0))
        return nat_refuse(msg, "span.stop = %s m must be finite and > 0 (the stop mark's distance "
                          "from the departure station)", repr(stop, r));
    if (!(isfinite(length) && length >= 0.0))
        return nat_refuse(msg, "span.length = %s m must be finite and >= 0 (0: span.stop)",
                          repr(length, r));
    if (!(isfinite(schedule) && schedule > 0.0))
        return nat_refuse(msg, "span.schedule = %s s must be finite and > 0", repr(schedule, r));
    for (k = 0; k < sizeof profiles / sizeof profiles[0]; k++)
        if (!nat_usable_name(g, m, profiles[k], msg)) return 0;
    return 1;
}

/* Span.__post_init__ on what open_ato gives it (the values check_span_parameters passed) */
static int check_span(const rc_ato_span *s, char *msg) {
    char a[REPR_SIZE], b[REPR_SIZE], c[REPR_SIZE];
    int k;
    if (s->stop > s->length)
        return nat_refuse(msg, "span.stop = %s m is beyond the span (span.length = %s m)",
                          repr(s->stop, a), repr(s->length, b));
    for (k = 0; k < s->n_limits; k++)
        if (!isfinite(s->limit_distances[k]))
            return nat_refuse(msg, "span.limit_distances[%d] must be finite, got %s", k,
                              repr(s->limit_distances[k], a));
    for (k = 0; k < s->n_limits; k++)
        if (!isfinite(s->limit_speeds[k]))
            return nat_refuse(msg, "span.limit_speeds[%d] must be finite, got %s", k,
                              repr(s->limit_speeds[k], a));
    if (s->limit_distances[0] != 0.0)
        return nat_refuse(msg, "span.limit_distances[0] must be 0, got %s",
                          repr(s->limit_distances[0], a));
    for (k = 1; k < s->n_limits; k++)
        if (!(s->limit_distances[k - 1] < s->limit_distances[k] &&
              s->limit_distances[k] < s->length))
            return nat_refuse(msg, "span.limit_distances[%d] = %s must increase and lie inside "
                              "the span [0, %s)", k, repr(s->limit_distances[k], a),
                              repr(s->length, b));
    for (k = 0; k < s->n_limits; k++)
        if (!(0.0 < s->limit_speeds[k] && s->limit_speeds[k] <= NAT_MAX_SPEED))
            return nat_refuse(msg, "span.limit_speeds[%d] = %s m/s (from s = %s m) must be in "
                              "(0, %s]", k, repr(s->limit_speeds[k], a),
                              repr(s->limit_distances[k], b), repr(NAT_MAX_SPEED, c));
    return 1;                   /* the grades: the profile reader bounds them as Span does */
}

/* CarTraction.__post_init__ (its fields: car.* in the table's order) */
static int read_car(const nat_instance *m, rc_ato_car *car, char *msg) {
    static const char *const names[NAT_CAR_FIELDS] = {
        "mass", "A0", "A1", "A2", "gamma", "length", "traction_force_max", "traction_power_max",
        "brake_force_max", "regen_force_max", "regen_power_max", "regen_fade_speed",
        "regen_off_speed", "mech_force_max", "adhesion_mass_fraction", "adhesion_factor", "eta_f",
        "eta"};
    double *fields[NAT_CAR_FIELDS];
    char a[REPR_SIZE], b[REPR_SIZE];
    rc_vehicle vehicle;
    rc_error err;
    int k;
    fields[0] = &car->mass; fields[1] = &car->A0; fields[2] = &car->A1; fields[3] = &car->A2;
    fields[4] = &car->gamma; fields[5] = &car->length; fields[6] = &car->traction_force_max;
    fields[7] = &car->traction_power_max; fields[8] = &car->brake_force_max;
    fields[9] = &car->regen_force_max; fields[10] = &car->regen_power_max;
    fields[11] = &car->regen_fade_speed; fields[12] = &car->regen_off_speed;
    fields[13] = &car->mech_force_max; fields[14] = &car->adhesion_mass_fraction;
    fields[15] = &car->adhesion_factor; fields[16] = &car->eta_f; fields[17] = &car->eta;
    for (k = 0; k < NAT_CAR_FIELDS; k++) {
        double x = m->real[NAT_VR_CAR_MASS + k];
        if (strcmp(NAT_VARS[NAT_VR_CAR_MASS + k].name + 4, names[k]))
            return nat_refuse(msg, "car.%s is not where this FMU expects it (rebuild it)",
                              names[k]);
        if (!isfinite(x))
            return nat_refuse(msg, "car.%s must be finite, got %s", names[k], repr(x, a));
        *fields[k] = x;
    }
    if (car->regen_force_max < 0)
        return nat_refuse(msg, "car.regen_force_max must be >= 0, got %s",
                          repr(car->regen_force_max, a));
    if (car->regen_power_max < 0 || car->regen_power_max == 0)
        return nat_refuse(msg, "car.regen_power_max must be > 0, got %s",
                          repr(car->regen_power_max, a));
    if (car->mech_force_max < 0)
        return nat_refuse(msg, "car.mech_force_max must be >= 0, got %s",
                          repr(car->mech_force_max, a));
    if (!(0.0 <= car->regen_off_speed && car->regen_off_speed <= car->regen_fade_speed))
        return nat_refuse(msg, "car.regen_off_speed must be in [0, car.regen_fade_speed = %s], "
                          "got %s",
                          repr(car->regen_fade_speed, a), repr(car->regen_off_speed, b));
    if (!(0.0 < car->eta_f && car->eta_f <= 1.0))
        return nat_refuse(msg, "car.eta_f must be in (0, 1], got %s", repr(car->eta_f, a));
    if (!(0.0 <= car->eta && car->eta <= 1.0))
        return nat_refuse(msg, "car.eta must be in [0, 1], got %s", repr(car->eta, a));
    memset(&vehicle, 0, sizeof vehicle);
    vehicle.mass = car->mass;
    vehicle.A0 = car->A0;
    vehicle.A1 = car->A1;
    vehicle.A2 = car->A2;
    vehicle.gamma = car->gamma;
    vehicle.length = car->length;
    vehicle.traction_force_max = car->traction_force_max;
    vehicle.traction_power_max = car->traction_power_max;
    vehicle.brake_force_max = car->brake_force_max;
    vehicle.adhesion_mass_fraction = car->adhesion_mass_fraction;
    vehicle.adhesion_factor = car->adhesion_factor;
    /* VehicleParams.validate("car."); a step and noise it accepts: only the car is checked */
    if (rc_plant_validate(&vehicle, 0.01, 0.0, &err) != RC_OK)
        return nat_refuse(msg, "%s", err.msg);
    return 1;
}

/* AtoTuning from the ato.<field> parameters */
static int read_tuning(const nat_instance *m, ato_tuning *tn, char *msg) {
    int k, vr;
    ato_tuning_defaults(tn);
    for (k = 0; k < ATO_N_TUNING_FIELDS; k++) {
        const ato_tuning_field *f = ato_tuning_field_at(k);
        char *at = (char *)tn + f->offset;
        for (vr = 0; vr < NAT_NVARS; vr++)
            if (NAT_VARS[vr].causality == GLUE_PARAMETER && !strncmp(NAT_VARS[vr].name, "ato.", 4)
                && !strcmp(NAT_VARS[vr].name + 4, f->name))
                break;
        if (vr == NAT_NVARS)
            return nat_refuse(msg, "ato.%s is not a parameter of this FMU (rebuild it)", f->name);
        if (f->kind == ATO_FIELD_REAL) *(double *)(void *)at = m->real[vr];
        else *(int *)(void *)at = (int)m->integer[vr];
    }
    return 1;
}

/* ------------------------------------------------------------------------- building */

/* the command as AtoController._publish writes it */
static void publish(nat_instance *m, double traction, double brake, int mode, double planned,
                    int stage) {
    const ato_controller *c = &m->line.controllers[m->line.k];
    m->real[NAT_VR_TRACTION_FORCE_DEMAND] = traction;
    m->real[NAT_VR_BRAKE_FORCE_DEMAND] = brake;
    m->integer[NAT_VR_ATO_MODE] = mode;
    m->real[NAT_VR_ATO_PLANNED_SPEED] = planned;
    m->integer[NAT_VR_ATO_EP_STAGE] = stage;
    m->integer[NAT_VR_ATO_FINISHED] = ato_controller_finished(c) != 0;
    m->integer[NAT_VR_ATO_REPLANS] = (fmi2Integer)c->replans;
    m->integer[NAT_VR_ATO_USING_ESTIMATES] = c->using_estimates != 0;
    m->real[NAT_VR_ATO_PREDICTED_ARRIVAL] = ato_controller_predicted_arrival(c);
}

/* the room of a line of n spans (span 1 copied in): the spans, their dwells, boardings,
   departures and default limits, the controllers, the events logged; 1, or 0 with msg */
static int alloc_line(nat_instance *m, int n, char *msg) {
    m->spans = calloc((size_t)n, sizeof *m->spans);
    m->line_block = calloc(5 * (size_t)n, sizeof(double));
    m->controllers = calloc((size_t)n, sizeof *m->controllers);
    m->logged = calloc((size_t)n, sizeof *m->logged);
    if (!m->spans || !m->line_block || !m->controllers || !m->logged)
        return nat_refuse(msg, "out of memory");
    m->n_spans = n;
    m->spans[0] = m->span;      /* LineSpan(span): the first span has no dwell nor boarding */
    return 1;
}

/* what alloc_line and the line files gave (span 1's own blocks stay) */
static void drop_spans(nat_instance *m) {
    free(m->spans);
    free(m->line_block);
    free(m->controllers);
    free(m->logged);
    ato_line_limits_free(&m->line_limits);
    m->spans = NULL;
    m->line_block = NULL;
    m->controllers = NULL;
    m->logged = NULL;
    m->n_spans = 0;
}

/* LineController(spans, car, tuning) over m->spans: RC_OK, or a LineError's "span k: ..." in msg */
static rc_status init_line(nat_instance *m, const ato_tuning *tuning, char *msg) {
    int n = m->n_spans;
    return ato_line_init(&m->line, n, m->spans, m->line_block, m->line_block + n, &m->car, tuning,
                         m->controllers, m->line_block + 2 * n, msg);
}

/* span 1's AtoController refused (open_ato's ValueError): msg without LineError's "span 1: " */
static int refuse_first_span(char *msg, int from_profile) {
    if (!strncmp(msg, "span 1: ", 8)) memmove(msg, msg + 8, strlen(msg + 8) + 1);
    fmu_names(msg, from_profile ? "span.speed_limit_profile" : NULL);
    return 0;
}

/* open_line after open_ato's checks: the line files (line.profile's rows, their limits in
   line.speed_limit_profile), a Span per row over span 1's grade, then the LineController. 1, or
   0 with Python's refusal in msg. Python builds span 1's AtoController (open_ato) before it
   reads the line files, so its refusal wins over theirs. */
static int build_line(GlueInstance *g, nat_instance *m, const ato_tuning *tuning,
                      int from_profile, char *msg) {
    char *line_where = NULL;
    ato_line_row *rows = NULL;
    long n_rows = 0, j;
    int ok = 0, n;
    if (!nat_read_line_files(g, m, &rows, &n_rows, &line_where, msg)) goto refused_files;
    n = (int)n_rows + 1;
    if (!alloc_line(m, n, msg)) goto done;
    for (j = 0; j < n_rows; j++) {                  /* span k = j + 2 */
        const ato_line_row *row = &rows[j];
        rc_ato_span *s = &m->spans[j + 1];
        double *fallback = m->line_block + 3 * n + 2 * (j + 1);
        int k = (int)j + 2, limited = m->line_limits.count && m->line_limits.count[k] > 0;
        s->length = row->length != 0.0 ? row->length : row->stop;
        s->schedule = row->schedule;
        s->stop = row->stop;
        s->grade = m->span.grade;
        if (limited) {
            s->n_limits = (int)m->line_limits.count[k];
            s->limit_distances = m->line_limits.distances + m->line_limits.first[k];
            s->limit_speeds = m->line_limits.speeds + m->line_limits.first[k];
        } else {                                    /* ([0.0], [span.speed_limit]) */
            fallback[0] = 0.0;
            fallback[1] = m->real[NAT_VR_SPAN_SPEED_LIMIT];
            s->n_limits = 1;
            s->limit_distances = fallback;
            s->limit_speeds = fallback + 1;
        }
        m->line_block[j + 1] = row->dwell;
        m->line_block[n + j + 1] = row->boarding;
        if (!check_span(s, msg)) {
            char rows_of[64];
            snprintf(rows_of, sizeof rows_of, "line.speed_limit_profile span %d", k);
            fmu_names(msg, limited ? rows_of : NULL);
            {
                char reason[NAT_MSG_SIZE];
                memcpy(reason, msg, NAT_MSG_SIZE);
                nat_refuse(msg, "line.profile: %s: line %ld (span %d): %s", line_where,
                           row->line, k, reason);
            }
            goto refused_files;
        }
    }
    if (init_line(m, tuning, msg) != RC_OK) {
        char *end = NULL;
        long k = !strncmp(msg, "span ", 5) ? strtol(msg + 5, &end, 10) : 0;
        if (k <= 1 || !end || strncmp(end, ": ", 2) || k > n) {
            refuse_first_span(msg, from_profile);
        } else {                                    /* AtoController's refusal of span k */
            char reason[NAT_MSG_SIZE], rows_of[64];
            int limited = m->line_limits.count && m->line_limits.count[k] > 0;
            snprintf(reason, sizeof reason, "%s", end + 2);
            snprintf(rows_of, sizeof rows_of, "line.speed_limit_profile span %ld", k);
            fmu_names(reason, limited ? rows_of : NULL);
            nat_refuse(msg, "line.profile: %s: line %ld (span %ld): the ATO cannot run this "
                       "span: %s", line_where, rows[k - 2].line, k, reason);
        }
        goto done;
    }
    ok = 1;
    goto done;
refused_files:
    {                                               /* unless span 1's controller refuses */
        char first[NAT_MSG_SIZE];
        drop_spans(m);
        if (!alloc_line(m, 1, first)) {
            memcpy(msg, first, NAT_MSG_SIZE);
        } else if (init_line(m, tuning, first) == RC_OK) {
            ato_line_free(&m->line);                /* span 1 runs: the files' refusal stands */
        } else {
            memcpy(msg, first, NAT_MSG_SIZE);
            refuse_first_span(msg, from_profile);
        }
    }
done:
    free(rows);
    free(line_where);
    return ok;
}

/* _build: 1, or 0 with the refusal in msg */
static int build(GlueInstance *g, nat_instance *m, char *msg) {
    ato_tuning tuning;
    int from_profile = 0;
    double length;
    if (!check_span_parameters(g, m, msg) || !nat_read_grade(g, m, msg) ||
        !nat_read_limits(g, m, &from_profile, msg))
        return 0;
    length = m->real[NAT_VR_SPAN_LENGTH];
    m->span.stop = m->real[NAT_VR_SPAN_STOP];
    m->span.length = length != 0.0 ? length : m->span.stop;
    m->span.schedule = m->real[NAT_VR_SPAN_SCHEDULE];
    if (!check_span(&m->span, msg) || !read_car(m, &m->car, msg) || !read_tuning(m, &tuning, msg)) {
        fmu_names(msg, from_profile ? "span.speed_limit_profile" : NULL);
        return 0;
    }
    {
        rc_error err;
        if (ato_tuning_validate(&tuning, "ato.", &err) != RC_OK)
            return nat_refuse(msg, "%s", err.msg);
    }
    if (!build_line(g, m, &tuning, from_profile, msg)) return 0;
    m->built = 1;
    m->real[NAT_VR_ATO_PAYLOAD] = 0.0;
    m->integer[NAT_VR_ATO_SPAN] = 1;
    publish(m, 0.0, tuning.hold_brake * m->car.brake_force_max, ATO_MODE_HOLD, 0.0, 0);
    return 1;
}

fmi2Status model_exit_initialization_mode(GlueInstance *g) {
    nat_instance *m = MODEL(g);
    char msg[NAT_MSG_SIZE];
    msg[0] = '\0';
    nat_drop_line(m);
    memset(&m->span, 0, sizeof m->span);
    if (!build(g, m, msg)) {
        nat_drop_line(m);
        glue_log(g, fmi2Error, "logStatusError", "fmi2ExitInitializationMode: initialisation "
                 "failed: %s", msg);
        return fmi2Error;
    }
    m->time = m->start_time;
    return fmi2OK;
}

/* ------------------------------------------------------------------------- stepping */

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    nat_instance *m = MODEL(g);
    double inputs[ATO_N_ALL_INPUTS];
    char a[REPR_SIZE], b[REPR_SIZE];
    const ato_controller *c;
    ato_line_step step;
    int k;
    long e;
    if (!m->built) {
        glue_log(g, fmi2Error, "logStatusError", "doStep refused: the instance is not "
                 "initialised (call exitInitializationMode first; after a failed "
                 "initialisation, reset or free the instance)");
        return fmi2Error;
    }
    /* AtoController._check_step: models.chain.check_step, then the time continuing */
    if (!(isfinite(step_size) && step_size > 0.0)) {
        glue_log(g, fmi2Discard, "logStatusDiscard", "step discarded: communication step size "
                 "must be > 0 [s], got %s", repr(step_size, a));
        return fmi2Discard;
    }
    if (step_size > NAT_MAX_STEP) {
        glue_log(g, fmi2Discard, "logStatusDiscard", "step discarded: communication step size "
                 "must be <= 3600 s, got %s", repr(step_size, a));
        return fmi2Discard;
    }
    if (!isfinite(current_time)) {
        glue_log(g, fmi2Discard, "logStatusDiscard", "step discarded: current time must be "
                 "finite [s], got %s", repr(current_time, a));
        return fmi2Discard;
    }
    if (fabs(current_time - m->time) > 1e-9 * fmax(1.0, fabs(current_time))) {
        glue_log(g, fmi2Discard, "logStatusDiscard", "step discarded: current time %s s does "
                 "not continue the FMU's time %s s", repr(current_time, a), repr(m->time, b));
        return fmi2Discard;
    }
    for (k = 0; k < ATO_N_ALL_INPUTS; k++) {
        int vr = m->input_vr[k];
        inputs[k] = NAT_VARS[vr].type == GLUE_REAL ? m->real[vr] : (double)m->integer[vr];
    }
    step = ato_line_demands(&m->line, current_time, inputs,
                            (double)m->integer[NAT_VR_EST_STATION_STOPS]);
    m->real[NAT_VR_ATO_PAYLOAD] += step.payload_change;
    m->integer[NAT_VR_ATO_SPAN] = step.span + 1;
    publish(m, step.command.traction, step.command.brake, step.command.mode,
            step.command.planned_speed, step.command.ep_stage);
    for (k = 0; k < m->n_spans; k++) {     /* line.events(): span by span, in time order */
        char head[32] = "";
        c = &m->line.controllers[k];
        if (m->n_spans > 1) snprintf(head, sizeof head, "span %d: ", k + 1);
        if (c->n_events - m->logged[k] > ATO_EVENT_RING)
            glue_log(g, fmi2Warning, "logStatusWarning", "t = %.3f s: %s%ld events not logged "
                     "(more than %d in one step)", current_time, head,
                     c->n_events - m->logged[k] - ATO_EVENT_RING, ATO_EVENT_RING);
        for (e = m->logged[k]; e < c->n_events; e++) {
            const ato_event *ev = ato_controller_event(c, e);
            if (ev) glue_log(g, fmi2Warning, "logStatusWarning", "t = %.3f s: %s%s", ev->t, head,
                             ev->text);
        }
        m->logged[k] = c->n_events;
    }
    m->time = current_time + step_size;
    return step.command.mode == ATO_MODE_SAFE ? fmi2Warning : fmi2OK;
}
