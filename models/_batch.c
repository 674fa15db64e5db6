/* _batch.c -- the CPython binding of the C scenario runner (models/core/scenario_driver.h): many
 * whole scripted runs per call, each on its own C chain (models/core/railcar.h), without
 * returning to Python per step (issue 31). models/batch.py is its Python face.
 *
 * A module of its own beside models._railcar (which binds one chain for per-step use): it is
 * linked with the same core sources (setup.py), so it needs nothing from _railcar at run time.
 * The binding only converts: every run's float64 arrays are read through the buffer protocol
 * (no copies), all runs are checked before the first one starts, and the runs themselves go
 * with the GIL released (other Python threads of a worker keep running).
 *
 * It also binds the metrics of a recorded run that run a model again (models/core/run_metrics.h:
 * the oracle filter, the interval forces, the coasts and their re-run times), the same way: flat
 * float64 arrays in and out, every length checked and a wrong one named.
 *
 * Over 600 lines because it is one extension module with one shared set of buffer helpers: the
 * scripted runs, the span runs, the metrics and the service day each bind a different C entry
 * point, and splitting them into modules would duplicate the helpers and setup.py's source list.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "core/run_metrics.h"
#include "core/scenario_driver.h"
#include "core/service_day.h"
#include "core/span_driver.h"
#include "_status.h"


#define RUN_ARRAYS 6   /* config, grade_distances, grades, speed_distances, speeds, script */

static const char *const ARRAY_NAMES[RUN_ARRAYS] = {"config", "grade_distances", "grades",
                                                    "speed_distances", "speeds", "script"};

typedef struct {                 /* one run, parsed */
    Py_buffer view[RUN_ARRAYS];
    int held;                    /* views acquired */
    rc_chain_config cfg;
    rc_script script;
    int has_script;
    rc_span_script span;         /* run_spans' runs: the span script instead */
    int has_span;
    rc_span_output out;          /* the arrays the run writes (a scripted run: outputs and inputs only) */
    long rows;                   /* output rows written */
    int finished;
} Run;

static void release_runs(Run *runs, Py_ssize_t n)
{
    for (Py_ssize_t r = 0; r < n; r++) {
        for (int k = 0; k < runs[r].held; k++)
            PyBuffer_Release(&runs[r].view[k]);
        if (runs[r].has_script)
            rc_script_free(&runs[r].script);
        if (runs[r].has_span)
            rc_span_script_free(&runs[r].span);
        PyMem_Free(runs[r].out.log);
    }
    PyMem_Free(runs);
}

/* A C-contiguous float64 buffer of obj into view; -1 with a ValueError naming run and array */
static int double_buffer(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t run,
                         const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0) {
        PyErr_Clear();
        if (run >= 0)
            PyErr_Format(PyExc_ValueError, "run %zd: %s must be a C-contiguous float64 array",
                         run, what);
        else
            PyErr_Format(PyExc_ValueError, "%s must be a %sC-contiguous float64 array", what,
                         writable ? "writable " : "");
        return -1;
    }
    if (!view->format || strcmp(view->format, "d") != 0) {
        PyBuffer_Release(view);
        if (run >= 0)
            PyErr_Format(PyExc_ValueError, "run %zd: %s must be float64", run, what);
        else
            PyErr_Format(PyExc_ValueError, "%s must be float64", what);
        return -1;
    }
    return 0;
}

static long length(const Py_buffer *view) { return (long)(view->len / (Py_ssize_t)sizeof(double)); }

/* runs[r]'s chain from the tuple (config, grade_distances, grades, speed_distances, speeds,
 * script); -1 with ValueError naming the run */
static int parse_chain(PyObject *item, Run *run, Py_ssize_t r)
{
    if (!PyTuple_Check(item) || PyTuple_GET_SIZE(item) != RUN_ARRAYS) {
        PyErr_Format(PyExc_ValueError, "run %zd: expected a tuple of %d arrays (config, "
                     "grade_distances, grades, speed_distances, speeds, script)", r, RUN_ARRAYS);
        return -1;
    }
    for (int k = 0; k < RUN_ARRAYS; k++) {
        if (double_buffer(PyTuple_GET_ITEM(item, k), &run->view[k], 0, r, ARRAY_NAMES[k]) < 0)
            return -1;
        run->held++;
    }
    const double *values = run->view[0].buf;
    long expected = rc_chain_config_from_values(&run->cfg, values, length(&run->view[0]));
    if (expected) {
        PyErr_Format(PyExc_ValueError, "run %zd: config: the C core takes %ld configuration "
                     "values, got %ld", r, expected, length(&run->view[0]));
        return -1;
    }
    long ng = length(&run->view[1]), ns = length(&run->view[3]);
    if (ng < 1 || length(&run->view[2]) != ng || length(&run->view[4]) != ns) {
        PyErr_Format(PyExc_ValueError, "run %zd: a profile's distances and values must have one "
                     "length (the grade's >= 1)", r);
        return -1;
    }
    run->cfg.grade_distances = run->view[1].buf;
    run->cfg.grades = run->view[2].buf;
    run->cfg.grade_n = ng;
    run->cfg.speed_distances = run->view[3].buf;
    run->cfg.speeds = run->view[4].buf;
    run->cfg.speed_n = ns;
    return 0;
}

