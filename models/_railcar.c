/* _railcar.c -- the thin CPython binding of the C model core (models/core/railcar.h).
 *
 * One type, Chain, owns one rc_chain (allocated once; the struct points into itself). It is
 * subclassed by models.compiled.CompiledChain, which gives it RailCarChain's interface. Estimator
 * does the same for RailCarEstimator's chain; the function ato_closed_loop runs whole ATO
 * closed-loop spans (models/core/ato_closed_loop.h), one call per list of seeds. The
 * binding only converts: numbers in, numbers out, the core's messages raised as the exception
 * type given at construction. Why a hand-written extension and not cffi or ctypes: the per-step
 * call is the hot path (three times the old compiled path is the target), cffi would be a new
 * dependency, and ctypes costs microseconds per call; the extension is ~300 lines of plain
 * argument conversion.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "core/ato_closed_loop.h"
#include "core/railcar.h"
#include "_status.h"

/* A sequence of numbers into a new malloc'd array of doubles (*n its length) */
static double *doubles(PyObject *seq, Py_ssize_t *n, const char *what)
{
    PyObject *fast = PySequence_Fast(seq, what);
    if (!fast)
        return NULL;
    *n = PySequence_Fast_GET_SIZE(fast);
    double *out = PyMem_Malloc(sizeof(double) * (size_t)(*n > 0 ? *n : 1));
    if (!out) {
        Py_DECREF(fast);
        PyErr_NoMemory();
        return NULL;
    }
    for (Py_ssize_t k = 0; k < *n; k++) {
        out[k] = PyFloat_AsDouble(PySequence_Fast_GET_ITEM(fast, k));
        if (out[k] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(fast);
            PyMem_Free(out);
            return NULL;
        }
    }
    Py_DECREF(fast);
    return out;
}

/* What Chain(...) and Estimator(...) are made of: the flat configuration, the profiles (copied
 * into new arrays, freed by free_init) and the output names, integer flags and error type
 * (borrowed references) */
typedef struct {
    double *values, *gd, *gg, *sd, *sv;
    Py_ssize_t n_values, n_grade, n_speed;
    PyObject *names, *integers, *error;
} InitArgs;

static void free_init(InitArgs *in)
{
    PyMem_Free(in->values);
    PyMem_Free(in->gd);
    PyMem_Free(in->gg);
    PyMem_Free(in->sd);
    PyMem_Free(in->sv);
}

/* Parse (config, grade_distances, grades, speed_distances, speeds, names, integers, error) for
 * a type with `outputs` outputs; -1 with an exception (nothing left to free) */
static int parse_init(PyObject *args, PyObject *kwds, const char *format, int outputs,
                      InitArgs *in)
{
    PyObject *values, *gd, *gg, *sd, *sv;
    Py_ssize_t ngg, nsv;
    static char *kwlist[] = {"config", "grade_distances", "grades", "speed_distances", "speeds",
                             "names", "integers", "error", NULL};
    memset(in, 0, sizeof *in);
    if (!PyArg_ParseTupleAndKeywords(args, kwds, format, kwlist, &values, &gd, &gg, &sd, &sv,
                                     &PyTuple_Type, &in->names, &PyTuple_Type, &in->integers,
                                     &in->error))
        return -1;
    if (PyTuple_GET_SIZE(in->names) != outputs || PyTuple_GET_SIZE(in->integers) != outputs) {
        PyErr_Format(PyExc_ValueError, "the C core has %d outputs", outputs);
        return -1;
    }
    if (!(in->values = doubles(values, &in->n_values, "config must be a sequence of numbers"))
            || !(in->gd = doubles(gd, &in->n_grade, "grade_distances must be a sequence of numbers"))
            || !(in->gg = doubles(gg, &ngg, "grades must be a sequence of numbers"))
            || !(in->sd = doubles(sd, &in->n_speed, "speed_distances must be a sequence of numbers"))
            || !(in->sv = doubles(sv, &nsv, "speeds must be a sequence of numbers")))
        goto fail;
    if (in->n_grade != ngg || in->n_speed != nsv || in->n_grade < 1) {
        PyErr_SetString(PyExc_ValueError, "a profile's distances and values must have one length (>= 1)");
        goto fail;
    }
    return 0;
fail:
    free_init(in);
    return -1;
}

