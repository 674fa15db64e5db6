/* pyslave.c -- the glue's backend for pythonfmu slaves: drives a pythonfmu.Fmi2Slave subclass
 * through the Python C API.
 *
 * - Not linked against libpython: the Py* symbols come from the host process (a Python host, or
 *   a C host that loaded libpython3.x.so). If no interpreter runs yet, the first instantiation
 *   starts one and releases the GIL; it is never finalised (CPython with numpy cannot be
 *   restarted reliably). Every call takes the GIL with PyGILState_Ensure/Release, so hosts may
 *   call from any thread.
 * - Stable ABI (Py_LIMITED_API 3.8): the binary does not depend on the minor version of the
 *   host's CPython (checked: built on 3.11, run under 3.11 and 3.13).
 * - The FMU's resources folder goes on sys.path once (not once per instance); the module named
 *   in resources/slavemodule.txt is imported and its concrete Fmi2Slave subclass (the deepest
 *   one) is instantiated with instance_name, resources and visible, as pythonfmu does.
 * - A Python exception never escapes: it is logged (fmi2Error, "logStatusError") and the call
 *   returns fmi2Error; every Python object stays owned by this instance until fmi2FreeInstance
 *   or fmi2Reset releases it. References are balanced on every path.
 * - After every call the slave's log queue (Fmi2Slave.log appends LogMsg objects to the list
 *   _get_log_queue returns) is forwarded to the host's logger and emptied.
 */
#define PY_SSIZE_T_CLEAN
#define Py_LIMITED_API 0x03080000
#include <Python.h>

#include <errno.h>
#include <limits.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2_glue.h"

/* Marker: tests check that the FMU carries this binary, not pythonfmu's. */
#define BINARY_ID "railcar-fmu fmi2 binary 1: C99 FMI 2.0 glue + Python C API backend"

GLUE_EXPORT const char *railcar_fmu_binary_id(void) { return BINARY_ID; }

enum {
    M_SETUP, M_ENTER_INIT, M_EXIT_INIT, M_DO_STEP, M_TERMINATE,
    M_GET, /* + GlueType: get_real, get_integer, get_boolean, get_string */
    M_SET = M_GET + 4,
    M_COUNT = M_SET + 4
};

static const char *const method_names[M_COUNT] = {
    "setup_experiment", "enter_initialization_mode", "exit_initialization_mode", "do_step",
    "terminate", "get_real", "get_integer", "get_boolean", "get_string",
    "set_real", "set_integer", "set_boolean", "set_string"};

/* One live Python slave and what we call on it (bound methods looked up once). */
typedef struct {
    PyObject *slave;
    PyObject *queue;               /* the list Fmi2Slave.log appends to (may be NULL) */
    PyObject *method[M_COUNT];
} Slave;

typedef struct {
    PyObject *cls;                 /* the slave class, kept for fmi2Reset */
    Slave s;
} PySlave;

#define MODEL(g) ((PySlave *)(g)->model)

/* ------------------------------------------------------------------ the interpreter */

static pthread_mutex_t start_lock = PTHREAD_MUTEX_INITIALIZER;

/* 1 if the interpreter runs (with may_start: started here if the host had none), else 0 with
   a fatal message: the only case in which this binary returns fmi2Fatal. */
static int python_running(GlueInstance *g, const char *function, int may_start) {
    int started = 0;
    if (Py_IsInitialized()) return 1;
    if (may_start) {
        pthread_mutex_lock(&start_lock);
        if (!Py_IsInitialized()) {
            Py_InitializeEx(0);                  /* 0: leave the host's signal handlers alone */
            if (Py_IsInitialized()) {
                PyEval_SaveThread();             /* release the GIL: each call takes it */
                started = 1;
            }
        }
        pthread_mutex_unlock(&start_lock);
        if (Py_IsInitialized()) {
            if (started)
                glue_log(g, fmi2OK, "logAll", "%s: started a Python interpreter (the host had "
                                              "none running)", function);
            return 1;
        }
    }
    glue_log(g, fmi2Fatal, "logStatusFatal", "%s: the Python interpreter is not running (the "
             "host finalised it?); this instance can only be freed", function);
    return 0;
}

/* ------------------------------------------------------------------ text and messages */

/* str(o) as UTF-8 bytes (never fails for a str: unencodable characters are escaped); NULL with
   no exception pending if str(o) fails. */