/* runs[r] from the tuple (config, grade_distances, grades, speed_distances, speeds, script); -1
 * with ValueError naming the run */
static int parse_run(PyObject *item, Run *run, Py_ssize_t r)
{
    if (parse_chain(item, run, r) < 0)
        return -1;
    rc_error err;
    if (rc_script_init(&run->script, run->view[5].buf, length(&run->view[5]), &err) != RC_OK) {
        PyErr_Format(PyExc_ValueError, "run %zd: %s", r, err.msg);
        return -1;
    }
    run->has_script = 1;
    return 0;
}

/* One call of many runs (run, run_spans): the runs' sequence, their parsed Runs, one chain
 * reused run after run and the writable arrays (outputs, inputs[, steps]) they fill */
#define CALL_ARRAYS 3

typedef struct {
    PyObject *fast;
    Py_ssize_t n;
    Run *runs;
    rc_chain *chain;
    Py_buffer view[CALL_ARRAYS];   /* outputs, inputs, steps */
    int held;
} RunsCall;

/* c from the runs' sequence and n_arrays writable float64 arrays; -1 with the error set (call
 * runs_call_close in any case) */
static int runs_call_open(RunsCall *c, PyObject *seq, PyObject *const *arrays, int n_arrays)
{
    static const char *const names[CALL_ARRAYS] = {"outputs", "inputs", "steps"};
    memset(c, 0, sizeof *c);
    c->fast = PySequence_Fast(seq, "runs must be a sequence of tuples");
    if (!c->fast)
        return -1;
    c->n = PySequence_Fast_GET_SIZE(c->fast);
    c->runs = PyMem_Calloc((size_t)(c->n > 0 ? c->n : 1), sizeof *c->runs);
    c->chain = PyMem_Malloc(sizeof *c->chain);
    if (!c->runs || !c->chain) {
        PyErr_NoMemory();
        return -1;
    }
    for (; c->held < n_arrays; c->held++)
        if (double_buffer(arrays[c->held], &c->view[c->held], 1, -1, names[c->held]) < 0)
            return -1;
    return 0;
}

static void runs_call_close(RunsCall *c)
{
    if (c->runs)
        release_runs(c->runs, c->n);
    PyMem_Free(c->chain);
    for (int k = 0; k < c->held; k++)
        PyBuffer_Release(&c->view[k]);
    Py_XDECREF(c->fast);
}

/* Every run of c through one(run, chain, err) on a chain set up for it, the GIL released; the
 * first refusal stops them: -1 with it raised as "run r: ..." (status_exception) */
static int runs_call_each(RunsCall *c, rc_status (*one)(Run *, rc_chain *, rc_error *),
                          PyObject *error)
{
    rc_status st = RC_OK;
    Py_ssize_t failed = -1;
    rc_error err;
    err.msg[0] = '\0';
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < c->n && st == RC_OK; r++) {
        st = rc_chain_init(c->chain, &c->runs[r].cfg, &err);
        if (st != RC_OK) {
            failed = r;
            break;
        }
        st = one(&c->runs[r], c->chain, &err);
        rc_chain_free(c->chain);
        if (st != RC_OK)
            failed = r;
    }
    Py_END_ALLOW_THREADS
    if (st != RC_OK) {
        PyErr_Format(status_exception(st, error), "run %zd: %s", failed, err.msg);
        return -1;
    }
    return 0;
}

static rc_status script_run_one(Run *run, rc_chain *chain, rc_error *err)
{
    return rc_script_run(&run->script, chain, run->out.outputs, run->out.inputs, &run->rows,
                         &run->finished, err);
}

static rc_status span_run_one(Run *run, rc_chain *chain, rc_error *err)
{
    return rc_span_run(&run->span, chain, &run->out, err);
}

/* run(runs, outputs, inputs, error) -> [(rows, finished), ...] */
static PyObject *batch_run(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *seq, *arrays[2], *error;
    if (!PyArg_ParseTuple(args, "OOOO:run", &seq, &arrays[0], &arrays[1], &error))
        return NULL;
    if (!PyExceptionClass_Check(error)) {
        PyErr_SetString(PyExc_TypeError, "error must be an exception class");
        return NULL;
    }
    RunsCall c;
    PyObject *result = NULL;
    if (runs_call_open(&c, seq, arrays, 2) < 0)
        goto done;
    Py_ssize_t n = c.n;
    const Py_buffer *out = &c.view[0], *in = &c.view[1];
    /* outputs: n x (steps + 1) x RC_CHAIN_OUTPUTS, inputs: n x steps x RC_SCRIPT_INPUTS */
    Py_ssize_t out_rows = n ? length(out) / (n * RC_CHAIN_OUTPUTS) : 0;
    Py_ssize_t in_rows = n ? length(in) / (n * RC_SCRIPT_INPUTS) : 0;
    if (n && (length(out) != n * out_rows * RC_CHAIN_OUTPUTS
              || length(in) != n * in_rows * RC_SCRIPT_INPUTS || out_rows != in_rows + 1)) {
        PyErr_Format(PyExc_ValueError, "outputs must be runs x (steps + 1) x %d and inputs runs x "
                     "steps x %d float64 (%zd runs), got %zd and %zd values", RC_CHAIN_OUTPUTS,
                     RC_SCRIPT_INPUTS, n, (Py_ssize_t)length(out), (Py_ssize_t)length(in));
        goto done;
    }
    for (Py_ssize_t r = 0; r < n; r++) {
        Run *run = &c.runs[r];
        if (parse_run(PySequence_Fast_GET_ITEM(c.fast, r), run, r) < 0)
            goto done;
        if (run->script.steps > in_rows) {
            PyErr_Format(PyExc_ValueError, "run %zd: %ld steps, the arrays have room for %zd",
                         r, run->script.steps, in_rows);
            goto done;
        }
        run->out.outputs = (double *)out->buf + r * out_rows * RC_CHAIN_OUTPUTS;
        run->out.inputs = (double *)in->buf + r * in_rows * RC_SCRIPT_INPUTS;
    }
    if (runs_call_each(&c, script_run_one, error) < 0)
        goto done;
    result = PyList_New(n);
    for (Py_ssize_t r = 0; result && r < n; r++) {
        PyObject *pair = Py_BuildValue("(lO)", c.runs[r].rows, c.runs[r].finished ? Py_True : Py_False);
        if (!pair)
            Py_CLEAR(result);
        else
            PyList_SET_ITEM(result, r, pair);
    }
done:
    runs_call_close(&c);
    return result;
}