/* Keep the names, flags and error type of a successful initialisation */
static void keep_refs(InitArgs *in, PyObject **names, PyObject **integers, PyObject **error)
{
    Py_INCREF(in->names);
    Py_INCREF(in->integers);
    Py_INCREF(in->error);
    *names = in->names;
    *integers = in->integers;
    *error = in->error;
}

typedef struct {
    PyObject_HEAD
    rc_chain *chain;
    PyObject *names;        /* tuple of the output names (str), RC_CHAIN_OUTPUTS */
    PyObject *integers;     /* tuple of bools: which outputs are integers */
    PyObject *error;        /* the exception type a rejected step raises */
} ChainObject;

static int chain_init(ChainObject *self, PyObject *args, PyObject *kwds)
{
    InitArgs in;
    if (self->chain) {
        PyErr_SetString(PyExc_RuntimeError, "Chain is initialised once");
        return -1;
    }
    if (parse_init(args, kwds, "OOOOOO!O!O:Chain", RC_CHAIN_OUTPUTS, &in) < 0)
        return -1;
    int ok = -1;
    rc_chain_config cfg;
    memset(&cfg, 0, sizeof cfg);
    long expected = rc_chain_config_from_values(&cfg, in.values, (long)in.n_values);
    if (expected) {
        PyErr_Format(PyExc_ValueError, "the C core takes %ld configuration values, got %zd",
                     expected, in.n_values);
        goto done;
    }
    cfg.grade_distances = in.gd;
    cfg.grades = in.gg;
    cfg.grade_n = in.n_grade;
    cfg.speed_distances = in.sd;
    cfg.speeds = in.sv;
    cfg.speed_n = in.n_speed;
    rc_chain *chain = PyMem_Malloc(sizeof *chain);
    if (!chain) {
        PyErr_NoMemory();
        goto done;
    }
    rc_error err;
    if (rc_chain_init(chain, &cfg, &err) != RC_OK) {
        PyMem_Free(chain);
        PyErr_SetString(PyExc_ValueError, err.msg);
        goto done;
    }
    self->chain = chain;
    keep_refs(&in, &self->names, &self->integers, &self->error);
    ok = 0;
done:
    free_init(&in);
    return ok;
}