static PyObject *utf8_bytes(PyObject *o) {
    PyObject *s = o && PyUnicode_Check(o) ? (Py_INCREF(o), o) : (o ? PyObject_Str(o) : NULL);
    PyObject *b = s ? PyUnicode_AsEncodedString(s, "utf-8", "backslashreplace") : NULL;
    Py_XDECREF(s);
    if (!b) PyErr_Clear();
    return b;
}

static const char *bytes_text(PyObject *b, const char *fallback) {
    const char *t = b ? PyBytes_AsString(b) : NULL;
    return t ? t : fallback;
}

/* A malloc'd UTF-8 copy of str(o) (the glue frees it), or NULL. */
static char *c_string(PyObject *o) {
    PyObject *b = utf8_bytes(o);
    const char *t = bytes_text(b, NULL);
    char *copy = NULL;
    if (t && (copy = malloc(strlen(t) + 1)) != NULL) strcpy(copy, t);
    Py_XDECREF(b);
    return copy;
}

/* Forward and empty the slave's log queue. Runs with no exception pending. */
static void forward_log(GlueInstance *g, Slave *s) {
    Py_ssize_t i, n;
    if (!s->queue) return;
    n = PySequence_Size(s->queue);
    if (n <= 0) {
        if (n < 0) PyErr_Clear();
        return;
    }
    for (i = 0; i < n; i++) {
        PyObject *item = PySequence_GetItem(s->queue, i);
        PyObject *status = item ? PyObject_GetAttrString(item, "status") : NULL;
        PyObject *category, *msg, *cat_b = NULL, *msg_b;
        long st;
        if (!status) PyErr_Clear();
        st = status ? PyLong_AsLong(status) : fmi2OK;   /* pythonfmu: an IntEnum */
        if (st == -1 && PyErr_Occurred()) {
            PyErr_Clear();
            st = fmi2OK;
        }
        if (st < fmi2OK || st > fmi2Fatal) st = fmi2Error;
        category = item ? PyObject_GetAttrString(item, "category") : NULL;
        if (!category) PyErr_Clear();
        if (category && category != Py_None) cat_b = utf8_bytes(category);
        msg = item ? PyObject_GetAttrString(item, "msg") : NULL;
        if (!msg) PyErr_Clear();
        msg_b = utf8_bytes(msg ? msg : item);
        glue_log_text(g, (fmi2Status)st, cat_b ? bytes_text(cat_b, NULL) : NULL,
                      bytes_text(msg_b, "(a log message that could not be read)"));
        Py_XDECREF(msg_b);
        Py_XDECREF(msg);
        Py_XDECREF(cat_b);
        Py_XDECREF(category);
        Py_XDECREF(status);
        Py_XDECREF(item);
    }
    if (PySequence_DelSlice(s->queue, 0, n) < 0) PyErr_Clear();
}

/* Log a fetched exception (references stolen): "<function>: <Type>: <message>", and with debug
   logging on, the traceback as a debug message. */
static void report(GlueInstance *g, const char *function, PyObject *type, PyObject *value,
                   PyObject *tb) {
    PyObject *name, *name_b, *msg_b;
    PyErr_NormalizeException(&type, &value, &tb);
    name = type ? PyObject_GetAttrString(type, "__name__") : NULL;
    if (!name) PyErr_Clear();
    name_b = utf8_bytes(name);
    msg_b = utf8_bytes(value);
    glue_log(g, fmi2Error, "logStatusError", "%s: the Python slave raised %s: %s", function,
             bytes_text(name_b, "an exception"), bytes_text(msg_b, "(no message)"));
    if (glue_log_wanted(g, fmi2OK, "logAll")) {
        PyObject *tbmod = PyImport_ImportModule("traceback");
        PyObject *lines = tbmod ? PyObject_CallMethod(tbmod, "format_exception", "OOO",
                                                      type ? type : Py_None,
                                                      value ? value : Py_None,
                                                      tb ? tb : Py_None) : NULL;
        PyObject *sep = PyUnicode_FromString("");
        PyObject *text = lines && sep ? PyUnicode_Join(sep, lines) : NULL;
        PyObject *text_b = text ? utf8_bytes(text) : NULL;
        if (text_b) glue_log(g, fmi2OK, "logAll", "%s: %s", function, bytes_text(text_b, ""));
        PyErr_Clear();
        Py_XDECREF(text_b);
        Py_XDECREF(text);
        Py_XDECREF(sep);
        Py_XDECREF(lines);
        Py_XDECREF(tbmod);
    }
    Py_XDECREF(msg_b);
    Py_XDECREF(name_b);
    Py_XDECREF(name);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
}