/* run_spans(runs, outputs, inputs, steps, log_cap, error) -> [(rows, finished, calls, log_lines,
 * [line, ...]), ...]: whole span runs (span_driver.h), each run's tuple (config, grade_distances,
 * grades, speed_distances, speeds, span_script); outputs runs x (steps + 1) x OUTPUTS, inputs
 * runs x steps x INPUTS, steps runs x steps x SPAN_STEP_FIELDS; at most log_cap log lines kept a
 * run (log_lines counts them all) */
static PyObject *batch_run_spans(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *seq, *arrays[3], *error;
    long log_cap;
    if (!PyArg_ParseTuple(args, "OOOOlO:run_spans", &seq, &arrays[0], &arrays[1], &arrays[2],
                          &log_cap, &error))
        return NULL;
    if (!PyExceptionClass_Check(error)) {
        PyErr_SetString(PyExc_TypeError, "error must be an exception class");
        return NULL;
    }
    if (log_cap < 0 || log_cap > 100000) {
        PyErr_Format(PyExc_ValueError, "log_cap must be in 0..100000, got %ld", log_cap);
        return NULL;
    }
    RunsCall c;
    PyObject *result = NULL;
    if (runs_call_open(&c, seq, arrays, 3) < 0)
        goto done;
    Py_ssize_t n = c.n;
    const Py_buffer *out = &c.view[0], *in = &c.view[1], *steps = &c.view[2];
    Py_ssize_t out_rows = n ? length(out) / (n * RC_CHAIN_OUTPUTS) : 0;
    Py_ssize_t in_rows = n ? length(in) / (n * RC_SPAN_INPUTS) : 0;
    if (n && (length(out) != n * out_rows * RC_CHAIN_OUTPUTS
              || length(in) != n * in_rows * RC_SPAN_INPUTS || out_rows != in_rows + 1
              || length(steps) != n * in_rows * RC_SPAN_STEP_FIELDS)) {
        PyErr_Format(PyExc_ValueError, "outputs must be runs x (steps + 1) x %d, inputs runs x "
                     "steps x %d and steps runs x steps x %d float64 (%zd runs), got %zd, %zd and "
                     "%zd values", RC_CHAIN_OUTPUTS, RC_SPAN_INPUTS, RC_SPAN_STEP_FIELDS, n,
                     (Py_ssize_t)length(out), (Py_ssize_t)length(in),
                     (Py_ssize_t)length(steps));
        goto done;
    }
    for (Py_ssize_t r = 0; r < n; r++) {
        Run *run = &c.runs[r];
        if (parse_chain(PySequence_Fast_GET_ITEM(c.fast, r), run, r) < 0)
            goto done;
        rc_error err;
        if (rc_span_script_init(&run->span, run->view[5].buf, length(&run->view[5]), &err) != RC_OK) {
            PyErr_Format(PyExc_ValueError, "run %zd: %s", r, err.msg);
            goto done;
        }
        run->has_span = 1;
        if (run->span.steps > in_rows) {
            PyErr_Format(PyExc_ValueError, "run %zd: %ld steps, the arrays have room for %zd",
                         r, run->span.steps, in_rows);
            goto done;
        }
        run->out.outputs = (double *)out->buf + r * out_rows * RC_CHAIN_OUTPUTS;
        run->out.inputs = (double *)in->buf + r * in_rows * RC_SPAN_INPUTS;
        run->out.steps = (double *)steps->buf + r * in_rows * RC_SPAN_STEP_FIELDS;
        run->out.log_cap = log_cap;
        run->out.log = PyMem_Malloc((size_t)(log_cap > 0 ? log_cap : 1) * RC_SPAN_LOG_SIZE);
        if (!run->out.log) {
            PyErr_NoMemory();
            goto done;
        }
    }
    if (runs_call_each(&c, span_run_one, error) < 0)
        goto done;
    result = PyList_New(n);
    for (Py_ssize_t r = 0; result && r < n; r++) {
        const rc_span_output *o = &c.runs[r].out;
        long kept = o->log_lines < log_cap ? o->log_lines : log_cap;
        PyObject *lines = PyList_New(kept);
        for (long k = 0; lines && k < kept; k++) {
            PyObject *line = PyUnicode_FromString(o->log + RC_SPAN_LOG_SIZE * k);
            if (!line)
                Py_CLEAR(lines);
            else
                PyList_SET_ITEM(lines, k, line);
        }
        PyObject *row = lines ? Py_BuildValue("(lOllN)", o->rows, o->finished ? Py_True : Py_False,
                                              o->calls, o->log_lines, lines) : NULL;
        if (!row)
            Py_CLEAR(result);
        else
            PyList_SET_ITEM(result, r, row);
    }
done:
    runs_call_close(&c);
    return result;
}