static void chain_dealloc(ChainObject *self)
{
    PyObject_GC_UnTrack(self);
    if (self->chain) {
        rc_chain_free(self->chain);
        PyMem_Free(self->chain);
    }
    Py_CLEAR(self->names);
    Py_CLEAR(self->integers);
    Py_CLEAR(self->error);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int chain_traverse(ChainObject *self, visitproc visit, void *arg)
{
    Py_VISIT(self->names);
    Py_VISIT(self->integers);
    Py_VISIT(self->error);
    return 0;
}

static int ready(ChainObject *self)
{
    if (self->chain)
        return 1;
    PyErr_SetString(PyExc_RuntimeError, "Chain was not initialised");
    return 0;
}

/* Positional numbers (the fast path), or keywords: x[0..max) from args and kwnames by `names` */
static int numbers(PyObject *const *args, Py_ssize_t nargs, PyObject *kwnames, double *x,
                   Py_ssize_t least, Py_ssize_t most, const char *const *names, const char *what)
{
    Py_ssize_t nkw = kwnames ? PyTuple_GET_SIZE(kwnames) : 0;
    PyObject *given[8] = {NULL};
    if (nargs > most) {
        PyErr_Format(PyExc_TypeError, "%s takes at most %zd arguments", what, most);
        return -1;
    }
    for (Py_ssize_t k = 0; k < nargs; k++)
        given[k] = args[k];
    for (Py_ssize_t j = 0; j < nkw; j++) {
        const char *key = PyUnicode_AsUTF8(PyTuple_GET_ITEM(kwnames, j));
        Py_ssize_t k = 0;
        if (!key)
            return -1;
        while (k < most && strcmp(names[k], key) != 0)
            k++;
        if (k == most || given[k]) {
            PyErr_Format(PyExc_TypeError, "%s got %s argument '%s'", what,
                         k == most ? "an unexpected" : "a second", key);
            return -1;
        }
        given[k] = args[nargs + j];
    }
    for (Py_ssize_t k = 0; k < most; k++) {
        if (!given[k]) {
            if (k < least) {
                PyErr_Format(PyExc_TypeError, "%s missing argument '%s'", what, names[k]);
                return -1;
            }
            x[k] = 0.0;
            continue;
        }
        x[k] = PyFloat_AsDouble(given[k]);
        if (x[k] == -1.0 && PyErr_Occurred())
            return -1;
    }
    return 0;
}

static const char *const STEP_NAMES[] = {"current_time", "step_size", "traction_demand",
                                         "brake_demand", "wind_speed", "payload"};

/* do_step(current_time, step_size, traction_demand, brake_demand, wind_speed, payload=0.0) */
static PyObject *chain_do_step(ChainObject *self, PyObject *const *args, size_t nargsf,
                               PyObject *kwnames)
{
    double x[6];
    if (!ready(self) || numbers(args, PyVectorcall_NARGS(nargsf), kwnames, x, 5, 6, STEP_NAMES,
                                "do_step") < 0)
        return NULL;
    rc_error err;
    rc_status st = rc_chain_step(self->chain, x[0], x[1], x[2], x[3], x[4], x[5], &err);
    if (st != RC_OK) {
        PyErr_SetString(status_exception(st, self->error), err.msg);
        return NULL;
    }
    Py_RETURN_NONE;
}

/* {names[k]: out[k]} with the integers (integers[k] is True) as int */
static PyObject *values_dict(PyObject *names, PyObject *integers, const double *out, Py_ssize_t n)
{
    PyObject *d = _PyDict_NewPresized(n);
    if (!d)
        return NULL;
    for (Py_ssize_t k = 0; k < n; k++) {
        PyObject *v = PyTuple_GET_ITEM(integers, k) == Py_True ? PyLong_FromDouble(out[k])
                                                               : PyFloat_FromDouble(out[k]);
        if (!v || PyDict_SetItem(d, PyTuple_GET_ITEM(names, k), v) < 0) {
            Py_XDECREF(v);
            Py_DECREF(d);
            return NULL;
        }
        Py_DECREF(v);
    }
    return d;
}

/* outputs() -> dict, RailCarChain.outputs() */
static PyObject *chain_outputs(ChainObject *self, PyObject *Py_UNUSED(ignored))
{
    double out[RC_CHAIN_OUTPUTS];
    if (!ready(self))
        return NULL;
    rc_chain_outputs(self->chain, out);
    return values_dict(self->names, self->integers, out, RC_CHAIN_OUTPUTS);
}

/* A writable (or read-only) C-contiguous buffer of doubles with `columns` columns: its rows */
static int double_rows(PyObject *obj, Py_buffer *view, int writable, Py_ssize_t columns,
                       const char *what, Py_ssize_t *rows)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, view, flags) < 0)
        return -1;
    if (!view->format || strcmp(view->format, "d") != 0 || view->len % (Py_ssize_t)(columns * sizeof(double))) {
        PyErr_Format(PyExc_ValueError, "%s must be float64 with %zd columns", what, columns);
        PyBuffer_Release(view);
        return -1;
    }
    *rows = view->len / (Py_ssize_t)(columns * sizeof(double));
    return 0;
}

/* run(inputs, outputs) -> None: for each row i of inputs (current_time, step_size,
 * traction_demand, brake_demand, wind_speed, payload), a step, then the outputs into row i of
 * outputs (RC_CHAIN_OUTPUTS columns), without returning to Python between steps. A rejected step
 * raises naming the row; the rows before it are done and written. */