/* End of every call, GIL held: the slave's messages first (they came first), then the exception
   if one is pending. Returns the call's status (fmi2Error if an exception was pending). */
static fmi2Status finish(GlueInstance *g, Slave *s, const char *function, fmi2Status status) {
    PyObject *type = NULL, *value = NULL, *tb = NULL;
    if (PyErr_Occurred()) {
        PyErr_Fetch(&type, &value, &tb);
        if (status < fmi2Error) status = fmi2Error;
    }
    if (s) forward_log(g, s);
    if (type) report(g, function, type, value, tb);
    return status;
}

/* ------------------------------------------------------------------- slave life cycle */

static void release_slave(Slave *s) {
    int i;
    for (i = 0; i < M_COUNT; i++) Py_CLEAR(s->method[i]);
    Py_CLEAR(s->queue);
    Py_CLEAR(s->slave);
}

/* A new slave object of `cls` with its bound methods and log queue; 0 with an exception or a
   logged error. */
static int make_slave(GlueInstance *g, PyObject *cls, Slave *s, const char *function) {
    PyObject *args = PyTuple_New(0), *kwargs = PyDict_New();
    PyObject *name = PyUnicode_DecodeUTF8(g->instance_name, (Py_ssize_t)strlen(g->instance_name),
                                          "replace");
    PyObject *res = PyUnicode_DecodeFSDefault(g->resources);
    PyObject *vis = PyBool_FromLong(g->visible);
    int i, ok = args && kwargs && name && res && vis &&
                PyDict_SetItemString(kwargs, "instance_name", name) == 0 &&
                PyDict_SetItemString(kwargs, "resources", res) == 0 &&
                PyDict_SetItemString(kwargs, "visible", vis) == 0;
    memset(s, 0, sizeof *s);
    if (ok) ok = (s->slave = PyObject_Call(cls, args, kwargs)) != NULL;
    Py_XDECREF(vis);
    Py_XDECREF(res);
    Py_XDECREF(name);
    Py_XDECREF(kwargs);
    Py_XDECREF(args);
    for (i = 0; ok && i < M_COUNT; i++) {
        s->method[i] = PyObject_GetAttrString(s->slave, method_names[i]);
        if (!s->method[i] || !PyCallable_Check(s->method[i])) {
            PyErr_Clear();
            glue_log(g, fmi2Error, "logStatusError", "%s: the slave class of %s has no method "
                     "%s()", function, g->model_name ? g->model_name : "this FMU",
                     method_names[i]);
            ok = 0;
        }
    }
    if (ok) {
        s->queue = PyObject_CallMethod(s->slave, "_get_log_queue", NULL);
        if (!s->queue || !PySequence_Check(s->queue)) {   /* no queue: no messages to forward */
            PyErr_Clear();
            Py_CLEAR(s->queue);
        }
    }
    if (!ok) {              /* keep what the half-made slave logged, then drop it */
        PyObject *type, *value, *tb;
        PyErr_Fetch(&type, &value, &tb);
        forward_log(g, s);
        release_slave(s);
        PyErr_Restore(type, value, tb);
    }
    return ok;
}

/* resources/slavemodule.txt names the module (pythonfmu's convention). */
static int read_module_name(GlueInstance *g, char *out, size_t size) {
    size_t len = strlen(g->resources), n;
    char *path = malloc(len + sizeof "/slavemodule.txt");
    FILE *f;
    if (!path) return 0;
    memcpy(path, g->resources, len);
    memcpy(path + len, "/slavemodule.txt", sizeof "/slavemodule.txt");
    f = fopen(path, "rb");
    if (!f) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: cannot read %s: %s", path,
                 strerror(errno));
        free(path);
        return 0;
    }
    n = fread(out, 1, size - 1, f);
    fclose(f);
    out[n] = '\0';
    while (n > 0 && (out[n - 1] == '\n' || out[n - 1] == '\r' || out[n - 1] == ' ')) out[--n] = '\0';
    if (n == 0 || strchr(out, '\n')) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: %s does not name one Python "
                 "module", path);
        free(path);
        return 0;
    }
    free(path);
    return 1;
}