/* ------------------------------------------------------------------ run metrics */

#define VEHICLE_VALUES 11        /* rc_vehicle's fields, models.plant.dynamics.VehicleParams' order */
#define COAST_VALUES 8           /* per coast: v0, x0, x1, A0, A1, A2, mass, t0 */
#define MAX_VIEWS 16

typedef struct {                 /* the buffers of one call, released together */
    Py_buffer view[MAX_VIEWS];
    int held;
} Views;

static void release_views(Views *v)
{
    for (int k = 0; k < v->held; k++)
        PyBuffer_Release(&v->view[k]);
    v->held = 0;
}

/* The next view: obj as a C-contiguous float64 array of `count` values (count < 0: any), or
 * NULL with a ValueError naming it */
static double *take(Views *v, PyObject *obj, int writable, const char *name, long count)
{
    Py_buffer *view = &v->view[v->held];
    if (double_buffer(obj, view, writable, -1, name) < 0)
        return NULL;
    v->held++;
    if (count >= 0 && length(view) != count) {
        PyErr_Format(PyExc_ValueError, "%s: expected %ld values, got %ld", name, count, length(view));
        return NULL;
    }
    return view->buf;
}

static long taken_length(const Views *v) { return length(&v->view[v->held - 1]); }

static void vehicle_from_values(rc_vehicle *p, const double *x)
{
    double *f[VEHICLE_VALUES] = {&p->mass, &p->A0, &p->A1, &p->A2, &p->gamma, &p->length,
                                 &p->traction_force_max, &p->traction_power_max,
                                 &p->brake_force_max, &p->adhesion_mass_fraction,
                                 &p->adhesion_factor};
    for (int k = 0; k < VEHICLE_VALUES; k++)
        *f[k] = x[k];
}

/* interval_forces(vehicle, speed, mass, traction_demand, brake_demand, traction_mean, brake_mean) */
static PyObject *batch_interval_forces(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *o[7];
    if (!PyArg_ParseTuple(args, "OOOOOOO:interval_forces", &o[0], &o[1], &o[2], &o[3], &o[4],
                          &o[5], &o[6]))
        return NULL;
    Views v = {.held = 0};
    PyObject *result = NULL;
    const double *vehicle, *speed, *mass, *td, *bd;
    double *f_mean, *b_mean;
    if (!(vehicle = take(&v, o[0], 0, "vehicle", VEHICLE_VALUES)) || !(speed = take(&v, o[1], 0, "speed", -1)))
        goto done;
    long n = taken_length(&v), intervals = n > 0 ? n - 1 : 0;
    if (!(mass = take(&v, o[2], 0, "mass", n)) || !(td = take(&v, o[3], 0, "traction_demand", -1)))
        goto done;
    if (taken_length(&v) < intervals) {
        PyErr_Format(PyExc_ValueError, "traction_demand: expected at least %ld values, got %ld",
                     intervals, taken_length(&v));
        goto done;
    }
    if (!(bd = take(&v, o[4], 0, "brake_demand", taken_length(&v)))
            || !(f_mean = take(&v, o[5], 1, "traction_mean", intervals))
            || !(b_mean = take(&v, o[6], 1, "brake_mean", intervals)))
        goto done;
    rc_vehicle car;
    vehicle_from_values(&car, vehicle);
    Py_BEGIN_ALLOW_THREADS
    rc_interval_forces(&car, n, speed, mass, td, bd, f_mean, b_mean);
    Py_END_ALLOW_THREADS
    Py_INCREF(Py_None);
    result = Py_None;
done:
    release_views(&v);
    return result;
}

/* oracle_filter(config, grade_distances, grades, speed_distances, speeds, A, step, wind, time,
 * mass, speed_meas, position_meas, traction_mean, brake_mean, v_out, x_out) */