static PyObject *chain_run(ChainObject *self, PyObject *args)
{
    PyObject *in_obj, *out_obj;
    Py_buffer in, out;
    Py_ssize_t n_in, n_out;
    if (!PyArg_ParseTuple(args, "OO:run", &in_obj, &out_obj) || !ready(self))
        return NULL;
    if (double_rows(in_obj, &in, 0, 6, "inputs", &n_in) < 0)
        return NULL;
    if (double_rows(out_obj, &out, 1, RC_CHAIN_OUTPUTS, "outputs", &n_out) < 0) {
        PyBuffer_Release(&in);
        return NULL;
    }
    PyObject *result = NULL;
    if (n_out != n_in) {
        PyErr_Format(PyExc_ValueError, "outputs must have one row per input row (%zd), got %zd",
                     n_in, n_out);
        goto done;
    }
    const double *x = in.buf;
    double *y = out.buf;
    rc_error err;
    rc_status st = RC_OK;
    Py_ssize_t i;
    for (i = 0; i < n_in; i++, x += 6, y += RC_CHAIN_OUTPUTS) {
        st = rc_chain_step(self->chain, x[0], x[1], x[2], x[3], x[4], x[5], &err);
        if (st != RC_OK)
            break;
        rc_chain_outputs(self->chain, y);
    }
    if (st != RC_OK) {
        PyErr_Format(status_exception(st, self->error), "inputs row %zd: %s", i, err.msg);
        goto done;
    }
    result = Py_NewRef(Py_None);
done:
    PyBuffer_Release(&in);
    PyBuffer_Release(&out);
    return result;
}

static PyObject *chain_next_sample_time(ChainObject *self, PyObject *Py_UNUSED(ignored))
{
    if (!ready(self))
        return NULL;
    return PyFloat_FromDouble(rc_chain_next_sample_time(self->chain));
}

static PyObject *chain_reset(ChainObject *self, PyObject *Py_UNUSED(ignored))
{
    if (!ready(self))
        return NULL;
    rc_error err;
    if (rc_chain_reset(self->chain, &err) != RC_OK) {
        PyMem_Free(self->chain);
        self->chain = NULL;
        PyErr_SetString(PyExc_RuntimeError, err.msg);
        return NULL;
    }
    Py_RETURN_NONE;
}

/* state() -> tuple: the internal state tests compare with the Python chain's (models/compiled.py
 * STATE_FIELDS says what each value is) */
static PyObject *chain_state(ChainObject *self, PyObject *Py_UNUSED(ignored))
{
    if (!ready(self))
        return NULL;
    const rc_chain *c = self->chain;
    const rc_ident *id = &c->est.ident;
    const rc_filter *f = &c->est.filter;
    const rc_plant *p = &c->plant;
    double v[128];
    int n = 0;
    for (int k = 0; k < 4; k++) v[n++] = id->theta[k];
    for (int k = 0; k < 16; k++) v[n++] = id->has_S ? id->S[k] : NAN;
    for (int k = 0; k < 16; k++) v[n++] = id->W[k];
    for (int k = 0; k < 16; k++) v[n++] = id->D[k];
    v[n++] = (double)id->n; v[n++] = id->q_e; v[n++] = id->s2; v[n++] = id->c0; v[n++] = id->c1;
    v[n++] = id->has_cL ? id->cL : NAN; v[n++] = (double)id->n_cL; v[n++] = (double)id->n_c1;
    v[n++] = f->xb0; v[n++] = f->xb1; v[n++] = f->m00; v[n++] = f->m01; v[n++] = f->m11;
    v[n++] = f->xh0; v[n++] = f->xh1; v[n++] = f->p00; v[n++] = f->p01; v[n++] = f->p11;
    v[n++] = c->est.station.still_time; v[n++] = (double)c->est.station.fast_run;
    v[n++] = p->time; v[n++] = (double)p->grid_index;
    v[n++] = p->traction_impulse; v[n++] = p->brake_impulse;
    v[n++] = p->state.still_time; v[n++] = (double)p->state.stops;
    v[n++] = (double)c->sample_index;
    v[n++] = c->has_track_t1 ? c->track_t1 : NAN;
    v[n++] = c->has_pending_track ? c->pending_speed : NAN;
    v[n++] = c->has_pending_track ? c->pending_age : NAN;
    PyObject *t = PyTuple_New(n);
    if (!t)
        return NULL;
    for (int k = 0; k < n; k++) {
        PyObject *x = PyFloat_FromDouble(v[k]);
        if (!x) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, k, x);
    }
    return t;
}