/* Put the resources folder on sys.path, once: in front, as pythonfmu does, so that the FMU's
   own modules win. */
static int add_to_sys_path(GlueInstance *g) {
    PyObject *path = PySys_GetObject("path");         /* borrowed */
    PyObject *dir = PyUnicode_DecodeFSDefault(g->resources);
    int present, ok;
    if (!path || !dir || !PyList_Check(path)) {
        Py_XDECREF(dir);
        if (!PyErr_Occurred())
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: sys.path is not a list");
        return 0;
    }
    present = PySequence_Contains(path, dir);
    ok = present == 1 || (present == 0 && PyList_Insert(path, 0, dir) == 0);
    Py_DECREF(dir);
    return ok;
}

static int has_name(PyObject *o, const char *name) {
    PyObject *n = PyObject_GetAttrString(o, "__name__");
    int eq = n && PyUnicode_Check(n) && PyUnicode_CompareWithASCIIString(n, name) == 0;
    if (!n) PyErr_Clear();
    Py_XDECREF(n);
    return eq;
}

/* The module's concrete class that derives from Fmi2Slave through the longest chain (what
   pythonfmu's builder picks). New reference, or NULL with an error logged or pending. */
static PyObject *find_slave_class(GlueInstance *g, PyObject *module, const char *module_name) {
    PyObject *values = PyDict_Values(PyModule_GetDict(module));
    PyObject *best = NULL;
    Py_ssize_t i, k, n, best_len = -1;
    int ambiguous = 0;
    if (!values) return NULL;
    n = PyList_Size(values);
    for (i = 0; i < n; i++) {
        PyObject *cls = PyList_GetItem(values, i);      /* borrowed */
        PyObject *mro, *abstract;
        Py_ssize_t len;
        int derived = 0, is_abstract;
        if (!PyType_Check(cls)) continue;
        mro = PyObject_GetAttrString(cls, "__mro__");
        if (!mro) {
            PyErr_Clear();
            continue;
        }
        len = PySequence_Size(mro);
        for (k = 1; k < len && !derived; k++) {         /* k = 0 is the class itself */
            PyObject *base = PySequence_GetItem(mro, k);
            derived = base && has_name(base, "Fmi2Slave");
            Py_XDECREF(base);
        }
        PyErr_Clear();
        Py_DECREF(mro);
        if (!derived) continue;
        abstract = PyObject_GetAttrString(cls, "__abstractmethods__");
        is_abstract = abstract && PyObject_IsTrue(abstract) == 1;
        PyErr_Clear();
        Py_XDECREF(abstract);
        if (is_abstract) continue;
        if (len > best_len) {
            best = cls;
            best_len = len;
            ambiguous = 0;
        } else if (len == best_len && cls != best) {
            ambiguous = 1;
        }
    }
    if (best && !ambiguous) Py_INCREF(best);
    Py_DECREF(values);
    if (!best)
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: module '%s' has no concrete "
                 "subclass of pythonfmu's Fmi2Slave", module_name);
    else if (ambiguous)
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: module '%s' has several "
                 "Fmi2Slave subclasses of the same depth; cannot tell which is the model",
                 module_name);
    return best && !ambiguous ? best : NULL;
}

/* Is `e` the enum member called `name` (Fmi2Causality.output is "output")? None is not. */
static int enum_is(PyObject *e, const char *name) {
    PyObject *n = e && e != Py_None ? PyObject_GetAttrString(e, "name") : NULL;
    int eq = n && PyUnicode_Check(n) && PyUnicode_CompareWithASCIIString(n, name) == 0;
    if (e && e != Py_None && !n) PyErr_Clear();
    Py_XDECREF(n);
    return eq;
}