static PyObject *batch_oracle_filter(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *o[16];
    double step;
    if (!PyArg_ParseTuple(args, "OOOOOOdOOOOOOOOO:oracle_filter", &o[0], &o[1], &o[2], &o[3],
                          &o[4], &o[5], &step, &o[7], &o[8], &o[9], &o[10], &o[11], &o[12],
                          &o[13], &o[14], &o[15]))
        return NULL;
    Views v = {.held = 0};
    PyObject *result = NULL;
    rc_oracle_config cfg;
    memset(&cfg, 0, sizeof cfg);
    const double *values, *A, *time, *mass, *vm, *xm, *f_mean, *b_mean;
    double *v_out, *x_out;
    if (!(values = take(&v, o[0], 0, "config", -1)))
        goto done;
    long expected = rc_estchain_config_from_values(&cfg.est, values, taken_length(&v));
    if (expected) {
        PyErr_Format(PyExc_ValueError, "config: the oracle takes %ld configuration values "
                     "(EstimatorChain's), got %ld", expected, taken_length(&v));
        goto done;
    }
    if (!(cfg.est.grade_distances = take(&v, o[1], 0, "grade_distances", -1)))
        goto done;
    cfg.est.grade_n = taken_length(&v);
    if (!(cfg.est.grades = take(&v, o[2], 0, "grades", cfg.est.grade_n))
            || !(cfg.est.speed_distances = take(&v, o[3], 0, "speed_distances", -1)))
        goto done;
    cfg.est.speed_n = taken_length(&v);
    if (!(cfg.est.speeds = take(&v, o[4], 0, "speeds", cfg.est.speed_n))
            || !(A = take(&v, o[5], 0, "A", 3)) || !(cfg.wind = take(&v, o[7], 0, "wind", -1)))
        goto done;
    if (taken_length(&v) % 2) {
        PyErr_Format(PyExc_ValueError, "wind: expected (time_s, speed_mps) pairs, got %ld values",
                     taken_length(&v));
        goto done;
    }
    cfg.wind_n = taken_length(&v) / 2;
    memcpy(cfg.A, A, sizeof cfg.A);
    cfg.step = step;
    if (!(time = take(&v, o[8], 0, "time", -1)))
        goto done;
    long n = taken_length(&v), intervals = n > 0 ? n - 1 : 0;
    if (n < 1) {
        PyErr_SetString(PyExc_ValueError, "time: a run has at least one row, got none");
        goto done;
    }
    if (!(mass = take(&v, o[9], 0, "mass", n)) || !(vm = take(&v, o[10], 0, "speed_meas", n))
            || !(xm = take(&v, o[11], 0, "position_meas", n))
            || !(f_mean = take(&v, o[12], 0, "traction_mean", intervals))
            || !(b_mean = take(&v, o[13], 0, "brake_mean", intervals))
            || !(v_out = take(&v, o[14], 1, "v_out", n)) || !(x_out = take(&v, o[15], 1, "x_out", n)))
        goto done;
    rc_error err;
    rc_status st;
    Py_BEGIN_ALLOW_THREADS
    st = rc_oracle_filter(&cfg, n, time, mass, vm, xm, f_mean, b_mean, v_out, x_out, &err);
    Py_END_ALLOW_THREADS
    if (st != RC_OK) {
        PyErr_Format(PyExc_ValueError, "oracle: %s", err.msg);
        goto done;
    }
    Py_INCREF(Py_None);
    result = Py_None;
done:
    release_views(&v);
    return result;
}

/* coast_segments(mode, min_rows) -> [(first, last), ...] */
static PyObject *batch_coast_segments(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *mode_obj;
    long min_rows;
    if (!PyArg_ParseTuple(args, "Ol:coast_segments", &mode_obj, &min_rows))
        return NULL;
    Views v = {.held = 0};
    PyObject *result = NULL;
    long *rows = NULL;
    const double *mode = take(&v, mode_obj, 0, "mode", -1);
    if (!mode)
        goto done;
    long n = taken_length(&v), room = n / 2 + 1;
    rows = PyMem_Malloc(2 * (size_t)room * sizeof *rows);
    if (!rows) {
        PyErr_NoMemory();
        goto done;
    }
    long count = rc_coast_segments(mode, n, min_rows, rows, rows + room);
    result = PyList_New(count);
    for (long k = 0; result && k < count; k++) {
        PyObject *pair = Py_BuildValue("(ll)", rows[k], rows[room + k]);
        if (!pair)
            Py_CLEAR(result);
        else
            PyList_SET_ITEM(result, k, pair);
    }
done:
    PyMem_Free(rows);
    release_views(&v);
    return result;
}