static PyMethodDef chain_methods[] = {
    {"do_step", (PyCFunction)(void (*)(void))chain_do_step, METH_FASTCALL | METH_KEYWORDS,
     "do_step(current_time, step_size, traction_demand, brake_demand, wind_speed, payload=0.0)"},
    {"outputs", (PyCFunction)chain_outputs, METH_NOARGS, "outputs() -> dict"},
    {"run", (PyCFunction)chain_run, METH_VARARGS,
     "run(inputs, outputs): many steps over float64 buffers (n x 6 in, n x outputs out)"},
    {"next_sample_time", (PyCFunction)chain_next_sample_time, METH_NOARGS, "[s]"},
    {"reset", (PyCFunction)chain_reset, METH_NOARGS, "back to the initial state"},
    {"state", (PyCFunction)chain_state, METH_NOARGS, "internal state (tests)"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject ChainType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "models._railcar.Chain",
    .tp_basicsize = sizeof(ChainObject),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "The RailCar chain in C (models/core/railcar.h); see models.compiled.CompiledChain",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)chain_init,
    .tp_dealloc = (destructor)chain_dealloc,
    .tp_traverse = (traverseproc)chain_traverse,
    .tp_methods = chain_methods,
};

/* ------------------------------------------------------------------ Estimator */

typedef struct {
    PyObject_HEAD
    rc_estchain *chain;
    PyObject *names;        /* tuple of the output names (str), RC_EST_OUTPUTS */
    PyObject *integers;     /* tuple of bools */
    PyObject *error;
} EstimatorObject;

static int estimator_init(EstimatorObject *self, PyObject *args, PyObject *kwds)
{
    InitArgs in;
    if (self->chain) {
        PyErr_SetString(PyExc_RuntimeError, "Estimator is initialised once");
        return -1;
    }
    if (parse_init(args, kwds, "OOOOOO!O!O:Estimator", RC_EST_OUTPUTS, &in) < 0)
        return -1;
    int ok = -1;
    rc_estchain_config cfg;
    memset(&cfg, 0, sizeof cfg);
    long expected = rc_estchain_config_from_values(&cfg, in.values, (long)in.n_values);
    if (expected) {
        PyErr_Format(PyExc_ValueError, "the C core takes %ld configuration values, got %zd",
                     expected, in.n_values);
        goto done;
    }
    cfg.grade_distances = in.gd;
    cfg.grades = in.gg;
    cfg.grade_n = in.n_grade;
    cfg.speed_distances = in.sd;
    cfg.speeds = in.sv;
    cfg.speed_n = in.n_speed;
    rc_estchain *chain = PyMem_Malloc(sizeof *chain);
    if (!chain) {
        PyErr_NoMemory();
        goto done;
    }
    rc_error err;
    if (rc_estchain_init(chain, &cfg, &err) != RC_OK) {
        PyMem_Free(chain);
        PyErr_SetString(PyExc_ValueError, err.msg);
        goto done;
    }
    self->chain = chain;
    keep_refs(&in, &self->names, &self->integers, &self->error);
    ok = 0;
done:
    free_init(&in);
    return ok;
}