static int read_one_variable(GlueInstance *g, PyObject *var, GlueVar *v) {
    static const char *const types[] = {"Real", "Integer", "Boolean", "String"};
    PyObject *cls = PyObject_Type(var);
    PyObject *mro = cls ? PyObject_GetAttrString(cls, "__mro__") : NULL;
    PyObject *name = PyObject_GetAttrString(var, "name");
    PyObject *caus = PyObject_GetAttrString(var, "causality");
    PyObject *varb = PyObject_GetAttrString(var, "variability");
    PyObject *setter = PyObject_GetAttrString(var, "setter");
    Py_ssize_t k, len = mro ? PySequence_Size(mro) : 0;
    int t = -1, ok = 0;
    for (k = 0; k < len && t < 0; k++) {               /* Real, Integer, ... or a subclass */
        PyObject *base = PySequence_GetItem(mro, k);
        int j;
        for (j = 0; base && j < 4 && t < 0; j++)
            if (has_name(base, types[j])) t = j;
        Py_XDECREF(base);
    }
    if (name && caus && varb && setter && t >= 0 && (v->name = c_string(name)) != NULL) {
        v->type = (GlueType)t;
        v->causality = enum_is(caus, "parameter") ? GLUE_PARAMETER
                     : enum_is(caus, "calculatedParameter") ? GLUE_CALCULATED_PARAMETER
                     : enum_is(caus, "input") ? GLUE_INPUT
                     : enum_is(caus, "output") ? GLUE_OUTPUT
                     : enum_is(caus, "independent") ? GLUE_INDEPENDENT
                     : GLUE_LOCAL;                      /* FMI's default */
        v->variability = enum_is(varb, "constant") ? GLUE_CONSTANT
                       : enum_is(varb, "fixed") ? GLUE_FIXED
                       : enum_is(varb, "tunable") ? GLUE_TUNABLE
                       : enum_is(varb, "discrete") ? GLUE_DISCRETE
                       : GLUE_CONTINUOUS;               /* FMI's default */
        v->settable = setter != Py_None;
        ok = 1;
    } else if (!PyErr_Occurred()) {
        glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: a registered variable of %s "
                 "is not a pythonfmu Real, Integer, Boolean or String", g->model_name);
    }
    Py_XDECREF(setter);
    Py_XDECREF(varb);
    Py_XDECREF(caus);
    Py_XDECREF(name);
    Py_XDECREF(mro);
    Py_XDECREF(cls);
    return ok;
}

/* The variable table from slave.vars (value reference -> ScalarVariable), read once: the glue
   checks every value reference against it before Python sees one. */
static int read_variables(GlueInstance *g, PyObject *slave) {
    PyObject *vars = PyObject_GetAttrString(slave, "vars");
    PyObject *items = vars ? PyMapping_Items(vars) : NULL;
    Py_ssize_t i, n = items ? PyList_Size(items) : -1;
    unsigned long max_vr = 0;
    int ok = n >= 0;
    for (i = 0; ok && i < n; i++) {                   /* the table's size: the largest vr */
        unsigned long vr = PyLong_AsUnsignedLong(PyTuple_GetItem(PyList_GetItem(items, i), 0));
        if (PyErr_Occurred() || vr > 1000000UL) {
            PyErr_Clear();
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: %s has a value reference "
                     "that is not an integer in 0..1000000", g->model_name);
            ok = 0;
        } else if (vr > max_vr) {
            max_vr = vr;
        }
    }
    if (ok) ok = glue_alloc_vars(g, n > 0 ? (size_t)max_vr + 1 : 0);
    for (i = 0; ok && i < n; i++) {
        PyObject *pair = PyList_GetItem(items, i);
        unsigned long vr = PyLong_AsUnsignedLong(PyTuple_GetItem(pair, 0));
        if (g->vars[vr].name) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2Instantiate: value reference %lu is "
                     "registered twice", vr);
            ok = 0;
        } else {
            ok = read_one_variable(g, PyTuple_GetItem(pair, 1), &g->vars[vr]);
        }
    }
    Py_XDECREF(items);
    Py_XDECREF(vars);
    return ok;
}

/* The log categories the slave declares (fmi2SetDebugLogging accepts these only). */
static void read_categories(GlueInstance *g, PyObject *slave) {
    PyObject *cats = PyObject_GetAttrString(slave, "log_categories");
    PyObject *keys = cats && PyDict_Check(cats) ? PyDict_Keys(cats) : NULL;
    Py_ssize_t i, n = keys ? PyList_Size(keys) : 0;
    for (i = 0; i < n; i++) {
        PyObject *b = utf8_bytes(PyList_GetItem(keys, i));
        if (b) glue_add_category(g, bytes_text(b, ""));
        Py_XDECREF(b);
    }
    if (keys) glue_add_category(g, "logAll");       /* pythonfmu's default for status ok */
    PyErr_Clear();
    Py_XDECREF(keys);
    Py_XDECREF(cats);
}