/* coast_times(vehicle, grade_distances, grades, wind, h, t_max, coasts, out) */
static PyObject *batch_coast_times(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *o[8];
    double h, t_max;
    if (!PyArg_ParseTuple(args, "OOOOddOO:coast_times", &o[0], &o[1], &o[2], &o[3], &h, &t_max,
                          &o[6], &o[7]))
        return NULL;
    Views v = {.held = 0};
    PyObject *result = NULL;
    double *profiles = NULL;
    const double *vehicle, *gd, *grades, *wind, *coasts;
    double *out;
    if (!(vehicle = take(&v, o[0], 0, "vehicle", VEHICLE_VALUES))
            || !(gd = take(&v, o[1], 0, "grade_distances", -1)))
        goto done;
    long ng = taken_length(&v);
    if (ng < 1) {
        PyErr_SetString(PyExc_ValueError, "grade_distances: the grade profile needs at least one row");
        goto done;
    }
    if (!(grades = take(&v, o[2], 0, "grades", ng)) || !(wind = take(&v, o[3], 0, "wind", -1)))
        goto done;
    long nw = taken_length(&v);
    if (nw % 2) {
        PyErr_Format(PyExc_ValueError, "wind: expected (time_s, speed_mps) pairs, got %ld values", nw);
        goto done;
    }
    if (!(h > 0.0 && isfinite(h))) {
        PyErr_Format(PyExc_ValueError, "h: the RK4 step must be > 0 and finite, got %R",
                     PyTuple_GET_ITEM(args, 4));
        goto done;
    }
    if (!(coasts = take(&v, o[6], 0, "coasts", -1)))
        goto done;
    long nc = taken_length(&v);
    if (nc % COAST_VALUES) {
        PyErr_Format(PyExc_ValueError, "coasts: expected rows of %d values (v0, x0, x1, A0, A1, A2, "
                     "mass, t0), got %ld values", COAST_VALUES, nc);
        goto done;
    }
    if (!(out = take(&v, o[7], 1, "out", nc / COAST_VALUES)))
        goto done;
    rc_grade_profile grade;
    rc_speed_profile none;
    if (rc_profiles_copy(gd, grades, ng, NULL, NULL, 0, &profiles, &grade, &none) != 0) {
        PyErr_NoMemory();
        goto done;
    }
    rc_vehicle car;
    vehicle_from_values(&car, vehicle);
    Py_BEGIN_ALLOW_THREADS
    for (long k = 0; k < nc / COAST_VALUES; k++) {
        const double *c = coasts + COAST_VALUES * k;
        rc_vehicle p = car;
        p.A0 = c[3];
        p.A1 = c[4];
        p.A2 = c[5];
        p.mass = c[6];
        out[k] = rc_coast_time(&p, &grade, c[0], c[1], c[2], wind, nw / 2, c[7], h, t_max);
    }
    Py_END_ALLOW_THREADS
    Py_INCREF(Py_None);
    result = Py_None;
done:
    free(profiles);
    release_views(&v);
    return result;
}

/* ------------------------------------------------------------------ the service day
 * studies/service_day.py's run_day loop in C (models/core/service_day.h): service_day(...) builds
 * a ServiceDay (its flat float64 arrays checked, copied), whose run(steps, draws) runs a block of
 * steps with the GIL released and whose export() gives the figures so far (a float64 bytearray
 * in service_day.h's export layout). models/batch.py's ServiceDay is its Python face. */

typedef struct {
    PyObject_HEAD
    rc_service_day *day;         /* NULL after a failed set-up */
    PyObject *error;             /* the class a chain's refusal raises (StepRejected) */
    int busy;                    /* a run is under way in another thread */
} ServiceDayObject;