static void estimator_dealloc(EstimatorObject *self)
{
    PyObject_GC_UnTrack(self);
    if (self->chain) {
        rc_estchain_free(self->chain);
        PyMem_Free(self->chain);
    }
    Py_CLEAR(self->names);
    Py_CLEAR(self->integers);
    Py_CLEAR(self->error);
    Py_TYPE(self)->tp_free((PyObject *)self);
}

static int estimator_traverse(EstimatorObject *self, visitproc visit, void *arg)
{
    Py_VISIT(self->names);
    Py_VISIT(self->integers);
    Py_VISIT(self->error);
    return 0;
}

static const char *const ESTIMATOR_STEP_NAMES[] = {"current_time", "step_size", "traction", "brake",
                                                   "speed_meas", "position_meas", "track_speed",
                                                   "track_time"};

/* do_step(current_time, step_size, traction, brake, speed_meas, position_meas, track_speed=0.0,
 * track_time=0.0) */
static PyObject *estimator_do_step(EstimatorObject *self, PyObject *const *args, size_t nargsf,
                                   PyObject *kwnames)
{
    double x[8];
    if (!self->chain) {
        PyErr_SetString(PyExc_RuntimeError, "Estimator was not initialised");
        return NULL;
    }
    if (numbers(args, PyVectorcall_NARGS(nargsf), kwnames, x, 6, 8, ESTIMATOR_STEP_NAMES,
                "do_step") < 0)
        return NULL;
    rc_error err;
    rc_status st = rc_estchain_step(self->chain, x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7], &err);
    if (st != RC_OK) {
        PyErr_SetString(status_exception(st, self->error), err.msg);
        return NULL;
    }
    Py_RETURN_NONE;
}

/* outputs() -> dict (empty before the first step) */
static PyObject *estimator_outputs(EstimatorObject *self, PyObject *Py_UNUSED(ignored))
{
    double out[RC_EST_OUTPUTS];
    if (!self->chain) {
        PyErr_SetString(PyExc_RuntimeError, "Estimator was not initialised");
        return NULL;
    }
    if (!rc_estchain_outputs(self->chain, out))
        return PyDict_New();
    return values_dict(self->names, self->integers, out, RC_EST_OUTPUTS);
}

static PyMethodDef estimator_methods[] = {
    {"do_step", (PyCFunction)(void (*)(void))estimator_do_step, METH_FASTCALL | METH_KEYWORDS,
     "do_step(current_time, step_size, traction, brake, speed_meas, position_meas, "
     "track_speed=0.0, track_time=0.0)"},
    {"outputs", (PyCFunction)estimator_outputs, METH_NOARGS, "outputs() -> dict"},
    {NULL, NULL, 0, NULL},
};

static PyTypeObject EstimatorType = {
    PyVarObject_HEAD_INIT(NULL, 0)
    .tp_name = "models._railcar.Estimator",
    .tp_basicsize = sizeof(EstimatorObject),
    .tp_flags = Py_TPFLAGS_DEFAULT | Py_TPFLAGS_BASETYPE | Py_TPFLAGS_HAVE_GC,
    .tp_doc = "RailCarEstimator's chain in C; see models.compiled.CompiledEstimatorChain",
    .tp_new = PyType_GenericNew,
    .tp_init = (initproc)estimator_init,
    .tp_dealloc = (destructor)estimator_dealloc,
    .tp_traverse = (traverseproc)estimator_traverse,
    .tp_methods = estimator_methods,
};

/* ------------------------------------------------------------------ the ATO closed loop */

/* A sequence of exactly n numbers into out; -1 with ValueError naming `what` */
static int exact_doubles(PyObject *seq, double *out, Py_ssize_t n, const char *what)
{
    Py_ssize_t got;
    double *x = doubles(seq, &got, what);
    if (!x)
        return -1;
    if (got != n) {
        PyErr_Format(PyExc_ValueError, "%s must have %zd values, got %zd", what, n, got);
        PyMem_Free(x);
        return -1;
    }
    memcpy(out, x, sizeof(double) * (size_t)n);
    PyMem_Free(x);
    return 0;
}