fmi2Status model_instantiate(GlueInstance *g) {
    PySlave *p = calloc(1, sizeof *p);
    PyGILState_STATE gil;
    PyObject *module = NULL, *model_name = NULL;
    char module_name[256];
    int ok;
    fmi2Status status;
    g->model = p;
    if (!p) return fmi2Error;
    if (!python_running(g, "fmi2Instantiate", 1)) return fmi2Fatal;
    gil = PyGILState_Ensure();
    ok = read_module_name(g, module_name, sizeof module_name) && add_to_sys_path(g);
    if (ok) {
        module = PyImport_ImportModule(module_name);
        ok = module != NULL;
    }
    if (ok) ok = (p->cls = find_slave_class(g, module, module_name)) != NULL;
    if (ok) {
        model_name = PyObject_GetAttrString(p->cls, "__name__");
        ok = model_name && (g->model_name = c_string(model_name)) != NULL;
    }
    if (ok) ok = make_slave(g, p->cls, &p->s, "fmi2Instantiate");
    if (ok) ok = read_variables(g, p->s.slave);
    if (ok) read_categories(g, p->s.slave);
    Py_XDECREF(model_name);
    Py_XDECREF(module);
    status = finish(g, &p->s, "fmi2Instantiate", ok ? fmi2OK : fmi2Error);
    PyGILState_Release(gil);
    return status;
}

void model_free(GlueInstance *g) {
    PySlave *p = MODEL(g);
    if (!p) return;
    if (Py_IsInitialized()) {
        PyGILState_STATE gil = PyGILState_Ensure();
        forward_log(g, &p->s);
        release_slave(&p->s);
        Py_CLEAR(p->cls);
        PyErr_Clear();
        PyGILState_Release(gil);
    }   /* else the interpreter is gone and its objects with it: free only our memory */
    free(p);
    g->model = NULL;
}

fmi2Status model_reset(GlueInstance *g) {
    PySlave *p = MODEL(g);
    Slave fresh;
    PyGILState_STATE gil;
    fmi2Status status;
    if (!python_running(g, "fmi2Reset", 0)) return fmi2Fatal;
    gil = PyGILState_Ensure();
    forward_log(g, &p->s);
    /* a fresh slave holds the start values; the old one goes only once the new one exists */
    if (make_slave(g, p->cls, &fresh, "fmi2Reset")) {
        release_slave(&p->s);
        p->s = fresh;
        status = finish(g, &p->s, "fmi2Reset", fmi2OK);
    } else {
        status = finish(g, &p->s, "fmi2Reset", fmi2Error);
    }
    PyGILState_Release(gil);
    return status;
}

/* ------------------------------------------------------------------------- calls */

/* Every call on a live slave: is Python there (else fmi2Fatal)? then take the GIL. */
#define ENTER(function)                                                                        \
    if (!python_running(g, (function), 0)) return fmi2Fatal;                                   \
    PyGILState_STATE gil = PyGILState_Ensure()

/* ... and leave: forward the log, report an exception, release the GIL. */
#define LEAVE(function, status)                                                                \
    do {                                                                                       \
        fmi2Status final_ = finish(g, &MODEL(g)->s, (function), (status));                    \
        PyGILState_Release(gil);                                                               \
        return final_;                                                                         \
    } while (0)

/* Call `method` with `args` (a new reference or NULL after a failure to build them; consumed). */
static PyObject *call(PyObject *method, PyObject *args) {
    PyObject *r;
    if (!args) return NULL;                  /* building the arguments failed: exception set */
    r = PyObject_CallObject(method, args);
    Py_DECREF(args);
    return r;
}

static PyObject *none(void) {
    Py_INCREF(Py_None);
    return Py_None;
}

/* A call whose result is of no interest; fmi2OK or fmi2Error. */
static fmi2Status plain(PyObject *r) {
    Py_XDECREF(r);
    return r ? fmi2OK : fmi2Error;
}