static void service_day_dealloc(ServiceDayObject *self)
{
    if (self->day) {
        rc_service_day_free(self->day);
        PyMem_Free(self->day);
    }
    Py_XDECREF(self->error);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

/* run(steps, draws) -> draws used: the next steps of the day; draws a float64 array of the
 * driver's Generator.random() doubles. ValueError naming a short supply or the day's end (the
 * steps before it done), error (StepRejected) or ArithmeticError (RC_MATH) naming a step refused
 * mid-way, after which the day is stopped (ValueError "the day stopped at step k: ..."). */
static PyObject *service_day_run(ServiceDayObject *self, PyObject *args)
{
    long steps;
    PyObject *draws_obj;
    if (!PyArg_ParseTuple(args, "lO:run", &steps, &draws_obj))
        return NULL;
    if (self->busy) {
        PyErr_SetString(PyExc_RuntimeError, "ServiceDay.run: already running in another thread");
        return NULL;
    }
    Py_buffer draws;
    if (double_buffer(draws_obj, &draws, 0, -1, "draws") < 0)
        return NULL;
    long used = 0;
    rc_error err;
    rc_status st;
    self->busy = 1;
    Py_BEGIN_ALLOW_THREADS
    st = rc_service_day_run(self->day, steps, draws.buf, length(&draws), &used, &err);
    Py_END_ALLOW_THREADS
    self->busy = 0;
    PyBuffer_Release(&draws);
    if (st != RC_OK) {
        PyErr_Format(status_exception(st, self->error), "service day: %s", err.msg);
        return NULL;
    }
    return PyLong_FromLong(used);
}

/* export() -> bytearray of float64: the figures so far (service_day.h's export layout).
 * RuntimeError while a run is under way in another thread (it moves the figures unlocked). */
static PyObject *service_day_export(ServiceDayObject *self, PyObject *Py_UNUSED(ignored))
{
    if (self->busy) {
        PyErr_SetString(PyExc_RuntimeError, "ServiceDay.export: a run is under way in another thread");
        return NULL;
    }
    long n = rc_service_day_export(self->day, NULL, 0);
    PyObject *out = PyByteArray_FromStringAndSize(NULL, (Py_ssize_t)n * (Py_ssize_t)sizeof(double));
    if (!out)
        return NULL;
    long written = rc_service_day_export(self->day, (double *)(void *)PyByteArray_AS_STRING(out), n);
    if (written != n) {
        Py_DECREF(out);
        PyErr_Format(PyExc_RuntimeError, "ServiceDay.export: the figures' size changed from %ld to "
                     "%ld values between the size and the copy", n, written);
        return NULL;
    }
    return out;
}

static PyMethodDef service_day_methods[] = {
    {"run", (PyCFunction)service_day_run, METH_VARARGS,
     "run(steps, draws) -> draws used: the next steps of the day (the GIL released)"},
    {"export", (PyCFunction)service_day_export, METH_NOARGS,
     "export() -> bytearray of float64: the figures so far (models/core/service_day.h)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject ServiceDayType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "models._batch.ServiceDay",
    .tp_basicsize = sizeof(ServiceDayObject),
    .tp_dealloc = (destructor)service_day_dealloc,
    .tp_flags = Py_TPFLAGS_DEFAULT,
    .tp_doc = "studies/service_day.py's day in C: run(steps, draws), export()",
    .tp_methods = service_day_methods,
};

#define SERVICE_DAY_ARRAYS 7

static PyObject *batch_service_day(PyObject *Py_UNUSED(module), PyObject *args)
{
    static const char *const names[SERVICE_DAY_ARRAYS] = {"day", "plant", "est", "grade_distances",
                                                          "grade_values", "wind", "faults"};
    PyObject *objs[SERVICE_DAY_ARRAYS], *error;
    if (!PyArg_ParseTuple(args, "OOOOOOOO:service_day", &objs[0], &objs[1], &objs[2], &objs[3],
                          &objs[4], &objs[5], &objs[6], &error))
        return NULL;
    if (!PyExceptionClass_Check(error)) {
        PyErr_SetString(PyExc_TypeError, "error must be an exception class");
        return NULL;
    }
    if (!(ServiceDayType.tp_flags & Py_TPFLAGS_READY) && PyType_Ready(&ServiceDayType) < 0)
        return NULL;
    Py_buffer v[SERVICE_DAY_ARRAYS];
    int held = 0;
    ServiceDayObject *self = NULL;
    for (; held < SERVICE_DAY_ARRAYS; held++)
        if (double_buffer(objs[held], &v[held], 0, -1, names[held]) < 0)
            goto done;
    long n_grade = length(&v[3]), n_wind = length(&v[5]), n_faults = length(&v[6]);
    if (length(&v[4]) != n_grade || n_wind % 2 || n_faults % 3) {
        PyErr_SetString(PyExc_ValueError, "service_day: grade_values must have grade_distances' "
                        "length, wind (time, speed) pairs and faults (step, kind, value) rows");
        goto done;
    }
    self = PyObject_New(ServiceDayObject, &ServiceDayType);
    if (!self)
        goto done;
    self->error = Py_NewRef(error);
    self->busy = 0;
    self->day = PyMem_Malloc(sizeof *self->day);
    if (!self->day) {
        PyErr_NoMemory();
        Py_CLEAR(self);
        goto done;
    }
    rc_error err;
    if (rc_service_day_init(self->day, v[0].buf, length(&v[0]), v[1].buf, length(&v[1]), v[2].buf,
                            length(&v[2]), v[3].buf, v[4].buf, n_grade, v[5].buf, n_wind / 2,
                            v[6].buf, n_faults / 3, &err) != RC_OK) {
        PyMem_Free(self->day);
        self->day = NULL;
        PyErr_Format(PyExc_ValueError, "service_day: %s", err.msg);
        Py_CLEAR(self);
    }
done:
    for (int k = 0; k < held; k++)
        PyBuffer_Release(&v[k]);
    return (PyObject *)self;
}


static PyMethodDef methods[] = {
    {"run", batch_run, METH_VARARGS,
     "run(runs, outputs, inputs, error) -> [(rows, finished), ...]: whole scripted runs; each run "
     "a tuple of float64 arrays (config, grade_distances, grades, speed_distances, speeds, "
     "script); outputs runs x (steps + 1) x OUTPUTS, inputs runs x steps x INPUTS; a rejected "
     "step raises error naming the run and the step"},
    {"run_spans", batch_run_spans, METH_VARARGS,
     "run_spans(runs, outputs, inputs, steps, log_cap, error) -> [(rows, finished, calls, "
     "log_lines, [line, ...]), ...]: whole span runs (the ATO drives); each run a tuple of float64 "
     "arrays (config, grade_distances, grades, speed_distances, speeds, span_script); steps runs x "
     "steps x SPAN_STEP_FIELDS (one row per ATO call)"},
    {"interval_forces", batch_interval_forces, METH_VARARGS,
     "interval_forces(vehicle, speed, mass, traction_demand, brake_demand, traction_mean, "
     "brake_mean): harness.metrics.estimation._interval_forces with recorded demands"},
    {"oracle_filter", batch_oracle_filter, METH_VARARGS,
     "oracle_filter(config, grade_distances, grades, speed_distances, speeds, A, step, wind, time, "
     "mass, speed_meas, position_meas, traction_mean, brake_mean, v_out, x_out): "
     "harness.metrics.estimation.oracle_filter's loop"},
    {"coast_segments", batch_coast_segments, METH_VARARGS,
     "coast_segments(mode, min_rows) -> [(first, last), ...]: harness.metrics.estimation.coast_segments"},
    {"coast_times", batch_coast_times, METH_VARARGS,
     "coast_times(vehicle, grade_distances, grades, wind, h, t_max, coasts, out): "
     "harness.metrics.estimation.coast_time of each coast row (v0, x0, x1, A0, A1, A2, mass, t0)"},
    {"service_day", batch_service_day, METH_VARARGS,
     "service_day(day, plant, est, grade_distances, grade_values, wind, faults, error) -> "
     "ServiceDay: studies/service_day.py's day in C (models/core/service_day.h), run in blocks"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "models._batch",
    "Whole scripted runs in the C core (models/core/scenario_driver.h): see models/batch.py.", -1,
    methods, NULL, NULL, NULL, NULL,
};

/* SERVICE_DAY_EXPORT_OFFSETS and SERVICE_DAY_SCORE_OFFSETS: {name: index} of service_day.h's
 * export layout (RC_SD_X_*, RC_SD_S_*), so that models/batch.py reads the export by name */
static int add_offsets(PyObject *m, const char *attr, const char *const *names, const int *at, int n)
{
    PyObject *d = PyDict_New();
    if (!d)
        return -1;
    for (int i = 0; i < n; i++) {
        PyObject *v = PyLong_FromLong(at[i]);
        if (!v || PyDict_SetItemString(d, names[i], v) < 0) {
            Py_XDECREF(v);
            Py_DECREF(d);
            return -1;
        }
        Py_DECREF(v);
    }
    if (PyModule_AddObject(m, attr, d) < 0) {
        Py_DECREF(d);
        return -1;
    }
    return 0;
}

static int add_service_day_offsets(PyObject *m)
{
    static const char *const x_names[] = {"steps_done", "stops", "long_cruises", "cruise_s",
        "distance_m", "moving_steps", "mass_min", "mass_max", "faults", "rejected"};
    static const int x_at[] = {RC_SD_X_STEPS_DONE, RC_SD_X_STOPS, RC_SD_X_LONG_CRUISES,
        RC_SD_X_CRUISE_S, RC_SD_X_DISTANCE, RC_SD_X_MOVING_STEPS, RC_SD_X_MASS_MIN, RC_SD_X_MASS_MAX,
        RC_SD_X_FAULTS, RC_SD_X_REJECTED};
    static const char *const s_names[] = {"nonfinite", "has_first", "first_t", "first_output",
        "sigma_in", "sigma_n", "se_all", "n_all", "has_rejected", "rejected_last", "rejected_max",
        "hour_len", "n_stops", "n_status", "n_outputs"};
    static const int s_at[] = {RC_SD_S_NONFINITE, RC_SD_S_HAS_FIRST, RC_SD_S_FIRST_T,
        RC_SD_S_FIRST_OUTPUT, RC_SD_S_SIGMA_IN, RC_SD_S_SIGMA_N, RC_SD_S_SE_ALL, RC_SD_S_N_ALL,
        RC_SD_S_HAS_REJECTED, RC_SD_S_REJECTED_LAST, RC_SD_S_REJECTED_MAX, RC_SD_S_HOUR_LEN,
        RC_SD_S_N_STOPS, RC_SD_S_N_STATUS, RC_SD_S_N_OUTPUTS};
    enum { X_N = sizeof x_at / sizeof x_at[0], S_N = sizeof s_at / sizeof s_at[0] };
    return add_offsets(m, "SERVICE_DAY_EXPORT_OFFSETS", x_names, x_at, X_N) < 0
        ? -1 : add_offsets(m, "SERVICE_DAY_SCORE_OFFSETS", s_names, s_at, S_N);
}

PyMODINIT_FUNC PyInit__batch(void)
{
    PyObject *m = PyModule_Create(&module);
    if (!m)
        return NULL;
    if (PyModule_AddIntConstant(m, "OUTPUTS", RC_CHAIN_OUTPUTS) < 0
            || PyModule_AddIntConstant(m, "INPUTS", RC_SCRIPT_INPUTS) < 0
            || PyModule_AddIntConstant(m, "HEADER", RC_SCRIPT_HEADER) < 0
            || PyModule_AddIntConstant(m, "PHASE_FIELDS", RC_PHASE_FIELDS) < 0
            || PyModule_AddIntConstant(m, "MAX_STEPS", RC_SCRIPT_MAX_STEPS) < 0
            || PyModule_AddIntConstant(m, "VEHICLE_VALUES", VEHICLE_VALUES) < 0
            || PyModule_AddIntConstant(m, "COAST_VALUES", COAST_VALUES) < 0
            || PyModule_AddIntConstant(m, "SPAN_HEADER", RC_SPAN_HEADER) < 0
            || PyModule_AddIntConstant(m, "SPAN_STEP_FIELDS", RC_SPAN_STEP_FIELDS) < 0
            || PyModule_AddIntConstant(m, "SPAN_TUNING_FIELDS", ATO_N_TUNING_FIELDS) < 0
            || PyModule_AddIntConstant(m, "SPAN_STATION_STOPS", RC_SPAN_STATION_STOPS) < 0
            || PyModule_AddIntConstant(m, "SERVICE_DAY_VALUES", RC_SD_DAY_VALUES) < 0
            || PyModule_AddIntConstant(m, "SERVICE_DAY_EXPORT_FIXED", RC_SD_X_DAY) < 0
            || PyModule_AddIntConstant(m, "SERVICE_DAY_SCORE_FIXED", RC_SD_S_FIXED) < 0
            || PyModule_AddIntConstant(m, "SERVICE_DAY_DRAWS_PER_STEP", RC_SD_DRAWS_PER_STEP) < 0
            || add_service_day_offsets(m) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