/* ato_closed_loop(chain_config, grade_distances, grades, span, limit_distances, limit_speeds, car,
 * tuning, truth, step, wind, max_steps, seeds, error) -> list of tuples (arrival, settle, stop,
 * margin, energy, interventions, replans, steps, finished), one per seed: the run of
 * models/core/ato_closed_loop.h for each seed (the chain configuration's seed replaced), the GIL
 * released while it runs. span: (length, schedule, stop); car: CarTraction's 18 fields; tuning:
 * AtoTuning's values in its order; truth: VehicleParams' 11 fields. A refused configuration raises
 * ValueError with the core's text, a step the chain refuses `error` (models.chain.StepRejected). */
static PyObject *run_ato_closed_loop(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *values_obj, *gd_obj, *gg_obj, *span_obj, *ld_obj, *lv_obj, *car_obj, *tuning_obj;
    PyObject *truth_obj, *seeds_obj, *error;
    double step, wind, span3[3], car_values[18], tuning_values[ATO_N_TUNING_FIELDS], truth[11];
    long max_steps;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOddlOO:ato_closed_loop", &values_obj, &gd_obj, &gg_obj,
                          &span_obj, &ld_obj, &lv_obj, &car_obj, &tuning_obj, &truth_obj, &step,
                          &wind, &max_steps, &seeds_obj, &error))
        return NULL;
    if (exact_doubles(span_obj, span3, 3, "span") < 0
            || exact_doubles(car_obj, car_values, 18, "car") < 0
            || exact_doubles(tuning_obj, tuning_values, ATO_N_TUNING_FIELDS, "tuning") < 0
            || exact_doubles(truth_obj, truth, 11, "truth") < 0)
        return NULL;
    double *values = NULL, *gd = NULL, *gg = NULL, *ld = NULL, *lv = NULL, *seeds = NULL;
    double *cum = NULL;
    ato_closed_loop *run = NULL;
    PyObject *result = NULL;
    Py_ssize_t n_values, n_grade, ngg, n_lim, nlv, n_seeds;
    if (!(values = doubles(values_obj, &n_values, "chain_config must be a sequence of numbers"))
            || !(gd = doubles(gd_obj, &n_grade, "grade_distances must be a sequence of numbers"))
            || !(gg = doubles(gg_obj, &ngg, "grades must be a sequence of numbers"))
            || !(ld = doubles(ld_obj, &n_lim, "limit_distances must be a sequence of numbers"))
            || !(lv = doubles(lv_obj, &nlv, "limit_speeds must be a sequence of numbers"))
            || !(seeds = doubles(seeds_obj, &n_seeds, "seeds must be a sequence of numbers")))
        goto done;
    if (n_grade != ngg || n_grade < 1 || n_lim != nlv || n_lim < 1) {
        PyErr_SetString(PyExc_ValueError,
                        "the grade's and the limits' distances and values must have one length (>= 1)");
        goto done;
    }
    rc_chain_config cfg;
    memset(&cfg, 0, sizeof cfg);
    long expected = rc_chain_config_from_values(&cfg, values, (long)n_values);
    if (expected) {
        PyErr_Format(PyExc_ValueError, "the C core takes %ld configuration values, got %zd",
                     expected, n_values);
        goto done;
    }
    cfg.grade_distances = gd;
    cfg.grades = gg;
    cfg.grade_n = n_grade;
    if (!(cum = PyMem_Malloc(sizeof(double) * (size_t)n_grade))
            || !(run = PyMem_Malloc(sizeof *run))) {
        PyErr_NoMemory();
        goto done;
    }
    rc_grade_cumulate(gd, gg, (long)n_grade, cum);
    rc_ato_span span = {span3[0], span3[1], span3[2], {gd, gg, cum, (long)n_grade}, (int)n_lim,
                        ld, lv};
    rc_ato_car car;
    ato_car_from_values(&car, car_values);
    ato_tuning tuning;
    ato_tuning_from_values(&tuning, tuning_values);
    ato_loop_config loop = {step, wind, max_steps,
                            {truth[0], truth[1], truth[2], truth[3], truth[4], truth[5], truth[6],
                             truth[7], truth[8], truth[9], truth[10]}};
    if (!(result = PyList_New(0)))
        goto done;
    for (Py_ssize_t i = 0; i < n_seeds; i++) {
        char msg[ATO_TEXT_SIZE];
        ato_loop_result r;
        rc_status st;
        cfg.seed = (long)seeds[i];
        Py_BEGIN_ALLOW_THREADS
        st = ato_closed_loop_init(run, &cfg, &span, &car, &tuning, &loop, msg);
        if (st == RC_OK) {
            st = ato_closed_loop_run(run, &r, msg);
            ato_closed_loop_free(run);
        }
        Py_END_ALLOW_THREADS
        if (st != RC_OK) {
            PyErr_SetString(status_exception(st, error), msg);
            Py_CLEAR(result);
            goto done;
        }
        PyObject *row = Py_BuildValue("(dddddllli)", r.arrival, r.settle, r.stop, r.margin,
                                      r.energy, r.interventions, r.replans, r.steps, r.finished);
        if (!row || PyList_Append(result, row) < 0) {
            Py_XDECREF(row);
            Py_CLEAR(result);
            goto done;
        }
        Py_DECREF(row);
    }