fmi2Status model_setup_experiment(GlueInstance *g, int tolerance_defined, double tolerance,
                                  double start_time, int stop_time_defined, double stop_time) {
    ENTER("fmi2SetupExperiment");
    /* pythonfmu's signature: setup_experiment(start_time, stop_time or None, tolerance or None) */
    PyObject *r = call(MODEL(g)->s.method[M_SETUP],
                       Py_BuildValue("(dNN)", start_time,
                                     stop_time_defined ? PyFloat_FromDouble(stop_time) : none(),
                                     tolerance_defined ? PyFloat_FromDouble(tolerance) : none()));
    LEAVE("fmi2SetupExperiment", plain(r));
}

fmi2Status model_enter_initialization_mode(GlueInstance *g) {
    ENTER("fmi2EnterInitializationMode");
    LEAVE("fmi2EnterInitializationMode", plain(PyObject_CallObject(MODEL(g)->s.method[M_ENTER_INIT], NULL)));
}

fmi2Status model_exit_initialization_mode(GlueInstance *g) {
    ENTER("fmi2ExitInitializationMode");
    LEAVE("fmi2ExitInitializationMode", plain(PyObject_CallObject(MODEL(g)->s.method[M_EXIT_INIT], NULL)));
}

fmi2Status model_terminate(GlueInstance *g) {
    ENTER("fmi2Terminate");
    LEAVE("fmi2Terminate", plain(PyObject_CallObject(MODEL(g)->s.method[M_TERMINATE], NULL)));
}

fmi2Status model_do_step(GlueInstance *g, double current_time, double step_size) {
    fmi2Status status = fmi2Error;
    ENTER("fmi2DoStep");
    PyObject *r = call(MODEL(g)->s.method[M_DO_STEP], Py_BuildValue("(dd)", current_time, step_size));
    if (r) {
        if (PyLong_Check(r) && !PyBool_Check(r)) {   /* a status (Fmi2Status): OK .. Error */
            long s = PyLong_AsLong(r);
            status = s >= fmi2OK && s <= fmi2Error ? (fmi2Status)s : fmi2Error;
        } else {                             /* a bool; False: discarded (logged by do_step) */
            int accepted = PyObject_IsTrue(r);
            status = accepted > 0 ? fmi2OK : accepted == 0 ? fmi2Discard : fmi2Error;
        }
        Py_DECREF(r);
    }
    LEAVE("fmi2DoStep", status);
}

static PyObject *vr_list(const fmi2ValueReference vr[], size_t nvr) {
    PyObject *list = PyList_New((Py_ssize_t)nvr);
    size_t i;
    for (i = 0; list && i < nvr; i++) {
        PyObject *item = PyLong_FromUnsignedLong(vr[i]);   /* small ints: cached by CPython */
        if (!item) {
            Py_CLEAR(list);
            break;
        }
        PyList_SetItem(list, (Py_ssize_t)i, item);          /* steals item */
    }
    return list;
}

static const char *const get_names[] = {"fmi2GetReal", "fmi2GetInteger", "fmi2GetBoolean",
                                        "fmi2GetString"};
static const char *const set_names[] = {"fmi2SetReal", "fmi2SetInteger", "fmi2SetBoolean",
                                        "fmi2SetString"};

