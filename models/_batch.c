/* _batch.c -- the CPython binding of the C scenario runner (models/core/scenario_driver.h): many
 * whole scripted runs per call, each on its own C chain (models/core/railcar.h), without
 * returning to Python per step (issue 31). models/batch.py is its Python face.
 *
 * A module of its own beside models._railcar (which binds one chain for per-step use): it is
 * linked with the same core sources (setup.py), so it needs nothing from _railcar at run time.
 * The binding only converts: every run's float64 arrays are read through the buffer protocol
 * (no copies), all runs are checked before the first one starts, and the runs themselves go
 * with the GIL released (other Python threads of a worker keep running).
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "core/scenario_driver.h"

#define RUN_ARRAYS 6   /* config, grade_distances, grades, speed_distances, speeds, script */

static const char *const ARRAY_NAMES[RUN_ARRAYS] = {"config", "grade_distances", "grades",
                                                    "speed_distances", "speeds", "script"};

typedef struct {                 /* one run, parsed */
    Py_buffer view[RUN_ARRAYS];
    int held;                    /* views acquired */
    rc_chain_config cfg;
    rc_script script;
    int has_script;
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

/* runs[r] from the tuple (config, grade_distances, grades, speed_distances, speeds, script); -1
 * with ValueError naming the run */
static int parse_run(PyObject *item, Run *run, Py_ssize_t r)
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
    rc_error err;
    if (rc_script_init(&run->script, run->view[5].buf, length(&run->view[5]), &err) != RC_OK) {
        PyErr_Format(PyExc_ValueError, "run %zd: %s", r, err.msg);
        return -1;
    }
    run->has_script = 1;
    return 0;
}

/* run(runs, outputs, inputs, error) -> [(rows, finished), ...] */
static PyObject *batch_run(PyObject *Py_UNUSED(module), PyObject *args)
{
    PyObject *seq, *out_obj, *in_obj, *error;
    if (!PyArg_ParseTuple(args, "OOOO:run", &seq, &out_obj, &in_obj, &error))
        return NULL;
    if (!PyExceptionClass_Check(error)) {
        PyErr_SetString(PyExc_TypeError, "error must be an exception class");
        return NULL;
    }
    PyObject *fast = PySequence_Fast(seq, "runs must be a sequence of tuples");
    if (!fast)
        return NULL;
    Py_ssize_t n = PySequence_Fast_GET_SIZE(fast);
    Run *runs = PyMem_Calloc((size_t)(n > 0 ? n : 1), sizeof *runs);
    rc_chain *chain = PyMem_Malloc(sizeof *chain);
    Py_buffer out, in;
    int have_out = 0, have_in = 0;
    PyObject *result = NULL;
    if (!runs || !chain) {
        PyErr_NoMemory();
        goto done;
    }
    if (double_buffer(out_obj, &out, 1, -1, "outputs") < 0)
        goto done;
    have_out = 1;
    if (double_buffer(in_obj, &in, 1, -1, "inputs") < 0)
        goto done;
    have_in = 1;
    /* outputs: n x (steps + 1) x RC_CHAIN_OUTPUTS, inputs: n x steps x RC_SCRIPT_INPUTS */
    Py_ssize_t out_rows = n ? length(&out) / (n * RC_CHAIN_OUTPUTS) : 0;
    Py_ssize_t in_rows = n ? length(&in) / (n * RC_SCRIPT_INPUTS) : 0;
    if (n && (length(&out) != n * out_rows * RC_CHAIN_OUTPUTS
              || length(&in) != n * in_rows * RC_SCRIPT_INPUTS || out_rows != in_rows + 1)) {
        PyErr_Format(PyExc_ValueError, "outputs must be runs x (steps + 1) x %d and inputs runs x "
                     "steps x %d float64 (%zd runs), got %zd and %zd values", RC_CHAIN_OUTPUTS,
                     RC_SCRIPT_INPUTS, n, (Py_ssize_t)length(&out), (Py_ssize_t)length(&in));
        goto done;
    }
    for (Py_ssize_t r = 0; r < n; r++) {
        if (parse_run(PySequence_Fast_GET_ITEM(fast, r), &runs[r], r) < 0)
            goto done;
        if (runs[r].script.steps > in_rows) {
            PyErr_Format(PyExc_ValueError, "run %zd: %ld steps, the arrays have room for %zd",
                         r, runs[r].script.steps, in_rows);
            goto done;
        }
    }
    rc_status st = RC_OK;
    Py_ssize_t failed = -1;
    rc_error err;
    err.msg[0] = '\0';
    Py_BEGIN_ALLOW_THREADS
    for (Py_ssize_t r = 0; r < n && st == RC_OK; r++) {
        double *y = (double *)out.buf + r * out_rows * RC_CHAIN_OUTPUTS;
        double *u = (double *)in.buf + r * in_rows * RC_SCRIPT_INPUTS;
        st = rc_chain_init(chain, &runs[r].cfg, &err);
        if (st != RC_OK) {
            failed = r;
            break;
        }
        st = rc_script_run(&runs[r].script, chain, y, u, &runs[r].rows, &runs[r].finished, &err);
        rc_chain_free(chain);
        if (st != RC_OK)
            failed = r;
    }
    Py_END_ALLOW_THREADS
    if (st != RC_OK) {
        PyErr_Format(st == RC_REJECTED ? error : PyExc_ValueError, "run %zd: %s", failed, err.msg);
        goto done;
    }
    result = PyList_New(n);
    for (Py_ssize_t r = 0; result && r < n; r++) {
        PyObject *pair = Py_BuildValue("(lO)", runs[r].rows, runs[r].finished ? Py_True : Py_False);
        if (!pair)
            Py_CLEAR(result);
        else
            PyList_SET_ITEM(result, r, pair);
    }
done:
    if (runs)
        release_runs(runs, n);
    PyMem_Free(chain);
    if (have_out)
        PyBuffer_Release(&out);
    if (have_in)
        PyBuffer_Release(&in);
    Py_DECREF(fast);
    return result;
}

static PyMethodDef methods[] = {
    {"run", batch_run, METH_VARARGS,
     "run(runs, outputs, inputs, error) -> [(rows, finished), ...]: whole scripted runs; each run "
     "a tuple of float64 arrays (config, grade_distances, grades, speed_distances, speeds, "
     "script); outputs runs x (steps + 1) x OUTPUTS, inputs runs x steps x INPUTS; a rejected "
     "step raises error naming the run and the step"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "models._batch",
    "Whole scripted runs in the C core (models/core/scenario_driver.h): see models/batch.py.", -1,
    methods, NULL, NULL, NULL, NULL,
};

PyMODINIT_FUNC PyInit__batch(void)
{
    PyObject *m = PyModule_Create(&module);
    if (!m)
        return NULL;
    if (PyModule_AddIntConstant(m, "OUTPUTS", RC_CHAIN_OUTPUTS) < 0
            || PyModule_AddIntConstant(m, "INPUTS", RC_SCRIPT_INPUTS) < 0
            || PyModule_AddIntConstant(m, "HEADER", RC_SCRIPT_HEADER) < 0
            || PyModule_AddIntConstant(m, "PHASE_FIELDS", RC_PHASE_FIELDS) < 0
            || PyModule_AddIntConstant(m, "MAX_STEPS", RC_SCRIPT_MAX_STEPS) < 0) {
        Py_DECREF(m);
        return NULL;
    }
    return m;
}