done:
    PyMem_Free(values);
    PyMem_Free(gd);
    PyMem_Free(gg);
    PyMem_Free(ld);
    PyMem_Free(lv);
    PyMem_Free(seeds);
    PyMem_Free(cum);
    PyMem_Free(run);
    return result;
}

/* The chain output each ATO input is read from (ato_closed_loop.h), for the test that holds it
 * to models/compiled.py's OUTPUT_NAMES */
static PyObject *ato_input_outputs(void)
{
    PyObject *t = PyTuple_New(ATO_N_ALL_INPUTS);
    if (!t)
        return NULL;
    for (int k = 0; k < ATO_N_ALL_INPUTS; k++) {
        PyObject *x = PyLong_FromLong(ATO_LOOP_INPUT_OUTPUTS[k]);
        if (!x) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, k, x);
    }
    return t;
}

static PyMethodDef module_methods[] = {
    {"ato_closed_loop", run_ato_closed_loop, METH_VARARGS,
     "ato_closed_loop(chain_config, grade_distances, grades, span, limit_distances, limit_speeds, "
     "car, tuning, truth, step, wind, max_steps, seeds, error) -> [(arrival, settle, stop, margin, "
     "energy, interventions, replans, steps, finished)] (models.compiled.run_ato_closed_loop)"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "models._railcar",
    "Thin binding of the C model core (models/core/): see models/compiled.py.", -1, module_methods,
    NULL, NULL, NULL, NULL,
};

/* PyModule_Add of Python 3.13: add obj (a new reference, or NULL with an exception) and drop it */
static int add_new_object(PyObject *m, const char *name, PyObject *obj)
{
    if (!obj)
        return -1;
    int rc = PyModule_AddObjectRef(m, name, obj);
    Py_DECREF(obj);
    return rc;
}

PyMODINIT_FUNC PyInit__railcar(void)
{
    if (PyType_Ready(&ChainType) < 0 || PyType_Ready(&EstimatorType) < 0)
        return NULL;
    PyObject *m = PyModule_Create(&module);
    if (!m)
        return NULL;
    if (PyModule_AddType(m, &ChainType) < 0 || PyModule_AddType(m, &EstimatorType) < 0
            || PyModule_AddIntConstant(m, "OUTPUTS", RC_CHAIN_OUTPUTS) < 0
            || PyModule_AddIntConstant(m, "ESTIMATOR_OUTPUTS", RC_EST_OUTPUTS) < 0
            || add_new_object(m, "ATO_INPUT_OUTPUTS", ato_input_outputs()) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