/* Copy the slave's answer into the host's array. 0 with an exception pending or logged. */
static int store_values(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], PyObject *r,
                        size_t nvr, void *values) {
    PyObject *small[64], **held = small;      /* String: the UTF-8 bytes until copied */
    size_t i, total = 0;
    int ok = 1;
    Py_ssize_t n = PySequence_Size(r);
    if (n != (Py_ssize_t)nvr) {
        if (!PyErr_Occurred())
            glue_log(g, fmi2Error, "logStatusError", "%s: the slave returned %zd values for %zu "
                     "value references", get_names[type], n, nvr);
        return 0;
    }
    if (type == GLUE_STRING) {
        if (nvr > sizeof small / sizeof small[0] && !(held = calloc(nvr, sizeof *held))) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2GetString: out of memory");
            return 0;
        }
        if (held == small) memset(small, 0, sizeof small);
    }
    for (i = 0; ok && i < nvr; i++) {
        PyObject *item = PySequence_GetItem(r, (Py_ssize_t)i);
        if (!item) {
            ok = 0;
            break;
        }
        switch (type) {
        case GLUE_REAL: {
            double d = PyFloat_AsDouble(item);
            ok = !(d == -1.0 && PyErr_Occurred());
            ((fmi2Real *)values)[i] = d;
            break;
        }
        case GLUE_INTEGER: {
            int overflow = 0;
            long v = PyLong_AsLongAndOverflow(item, &overflow);
            ok = !(v == -1 && PyErr_Occurred());
            if (ok && (overflow || v < INT_MIN || v > INT_MAX)) {
                glue_log(g, fmi2Error, "logStatusError", "fmi2GetInteger: the value of '%s' "
                         "(value reference %u) does not fit in an fmi2Integer",
                         g->vars[vr[i]].name, (unsigned)vr[i]);
                ok = 0;
            }
            ((fmi2Integer *)values)[i] = (fmi2Integer)v;
            break;
        }
        case GLUE_BOOLEAN: {
            int b = PyObject_IsTrue(item);
            ok = b >= 0;
            ((fmi2Boolean *)values)[i] = b > 0 ? fmi2True : fmi2False;
            break;
        }
        case GLUE_STRING:
            if (PyUnicode_Check(item)) {
                held[i] = PyUnicode_AsEncodedString(item, "utf-8", "backslashreplace");
            } else {
                glue_log(g, fmi2Error, "logStatusError", "fmi2GetString: the slave returned a "
                         "value that is not a str for '%s' (value reference %u)",
                         g->vars[vr[i]].name, (unsigned)vr[i]);
            }
            ok = held[i] != NULL;
            if (ok) total += (size_t)PyBytes_Size(held[i]) + 1;
            break;
        }
        Py_DECREF(item);
    }
    if (type == GLUE_STRING) {
        char *space = ok ? glue_string_space(g, total ? total : 1) : NULL;
        if (ok && !space) {
            glue_log(g, fmi2Error, "logStatusError", "fmi2GetString: out of memory");
            ok = 0;
        }
        for (i = 0; i < nvr && held[i]; i++) {
            if (ok) {          /* the strings stay valid until the next call on this instance */
                size_t len = (size_t)PyBytes_Size(held[i]);
                memcpy(space, PyBytes_AsString(held[i]), len + 1);
                ((fmi2String *)values)[i] = space;
                space += len + 1;
            }
            Py_DECREF(held[i]);
        }
        if (held != small) free(held);
    }
    return ok;
}

fmi2Status model_get(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     void *values) {
    int ok;
    ENTER(get_names[type]);
    PyObject *vrs = vr_list(vr, nvr);
    PyObject *r = vrs ? call(MODEL(g)->s.method[M_GET + type], Py_BuildValue("(N)", vrs)) : NULL;
    ok = r && store_values(g, type, vr, r, nvr, values);
    Py_XDECREF(r);
    LEAVE(get_names[type], ok ? fmi2OK : fmi2Error);
}

static PyObject *value_list(GlueType type, size_t nvr, const void *values) {
    PyObject *list = PyList_New((Py_ssize_t)nvr);
    size_t i;
    for (i = 0; list && i < nvr; i++) {
        PyObject *item = NULL;
        switch (type) {
        case GLUE_REAL: item = PyFloat_FromDouble(((const fmi2Real *)values)[i]); break;
        case GLUE_INTEGER: item = PyLong_FromLong(((const fmi2Integer *)values)[i]); break;
        case GLUE_BOOLEAN:
            item = PyBool_FromLong(((const fmi2Boolean *)values)[i] != fmi2False);
            break;
        case GLUE_STRING: {
            const char *s = ((const fmi2String *)values)[i];   /* valid UTF-8: the glue checked */
            item = PyUnicode_DecodeUTF8(s, (Py_ssize_t)strlen(s), "strict");
            break;
        }
        }
        if (!item) {
            Py_CLEAR(list);
            break;
        }
        PyList_SetItem(list, (Py_ssize_t)i, item);
    }
    return list;
}

fmi2Status model_set(GlueInstance *g, GlueType type, const fmi2ValueReference vr[], size_t nvr,
                     const void *values) {
    ENTER(set_names[type]);
    PyObject *vrs = vr_list(vr, nvr), *vals = vrs ? value_list(type, nvr, values) : NULL;
    PyObject *r = NULL;
    if (vals)
        r = call(MODEL(g)->s.method[M_SET + type], Py_BuildValue("(NN)", vrs, vals));
    else
        Py_XDECREF(vrs);
    LEAVE(set_names[type], plain(r));
}
