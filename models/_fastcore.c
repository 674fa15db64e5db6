/* Compiled bodies of the chain's per-step hot paths (issue 7), optional.
 *
 * Each function here is the body of one Python method, operating on the same Python objects
 * (attributes read at entry, written at exit), so the Python classes stay the only state and
 * the Python code stays the reference:
 *   plant_advance    models.dynamics.CarPlant.advance (+ _update_outputs)
 *   ident_update     models.identification.ParameterIdentifier.update, recursive path, mu = 1/n
 *   ident_covariance models.identification.ParameterIdentifier._covariance_flat, mu = 1/n
 *   filter_update    models.filters.MotionFilter.update (kinds 1-3)
 *   filter_predict   models.filters.MotionFilter.predict (EKF)
 * Every expression keeps Python's operand order and association, x ** 2 is pow(x, 2.0) as in
 * CPython, and the module is compiled with -ffp-contract=off (no fused multiply-add), so the
 * results are bit-identical to the Python code (tests/test_fastcore.py compares them exactly).
 * Where Python would raise (division by zero, sqrt of a negative), these raise the same error.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>

#if PY_VERSION_HEX >= 0x030D0000
#define LOOKUP_ATTR PyObject_GetOptionalAttr        /* 3.13: public name */
#else
#define LOOKUP_ATTR _PyObject_LookupAttr
#endif

static double G_ACC = 9.81;   /* set from models.units.G by set_constants() */
static unsigned long long steps_compiled = 0, steps_declined = 0;   /* chain_step's answers */
static unsigned long long full_checks = 0;                          /* guard_ok's dict walks */

/* CPython's x ** 2 calls libm's pow(), which is not always x * x (last bit, ~0.1 % of values);
 * GCC folds pow(x, 2.0) into x * x, so it is called through a pointer it cannot see through. */
static double (*volatile libm_pow)(double, double) = pow;
static inline double py_square(double x) { return libm_pow(x, 2.0); }

/* ------------------------------------------------------------------ attribute helpers */

enum {
    A_p, A_state, A_time, A_grid_index, A_h, A_noise_std, A_station_dwell, A_normal,
    A_grade_profile, A_traction_impulse, A_brake_impulse, A_mass, A_adhesion_mass_fraction,
    A_adhesion_factor, A_traction_force_max, A_traction_power_max, A_brake_force_max, A_A0,
    A_A1, A_A2, A_gamma, A_length, A_distances, A_grades, A_cum, A_speed, A_position,
    A_still_time, A_stops, A_acceleration, A_traction_force, A_brake_force, A_grade, A_mode,
    A_cfg, A_frozen, A_S, A_forgetting, A_dt, A_n, A_theta, A_cov, A_sigma2, A_W, A_D,
    A_last_phi, A_window, A_window_sum, A_LAG, A_n_cL, A_cL, A_c0, A_c1, A_n_c1, A_last_err,
    A_q_e, A_s2, A_s2_ref, A_J, A_j0, A_s2_prior, A_kind, A_r0, A_r1, A_position_std_rel,
    A_position_std, A_vzad_bar, A_vzad_hat, A_xb0, A_xb1, A_m00, A_m01, A_m11, A_xh0, A_xh1,
    A_p00, A_p01, A_p11, A_buf, A_i,
    /* chain level */
    A_plant, A_estimator, A_ident, A_filter, A_station, A_start_time, A_base_mass,
    A_sample_index, A_sample_period, A_sensor_speed, A_sensor_position, A_speed_noise,
    A_position_noise, A_speed_std, A_prev, A_pair_used, A_forces, A_dt_private, A_v_thr, A_x_thr,
    A_dwell, A_fast_run, A_moving, A_restarted, A_MOVING_RUN, A_station_stops, A_dt_nominal,
    A_sigma2_initial, A_track_speed, A_track_time, A_batch_y,
    A_m_covariance_flat, A_m_sigma2, A_m_update, A_m_restart_mass, A_m_measure,
    A_kw_contiguous, A_scale, A_core_guard,
    /* the innovation gate (MotionFilter.gate) and the information cap (OnlineEstimator._excited) */
    A_rejected, A_speed_run, A_position_run, A_speed_fit, A_reacquire, A_GATE_SIGMAS,
    A_FIT_SIGMAS, A_REACQUIRE, A_prev_fit,
    A_net_force, A_steady_speed, A_steady_force, A_steady_time, A_force_band, A_STEADY_SPEED,
    A_STEADY_TIME, A_FORCE_SMOOTHING,
    A_count
};
static const char *ATTR_NAMES[A_count] = {
    "p", "state", "time", "_grid_index", "h", "noise_std", "station_dwell", "_normal",
    "grade_profile", "traction_impulse", "brake_impulse", "mass", "adhesion_mass_fraction",
    "adhesion_factor", "traction_force_max", "traction_power_max", "brake_force_max", "A0",
    "A1", "A2", "gamma", "length", "distances", "grades", "_cum", "speed", "position",
    "still_time", "stops", "acceleration", "traction_force", "brake_force", "grade", "mode",
    "cfg", "frozen", "_S", "forgetting", "dt", "n", "_theta", "_cov", "_sigma2", "_W", "_D",
    "_last_phi", "_window", "_window_sum", "LAG", "_n_cL", "cL", "c0", "c1", "_n_c1", "_last_err",
    "q_e", "s2", "s2_ref", "_J", "_j0", "s2_prior", "kind", "_r0", "_r1", "position_std_rel",
    "position_std", "vzad_bar", "vzad_hat", "_xb0", "_xb1", "_m00", "_m01", "_m11", "_xh0", "_xh1",
    "_p00", "_p01", "_p11", "_buf", "_i",
    "plant", "estimator", "ident", "filter", "station", "start_time", "base_mass",
    "_sample_index", "sample_period", "sensor_speed", "sensor_position", "_speed_noise",
    "_position_noise", "speed_std", "_prev", "_pair_used", "_forces", "_dt", "v_thr", "x_thr",
    "dwell", "_fast_run", "moving", "_restarted", "MOVING_RUN", "station_stops", "dt_nominal",
    "sigma2_initial", "track_speed", "track_time", "_batch_y",
    "_covariance_flat", "sigma2", "update", "restart_mass", "measure",
    "contiguous", "_scale", "_core_guard",
    "rejected", "speed_run", "position_run", "speed_fit", "_reacquire", "GATE_SIGMAS",
    "FIT_SIGMAS", "REACQUIRE", "_prev_fit",
    "_net_force", "_steady_speed", "_steady_force", "_steady_time", "_force_band", "STEADY_SPEED",
    "STEADY_TIME", "FORCE_SMOOTHING",
};
static PyObject *ATTR[A_count];

/* Attribute access through the instance __dict__. Every attribute read or written here is a
 * plain instance attribute (no property or other data descriptor of that name on the class),
 * so o.__dict__[name] is what getattr/setattr would reach, minus the type lookup that took a
 * third of the step. The dicts of the objects touched in one top-level call are cached (with
 * references, so an address cannot be reused); names not in the dict (class attributes such as
 * LAG), objects with their own __getattribute__, and writes to objects with their own __setattr__
 * (frozen dataclasses) go through getattr/setattr. */
#define DICT_CACHE_BITS 6
#define DICT_CACHE (1 << DICT_CACHE_BITS)    /* direct-mapped by address */
static struct { PyObject *obj, *dict; int writable; } dcache[DICT_CACHE];
static int call_depth = 0;

/* The cached entry of o (borrowed dict), or NULL: use getattr/setattr. */
/* Fibonacci hashing of an address to `bits` bits: objects and dicts of one chain come from
 * the same allocator pools, and the low address bits alone sent three dicts to one slot. */
static inline int addr_slot(const void *p, int bits)
{
    return (int)(((uint64_t)(uintptr_t)p * 0x9E3779B97F4A7C15ull) >> (64 - bits));
}
static inline int dslot(PyObject *o) { return addr_slot(o, DICT_CACHE_BITS); }

static PyObject *inst_dict(PyObject *o, int for_write)
{
    int k = dslot(o);
    if (dcache[k].obj == o) return (for_write && !dcache[k].writable) ? NULL : dcache[k].dict;
    PyTypeObject *tp = Py_TYPE(o);
    if (tp->tp_getattro != PyObject_GenericGetAttr) return NULL;
    int writable = tp->tp_setattro == PyObject_GenericSetAttr;   /* not frozen dataclasses */
    PyObject **dp = _PyObject_GetDictPtr(o);
    if (!dp || !*dp || !PyDict_CheckExact(*dp)) { PyErr_Clear(); return NULL; }
    if (dcache[k].obj == NULL) {            /* a free slot: cache it; taken: just use it */
        dcache[k].obj = Py_NewRef(o);
        dcache[k].dict = Py_NewRef(*dp);
        dcache[k].writable = writable;
    }
    /* borrowed: every object passed here is held by the caller for the whole call */
    return (for_write && !writable) ? NULL : *dp;
}

static void call_enter(void) { call_depth++; }

static void call_leave(void)
{
    if (--call_depth > 0) return;
    /* Detach the table before releasing: a release can run a __del__ that calls back in. */
    PyObject *held[2 * DICT_CACHE];
    int n = 0;
    for (int i = 0; i < DICT_CACHE; i++)
        if (dcache[i].obj) {
            held[n++] = dcache[i].obj;
            held[n++] = dcache[i].dict;
            dcache[i].obj = dcache[i].dict = NULL;
        }
    while (n > 0) Py_DECREF(held[--n]);
}


static PyObject *ga(PyObject *o, int a)       /* new reference */
{
    PyObject *d = inst_dict(o, 0);
    if (d) {
        PyObject *v = PyDict_GetItemWithError(d, ATTR[a]);
        if (v) return Py_NewRef(v);
        if (PyErr_Occurred()) return NULL;
        v = _PyType_Lookup(Py_TYPE(o), ATTR[a]);       /* a class attribute such as LAG */
        if (v && Py_TYPE(v)->tp_descr_get == NULL) return Py_NewRef(v);
    }
    return PyObject_GetAttr(o, ATTR[a]);
}

static int sa(PyObject *o, int a, PyObject *v)
{
    PyObject *d = inst_dict(o, 1);
    return d ? PyDict_SetItem(d, ATTR[a], v) : PyObject_SetAttr(o, ATTR[a], v);
}

/* The compiled functions replicate the bodies of these objects' methods (and of the methods
 * those call). A method replaced on an instance (a study recording the forces by wrapping
 * estimator.propagate, a test pinning ident.sigma2) must be honoured: the Python code then runs.
 * guard_ok(owner, objs, n) is false when an object's instance dict holds a name that its type
 * defines as a descriptor (a function, property, classmethod...) or when a class whose methods
 * are compiled was changed since import (remember_classes, called as each module is imported:
 * its version tag). The dict walk is remembered in the owner's own bytearray _core_guard (set
 * empty by its __init__): each object's dict size and its type's version tag when last walked; the
 * walk is re-run when either changes (a replaced method adds a key; deleting an attribute and
 * adding a method in one go is not seen). A patched module-level function is checked in Python
 * when an object is built (models/_fast.py). */
#define MAX_CLASSES 32
static struct { PyTypeObject *type; unsigned int tag; PyObject *dict; } classes[MAX_CLASSES];
static int n_classes = 0;

/* A type's version tag now, assigned if it has none (0: none can be). A change of the class
 * (PyType_Modified) sets it to 0 and a new one is assigned later: 3.11-3.13 alike; 3.12 and
 * later no longer keep Py_TPFLAGS_VALID_VERSION_TAG. */
static unsigned int class_tag(PyTypeObject *tp)
{
    if (!tp->tp_version_tag) {
#if PY_VERSION_HEX >= 0x030C0000
        (void)PyUnstable_Type_AssignVersionTag(tp);
#else
        (void)_PyType_Lookup(tp, ATTR[0]);           /* assigns one when it can */
#endif
    }
    return tp->tp_version_tag;
}

/* The class's namespace holds the same objects as when remembered (a patch undone) */
static int same_namespace(PyObject *now, PyObject *then)
{
    if (PyDict_GET_SIZE(now) != PyDict_GET_SIZE(then)) return 0;
    PyObject *key, *val;
    Py_ssize_t pos = 0;
    while (PyDict_Next(then, &pos, &key, &val)) {
        PyObject *cur = PyDict_GetItemWithError(now, key);
        if (cur != val) { PyErr_Clear(); return 0; }
    }
    return 1;
}

static int class_unchanged(PyTypeObject *tp)
{
    for (int i = 0; i < n_classes; i++) {
        if (classes[i].type != tp) continue;
        unsigned int tag = class_tag(tp);
        if (tag && tag == classes[i].tag) return 1;
        /* modified since: unchanged only if every attribute is back (monkeypatch undone) */
        if (!tag || !same_namespace(tp->tp_dict, classes[i].dict)) return 0;
        classes[i].tag = tag;
        return 1;
    }
    return 1;                                /* not a class whose methods are compiled */
}

/* The object's dict shadows no method of its type (walks it) */
static int no_method_shadowed(PyObject *d, PyTypeObject *tp)
{
    full_checks++;
    PyObject *key, *val;
    Py_ssize_t pos = 0;
    while (PyDict_Next(d, &pos, &key, &val)) {
        if (!PyUnicode_Check(key)) continue;
        PyObject *attr = _PyType_Lookup(tp, key);           /* borrowed, no exception */
        if (attr && Py_TYPE(attr)->tp_descr_get) return 0;
    }
    return 1;
}

static int guard_ok(PyObject *owner, PyObject *const *objs, int n)
{
    PyObject *g = ga(owner, A_core_guard);
    if (!g) { PyErr_Clear(); return 0; }     /* cannot tell: take the Python step */
    int ok = 1;
    Py_ssize_t need = 2 * n * (Py_ssize_t)sizeof(Py_ssize_t);
    if (!PyByteArray_CheckExact(g)
        || (PyByteArray_GET_SIZE(g) != need && PyByteArray_Resize(g, need))) {   /* zeros: walk */
        PyErr_Clear();
        ok = 0;
        goto done;
    }
    Py_ssize_t *rec = (Py_ssize_t *)PyByteArray_AS_STRING(g);   /* size, tag per object */
    for (int i = 0; i < n; i++) {
        PyObject *d = inst_dict(objs[i], 0);
        if (!d) { PyErr_Clear(); ok = 0; break; }
        PyTypeObject *tp = Py_TYPE(objs[i]);
        Py_ssize_t size = PyDict_GET_SIZE(d);
        Py_ssize_t tag = (Py_ssize_t)tp->tp_version_tag;
        if (tag && rec[2 * i] == size && rec[2 * i + 1] == tag) continue;
        if (!class_unchanged(tp) || !no_method_shadowed(d, tp)) { ok = 0; break; }
        rec[2 * i] = size;
        rec[2 * i + 1] = (Py_ssize_t)class_tag(tp);   /* 0 (none): walk again next time */
    }
done:
    Py_DECREF(g);
    return ok;
}

/* remember_classes(*classes): their namespaces and version tags as first seen, see guard_ok */
static PyObject *remember_classes(PyObject *self, PyObject *args)
{
    (void)self;
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(args); i++) {
        PyObject *c = PyTuple_GET_ITEM(args, i);
        if (!PyType_Check(c)) { PyErr_SetString(PyExc_TypeError, "remember_classes takes classes"); return NULL; }
        PyTypeObject *tp = (PyTypeObject *)c;
        int j = 0;
        while (j < n_classes && classes[j].type != tp) j++;
        if (j < n_classes) continue;          /* the first state seen is the original */
        if (n_classes == MAX_CLASSES) { PyErr_SetString(PyExc_ValueError, "too many classes"); return NULL; }
        PyObject *copy = PyDict_Copy(tp->tp_dict);
        if (!copy) return NULL;
        classes[n_classes].type = (PyTypeObject *)Py_NewRef(c);
        classes[n_classes].dict = copy;
        classes[n_classes++].tag = class_tag(tp);
    }
    Py_RETURN_NONE;
}

static int getd(PyObject *o, int a, double *out)
{
    PyObject *v = ga(o, a);
    if (!v) return -1;
    *out = PyFloat_AsDouble(v);
    Py_DECREF(v);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

static int getl(PyObject *o, int a, long *out)
{
    PyObject *v = ga(o, a);
    if (!v) return -1;
    *out = PyLong_AsLong(v);
    Py_DECREF(v);
    return (*out == -1 && PyErr_Occurred()) ? -1 : 0;
}

static int setd(PyObject *o, int a, double x)
{
    PyObject *v = PyFloat_FromDouble(x);
    if (!v) return -1;
    int r = sa(o, a, v);
    Py_DECREF(v);
    return r;
}

static int setl(PyObject *o, int a, long x)
{
    PyObject *v = PyLong_FromLong(x);
    if (!v) return -1;
    int r = sa(o, a, v);
    Py_DECREF(v);
    return r;
}

/* A list or tuple of n numbers into buf (ints are converted like Python's int + float). */
static int seq_to_doubles(PyObject *seq, double *buf, Py_ssize_t n, const char *what)
{
    PyObject *fast = PySequence_Fast(seq, what);
    if (!fast) return -1;
    if (PySequence_Fast_GET_SIZE(fast) != n) {
        Py_DECREF(fast);
        PyErr_Format(PyExc_ValueError, "%s: expected %zd values", what, n);
        return -1;
    }
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (Py_ssize_t i = 0; i < n; i++) {
        buf[i] = PyFloat_AsDouble(items[i]);
        if (buf[i] == -1.0 && PyErr_Occurred()) { Py_DECREF(fast); return -1; }
    }
    Py_DECREF(fast);
    return 0;
}

/* A new list (or tuple) of n floats */
static PyObject *doubles_to_seq(const double *buf, Py_ssize_t n, int tuple)
{
    PyObject *seq = tuple ? PyTuple_New(n) : PyList_New(n);
    if (!seq) return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(buf[i]);
        if (!f) { Py_DECREF(seq); return NULL; }
        if (tuple) PyTuple_SET_ITEM(seq, i, f); else PyList_SET_ITEM(seq, i, f);
    }
    return seq;
}

static inline PyObject *doubles_to_list(const double *buf, Py_ssize_t n) { return doubles_to_seq(buf, n, 0); }
static inline PyObject *doubles_to_tuple(const double *buf, Py_ssize_t n) { return doubles_to_seq(buf, n, 1); }

static int zero_division(void)
{
    PyErr_SetString(PyExc_ZeroDivisionError, "float division by zero");
    return -1;
}

/* Python's max(a, b) and min(a, b) for floats: the first unless the second is strictly
 * greater (smaller). */
static inline double py_max(double a, double b) { return b > a ? b : a; }

/* ------------------------------------------------------------------ grade profile */

typedef struct {
    PyObject *distances, *grades, *cum;   /* borrowed from the GradeProfile (tuples) */
    Py_ssize_t n;
} Grade;

static inline double titem(PyObject *t, Py_ssize_t i)
{
    PyObject *o = PyTuple_GET_ITEM(t, i);
    return PyFloat_CheckExact(o) ? PyFloat_AS_DOUBLE(o) : PyFloat_AsDouble(o);
}

/* bisect.bisect_right(distances, x) */
static inline Py_ssize_t bisect_right(const Grade *g, double x)
{
    Py_ssize_t lo = 0, hi = g->n;
    while (lo < hi) {
        Py_ssize_t mid = (lo + hi) / 2;
        if (x < titem(g->distances, mid)) hi = mid; else lo = mid + 1;
    }
    return lo;
}

static inline double grade_at(const Grade *g, double x)
{
    Py_ssize_t k = bisect_right(g, x) - 1;
    return titem(g->grades, k >= 0 ? k : 0);
}

static inline double grade_integral(const Grade *g, double x)
{
    Py_ssize_t k = bisect_right(g, x) - 1;
    if (k < 0) return titem(g->grades, 0) * (x - titem(g->distances, 0));
    return titem(g->cum, k) + titem(g->grades, k) * (x - titem(g->distances, k));
}

/* GradeProfile.average(x, length) */
static inline double grade_average(const Grade *g, double x, double length)
{
    if (length <= 0.0) return grade_at(g, x);
    return (grade_integral(g, x) - grade_integral(g, x - length)) / length;
}

/* GradeProfile is a frozen dataclass (its tuples are set once, in __init__): the last one
 * loaded is kept, with a reference, and reused while the same object comes back. */
static PyObject *grade_cache_obj = NULL;
static Grade grade_cache = {NULL, NULL, NULL, 0};

static int grade_load_uncached(PyObject *profile, Grade *g);

static int grade_load(PyObject *profile, Grade *g)
{
    if (profile != grade_cache_obj) {
        Grade fresh;
        if (grade_load_uncached(profile, &fresh)) return -1;
        Py_XDECREF(grade_cache.distances); Py_XDECREF(grade_cache.grades); Py_XDECREF(grade_cache.cum);
        Py_XSETREF(grade_cache_obj, Py_NewRef(profile));
        grade_cache = fresh;
    }
    *g = grade_cache;
    Py_INCREF(g->distances); Py_INCREF(g->grades); Py_INCREF(g->cum);
    return 0;
}

static int grade_load_uncached(PyObject *profile, Grade *g)
{
    g->distances = ga(profile, A_distances);
    g->grades = ga(profile, A_grades);
    g->cum = ga(profile, A_cum);
    if (!g->distances || !g->grades || !g->cum) goto fail;
    if (!PyTuple_Check(g->distances) || !PyTuple_Check(g->grades) || !PyTuple_Check(g->cum)) {
        PyErr_SetString(PyExc_TypeError, "GradeProfile: distances, grades and _cum must be tuples");
        goto fail;
    }
    g->n = PyTuple_GET_SIZE(g->distances);
    if (g->n < 1 || PyTuple_GET_SIZE(g->grades) != g->n || PyTuple_GET_SIZE(g->cum) != g->n) {
        PyErr_SetString(PyExc_ValueError, "GradeProfile: inconsistent lengths");
        goto fail;
    }
    return 0;
fail:
    Py_XDECREF(g->distances); Py_XDECREF(g->grades); Py_XDECREF(g->cum);
    g->distances = g->grades = g->cum = NULL;
    return -1;
}

static void grade_release(Grade *g)
{
    Py_XDECREF(g->distances); Py_XDECREF(g->grades); Py_XDECREF(g->cum);
}

/* ------------------------------------------------------------------ plant (models/dynamics.py) */

typedef struct {        /* held_input_dynamics's bound values */
    double k_adh, frac, f_max, p_max, b_max, a0, a1, a2, inv_weight, k_acc, length;
    double traction_demand, brake_demand, wind;
    int braking;
    Grade grade;
} Dyn;

static inline void dyn_forces(const Dyn *d, double v, double *f, double *b)
{
    double adh = d->k_adh * (0.161 + 7.5 / (fabs(v) * 3.6 + 44.0));
    if (d->braking) {
        double lim = adh / d->frac;
        double bd = d->brake_demand;
        *f = 0.0;
        *b = (bd < lim && bd < d->b_max) ? bd : (lim < d->b_max ? lim : d->b_max);
        return;
    }
    double lim = d->f_max;
    if (v > 0.0 && d->p_max / v < lim) lim = d->p_max / v;
    if (adh < lim) lim = adh;
    *f = d->traction_demand < lim ? d->traction_demand : lim;
    *b = 0.0;
}

static inline double dyn_accel(const Dyn *d, double v, double x)
{
    double f, b;
    dyn_forces(d, v, &f, &b);
    double va = v + d->wind;
    double spec = (f - b) * d->inv_weight - (d->a0 + d->a1 * v + d->a2 * va * fabs(va))
                  - grade_average(&d->grade, x, d->length);
    double a = d->k_acc * spec;
    return (v > 0.0 || a > 0.0) ? a : 0.0;
}

/* models.dynamics._rk4 */
static void rk4(const Dyn *d, double v, double x, double h, double *v_out, double *x_out)
{
    if (v <= 0.0 && dyn_accel(d, 0.0, x) <= 0.0) { *v_out = 0.0; *x_out = x; return; }
    double k1v = dyn_accel(d, v > 0.0 ? v : 0.0, x);
    double v2 = v + 0.5 * h * k1v;
    double k2v = dyn_accel(d, v2 > 0.0 ? v2 : 0.0, x + 0.5 * h * v);
    double v3 = v + 0.5 * h * k2v;
    double k3v = dyn_accel(d, v3 > 0.0 ? v3 : 0.0, x + 0.5 * h * v2);
    double v4 = v + h * k3v;
    double k4v = dyn_accel(d, v4 > 0.0 ? v4 : 0.0, x + h * v3);
    double v_new = v + h / 6.0 * (k1v + 2.0 * k2v + 2.0 * k3v + k4v);
    double x_new = x + h / 6.0 * (v + 2.0 * v2 + 2.0 * v3 + v4);
    if (v_new < 0.0) {
        double t_stop = h * v / (v - v_new);
        *v_out = 0.0;
        *x_out = x + 0.5 * v * t_stop;
        return;
    }
    *v_out = v_new;
    *x_out = x_new;
}

/* models.noise.NormalStream.__call__ without the Python call when the block has draws left;
 * any other callable (tests pass their own draws) is called. */
static int next_normal(PyObject *stream, double *out)
{
    PyObject *buf = NULL;
    if (LOOKUP_ATTR(stream, ATTR[A_buf], &buf) < 0) return -1;
    if (!buf) buf = Py_NewRef(Py_None);             /* any other callable: call it */
    long i;
    if (PyList_CheckExact(buf) && getl(stream, A_i, &i) == 0 && i >= 0 && i < PyList_GET_SIZE(buf)) {
        *out = PyFloat_AsDouble(PyList_GET_ITEM(buf, i));
        Py_DECREF(buf);
        if (*out == -1.0 && PyErr_Occurred()) return -1;
        return setl(stream, A_i, i + 1);
    }
    Py_DECREF(buf);
    if (PyErr_Occurred()) return -1;
    PyObject *r = PyObject_CallNoArgs(stream);     /* refills the block */
    if (!r) return -1;
    *out = PyFloat_AsDouble(r);
    Py_DECREF(r);
    return (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
}

/* CarPlant.advance(t_end, traction_demand, brake_demand, wind) on the plant object; -1 on error */
static int advance_impl(PyObject *plant, double t_end, double traction_demand, double brake_demand,
                        double wind)
{
    Dyn d;
    d.traction_demand = traction_demand;
    d.brake_demand = brake_demand;
    d.wind = wind;
    d.grade.distances = d.grade.grades = d.grade.cum = NULL;
    PyObject *p = NULL, *s = NULL, *normal = NULL, *profile = NULL;
    double mass, gamma, adh_factor;
    double time, h, noise_std, dwell, ti, bi;
    double speed, position, still_time;
    long grid_index, stops;
    p = ga(plant, A_p);
    s = p ? ga(plant, A_state) : NULL;
    normal = s ? ga(plant, A_normal) : NULL;
    profile = normal ? ga(plant, A_grade_profile) : NULL;
    if (!profile) goto fail;
    if (getd(p, A_mass, &mass) || getd(p, A_adhesion_mass_fraction, &d.frac)
        || getd(p, A_adhesion_factor, &adh_factor) || getd(p, A_traction_force_max, &d.f_max)
        || getd(p, A_traction_power_max, &d.p_max) || getd(p, A_brake_force_max, &d.b_max)
        || getd(p, A_A0, &d.a0) || getd(p, A_A1, &d.a1) || getd(p, A_A2, &d.a2)
        || getd(p, A_gamma, &gamma) || getd(p, A_length, &d.length)
        || getd(plant, A_time, &time) || getl(plant, A_grid_index, &grid_index)
        || getd(plant, A_h, &h) || getd(plant, A_noise_std, &noise_std)
        || getd(plant, A_station_dwell, &dwell) || getd(plant, A_traction_impulse, &ti)
        || getd(plant, A_brake_impulse, &bi) || getd(s, A_speed, &speed)
        || getd(s, A_position, &position) || getd(s, A_still_time, &still_time)
        || getl(s, A_stops, &stops) || grade_load(profile, &d.grade))
        goto fail;
    if (mass * G_ACC == 0.0 || 1.0 + gamma == 0.0 || d.frac == 0.0) { zero_division(); goto fail; }
    d.k_adh = 1000.0 * mass * d.frac * G_ACC * adh_factor;
    d.inv_weight = 1.0 / (mass * G_ACC);
    d.k_acc = G_ACC / 1000.0 / (1.0 + gamma);
    d.braking = d.brake_demand > 0.0;

    double eps = 1e-9 * py_max(1.0, fabs(t_end));
    while (time < t_end - eps) {
        double t_grid = (double)(grid_index + 1) * h;
        double t_next = t_grid <= t_end + eps ? t_grid : t_end;
        double hh = t_next - time;
        int was_still = speed <= 0.0;
        if (was_still && still_time >= dwell && position != 0.0) {
            if (dyn_accel(&d, 0.0, position) > 0.0) { position = 0.0; stops += 1; }
        }
        double f0, b0, f1, b1;
        dyn_forces(&d, speed, &f0, &b0);
        rk4(&d, speed, position, hh, &speed, &position);
        dyn_forces(&d, speed, &f1, &b1);
        ti += 0.5 * (f0 + f1) * hh;
        bi += 0.5 * (b0 + b1) * hh;
        time = t_next;
        if (fabs(t_next - t_grid) <= eps) {
            grid_index += 1;
            time = (double)grid_index * h;
            if (speed > 0.0 && noise_std > 0.0) {
                double z;
                if (next_normal(normal, &z)) goto fail;
                speed = py_max(0.0, speed + noise_std * z);
            }
        }
        if (speed <= 0.0) still_time = was_still ? still_time + hh : 0.0;
        else still_time = 0.0;
    }
    /* _update_outputs */
    double f, b;
    dyn_forces(&d, speed, &f, &b);
    double a = dyn_accel(&d, speed, position);
    double grade = grade_average(&d.grade, position, d.length);
    long mode = (speed <= 0.0 && a <= 0.0) ? 0 : (b > 0.0 ? 3 : (f > 0.0 ? 1 : 2));
    if (setd(s, A_speed, speed) || setd(s, A_position, position) || setd(s, A_still_time, still_time)
        || setl(s, A_stops, stops) || setd(s, A_acceleration, a) || setd(s, A_traction_force, f)
        || setd(s, A_brake_force, b) || setd(s, A_grade, grade) || setl(s, A_mode, mode)
        || setd(plant, A_time, time) || setl(plant, A_grid_index, grid_index)
        || setd(plant, A_traction_impulse, ti) || setd(plant, A_brake_impulse, bi))
        goto fail;
    grade_release(&d.grade);
    Py_DECREF(p); Py_DECREF(s); Py_DECREF(normal); Py_DECREF(profile);
    return 0;
fail:
    grade_release(&d.grade);
    Py_XDECREF(p); Py_XDECREF(s); Py_XDECREF(normal); Py_XDECREF(profile);
    return -1;
}

/* plant_advance(plant, t_end, traction_demand, brake_demand, wind) -> bool: False, with nothing
 * changed, when a method was replaced (the Python loop then runs) */
static PyObject *plant_advance_body(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 5) { PyErr_SetString(PyExc_TypeError, "plant_advance takes 5 arguments"); return NULL; }
    double t_end = PyFloat_AsDouble(args[1]), td = PyFloat_AsDouble(args[2]);
    double bd = PyFloat_AsDouble(args[3]), wind = PyFloat_AsDouble(args[4]);
    if (PyErr_Occurred()) return NULL;
    PyObject *plant = args[0], *p = ga(plant, A_p), *gp = p ? ga(plant, A_grade_profile) : NULL;
    if (!gp) { Py_XDECREF(p); return NULL; }
    PyObject *const objs[3] = {plant, p, gp};
    int ok = guard_ok(plant, objs, 3);
    Py_DECREF(p); Py_DECREF(gp);
    if (!ok) Py_RETURN_FALSE;                /* a replaced method: the Python loop runs */
    if (advance_impl(plant, t_end, td, bd, wind)) return NULL;
    Py_RETURN_TRUE;
}

/* ------------------------------------------------------------------ identification */

static inline void add_outer(double *M, const double *u)
{
    for (int i = 0; i < 4; i++) {
        double ui = u[i];
        int r = 4 * i;
        M[r] += ui * u[0];
        M[r + 1] += ui * u[1];
        M[r + 2] += ui * u[2];
        M[r + 3] += ui * u[3];
    }
}

/* _sandwich4: Ji M Ji for symmetric flat 4x4 (same expressions as the Python). */
static void sandwich4(const double *J, const double *M, double *c)
{
    double j00 = J[0], j01 = J[1], j02 = J[2], j03 = J[3], j11 = J[5], j12 = J[6], j13 = J[7];
    double j22 = J[10], j23 = J[11], j33 = J[15];
    double m00 = M[0], m01 = M[1], m02 = M[2], m03 = M[3], m11 = M[5], m12 = M[6], m13 = M[7];
    double m22 = M[10], m23 = M[11], m33 = M[15];
    double t00 = m00 * j00 + m01 * j01 + m02 * j02 + m03 * j03;
    double t01 = m00 * j01 + m01 * j11 + m02 * j12 + m03 * j13;
    double t02 = m00 * j02 + m01 * j12 + m02 * j22 + m03 * j23;
    double t03 = m00 * j03 + m01 * j13 + m02 * j23 + m03 * j33;
    double t10 = m01 * j00 + m11 * j01 + m12 * j02 + m13 * j03;
    double t11 = m01 * j01 + m11 * j11 + m12 * j12 + m13 * j13;
    double t12 = m01 * j02 + m11 * j12 + m12 * j22 + m13 * j23;
    double t13 = m01 * j03 + m11 * j13 + m12 * j23 + m13 * j33;
    double t20 = m02 * j00 + m12 * j01 + m22 * j02 + m23 * j03;
    double t21 = m02 * j01 + m12 * j11 + m22 * j12 + m23 * j13;
    double t22 = m02 * j02 + m12 * j12 + m22 * j22 + m23 * j23;
    double t23 = m02 * j03 + m12 * j13 + m22 * j23 + m23 * j33;
    double t30 = m03 * j00 + m13 * j01 + m23 * j02 + m33 * j03;
    double t31 = m03 * j01 + m13 * j11 + m23 * j12 + m33 * j13;
    double t32 = m03 * j02 + m13 * j12 + m23 * j22 + m33 * j23;
    double t33 = m03 * j03 + m13 * j13 + m23 * j23 + m33 * j33;
    double c00 = j00 * t00 + j01 * t10 + j02 * t20 + j03 * t30;
    double c01 = j00 * t01 + j01 * t11 + j02 * t21 + j03 * t31;
    double c02 = j00 * t02 + j01 * t12 + j02 * t22 + j03 * t32;
    double c03 = j00 * t03 + j01 * t13 + j02 * t23 + j03 * t33;
    double c11 = j01 * t01 + j11 * t11 + j12 * t21 + j13 * t31;
    double c12 = j01 * t02 + j11 * t12 + j12 * t22 + j13 * t32;
    double c13 = j01 * t03 + j11 * t13 + j12 * t23 + j13 * t33;
    double c22 = j02 * t02 + j12 * t12 + j22 * t22 + j23 * t32;
    double c23 = j02 * t03 + j12 * t13 + j22 * t23 + j23 * t33;
    double c33 = j03 * t03 + j13 * t13 + j23 * t23 + j33 * t33;
    double out[16] = {c00, c01, c02, c03, c01, c11, c12, c13, c02, c12, c22, c23, c03, c13, c23, c33};
    memcpy(c, out, sizeof out);
}

/* Read a flat list of 16 floats into buf and write buf back into the same list. */
static int list16_read(PyObject *list, double *buf)
{
    if (!PyList_CheckExact(list) || PyList_GET_SIZE(list) != 16) {
        PyErr_SetString(PyExc_TypeError, "expected a flat list of 16 floats");
        return -1;
    }
    for (int i = 0; i < 16; i++) {
        buf[i] = PyFloat_AsDouble(PyList_GET_ITEM(list, i));
        if (buf[i] == -1.0 && PyErr_Occurred()) return -1;
    }
    return 0;
}

/* No allocation per sample where nobody can tell: a float referenced by its list alone is
 * overwritten in place (no one else holds it, so no one sees it change), any other item is
 * replaced by a new float. Boxing ~65 floats per sample into the identifier's lists was a tenth
 * of the compiled step. */
static int list_store(PyObject *list, Py_ssize_t i, double v)
{
    PyObject *old = PyList_GET_ITEM(list, i);
    if (old && PyFloat_CheckExact(old) && Py_REFCNT(old) == 1) {
        ((PyFloatObject *)old)->ob_fval = v;
        return 0;
    }
    PyObject *f = PyFloat_FromDouble(v);
    if (!f) return -1;
    return PyList_SetItem(list, i, f);               /* steals f */
}

static int list16_write(PyObject *list, const double *buf)
{
    for (int i = 0; i < 16; i++)
        if (list_store(list, i, buf[i])) return -1;
    return 0;
}

/* Set attribute a of o to a list of the n doubles: the list already there, written in place,
 * when o's __dict__ and our `held` references are its only holders (the Python code would have
 * bound a new list; with no other holder nobody can tell), else a new list. */
static int set_list_attr(PyObject *o, int a, PyObject *current, Py_ssize_t held, const double *buf,
                         Py_ssize_t n)
{
    if (current && PyList_CheckExact(current) && PyList_GET_SIZE(current) == n
        && Py_REFCNT(current) == 1 + held) {
        for (Py_ssize_t i = 0; i < n; i++)
            if (list_store(current, i, buf[i])) return -1;
        return 0;
    }
    PyObject *fresh = doubles_to_list(buf, n);
    if (!fresh) return -1;
    int r = sa(o, a, fresh);
    Py_DECREF(fresh);
    return r;
}

/* ident_update(ident, traction, brake, speed, speed_next, grade, dt, contiguous) -> bool
 * The recursive step of ParameterIdentifier.update for mu = 1/n (no forgetting), after the
 * batch. Returns False without touching anything when that is not the case (the caller then
 * runs the Python code). */
/* The residual statistics the covariance and sigma2 are computed from. */
typedef struct { double c0, c1, cL; int have_cL; long n_cL, lag, n; } Resid;

/* ParameterIdentifier._covariance_flat for mu = 1/n after the batch (J = n R), from the state;
 * lp = the open run's last regressor or NULL. -1 with an exception where Python would raise. */
static int cov_compute(const double *S, const double *W, const double *D, const double *lp,
                       const Resid *r, const double *j0, const double *s2p, double *cov)
{
    double a = py_max(-r->c1, 0.0);                      /* noise_split */
    double b = py_max(r->c0 - 2.0 * a, 1e-12 * r->c0);
    if (r->have_cL && r->n_cL >= r->lag) {                /* _process_share */
        if (r->lag == 0) return zero_division();
        b = py_max((r->cL - 2.0 * a) / (double)r->lag, 1e-3 * r->c0 / (double)r->lag);
    }
    double k = 1.0 / (double)(r->n > 1 ? r->n : 1);      /* 1 / _n_info() */
    double Ji[16], M[16];
    for (int i = 0; i < 16; i++) Ji[i] = S[i] * k;
    for (int i = 0; i < 16; i++) M[i] = a * D[i] + b * W[i];
    if (lp) {
        if (a < 0.0) { PyErr_SetString(PyExc_ValueError, "math domain error"); return -1; }
        double sq = sqrt(a);
        double u[4] = {sq * lp[0], sq * lp[1], sq * lp[2], sq * lp[3]};
        add_outer(M, u);
    }
    M[0] += s2p[0] * j0[0];
    M[5] += s2p[1] * j0[1];
    M[10] += s2p[2] * j0[2];
    M[15] += s2p[3] * j0[3];
    sandwich4(Ji, M, cov);
    return 0;
}

/* ParameterIdentifier.sigma2 for mu = 1/n after the batch, eq. (12) on the process share;
 * b_configured = _configured_noise()[1], used until the LAG sums are ready */
static int sigma2_compute(const Resid *r, double dt, double gamma, double b_configured, double *out)
{
    double a = py_max(-r->c1, 0.0);                      /* noise_split */
    double b;
    if (!(r->have_cL && r->n_cL >= r->lag))
        b = b_configured;
    else {                                                /* _process_share */
        if (r->lag == 0) return zero_division();
        b = py_max((r->cL - 2.0 * a) / (double)r->lag, 1e-3 * r->c0 / (double)r->lag);
    }
    double den = py_square(1.0 + gamma);
    if (den == 0.0) return zero_division();
    *out = G_ACC * G_ACC * dt * dt / 1e6 * b / den;
    return 0;
}

/* ParameterIdentifier._configured_noise()[1]: _scale ** 2 * max(cfg.sigma2_initial, 1e-12) */
static int configured_b(PyObject *id, PyObject *cfg, double *out)
{
    double scale, s2i;
    if (getd(id, A_scale, &scale) || getd(cfg, A_sigma2_initial, &s2i)) return -1;
    *out = py_square(scale) * py_max(s2i, 1e-12);
    return 0;
}

/* What the identifier's covariance is computed from (ParameterIdentifier._covariance_flat), read
 * once: S, W, D (the lists kept for writing back), the open run's last regressor, the residual
 * statistics and the prior. */
typedef struct {
    PyObject *Wl, *Dl, *last, *cLo;              /* new references */
    double S[16], W[16], D[16], lp[4], j0[4], s2p[4];
    Resid r;
} Sandwich;

static void sandwich_release(Sandwich *st)
{
    Py_XDECREF(st->Wl); Py_XDECREF(st->Dl); Py_XDECREF(st->last); Py_XDECREF(st->cLo);
}

/* Sl: the identifier's _S (a list, borrowed). -1 with an exception (st released) */
static int sandwich_load(PyObject *id, PyObject *Sl, Sandwich *st)
{
    st->Wl = ga(id, A_W);
    st->Dl = st->Wl ? ga(id, A_D) : NULL;
    st->last = st->Dl ? ga(id, A_last_phi) : NULL;
    st->cLo = st->last ? ga(id, A_cL) : NULL;
    PyObject *j0l = st->cLo ? ga(id, A_j0) : NULL;
    PyObject *s2l = j0l ? ga(id, A_s2_prior) : NULL;
    int bad = !s2l || list16_read(Sl, st->S) || list16_read(st->Wl, st->W) || list16_read(st->Dl, st->D)
              || (st->last != Py_None && seq_to_doubles(st->last, st->lp, 4, "_last_phi"))
              || seq_to_doubles(j0l, st->j0, 4, "_j0") || seq_to_doubles(s2l, st->s2p, 4, "s2_prior")
              || getd(id, A_c0, &st->r.c0) || getd(id, A_c1, &st->r.c1) || getl(id, A_LAG, &st->r.lag)
              || getl(id, A_n_cL, &st->r.n_cL) || getl(id, A_n, &st->r.n);
    Py_XDECREF(j0l); Py_XDECREF(s2l);
    if (!bad) {
        st->r.have_cL = st->cLo != Py_None;
        st->r.cL = st->r.have_cL ? PyFloat_AsDouble(st->cLo) : 0.0;
        bad = st->r.cL == -1.0 && PyErr_Occurred();
    }
    if (bad) { sandwich_release(st); memset(st, 0, sizeof *st); return -1; }
    return 0;
}

/* 1 done, 0 not this case (nothing touched), -1 error; dt 0 means cfg.dt */
static int ident_update_impl(PyObject *id, double traction, double brake, double speed,
                             double speed_next, double grade, double dt, int contiguous)
{
    PyObject *cfg = NULL, *Sl = NULL, *thl = NULL, *win = NULL, *lasterr = NULL, *frozen = NULL;
    Sandwich st = {0};
    int result = -1;
    double forgetting, gamma, cfg_dt;
    cfg = ga(id, A_cfg);
    if (!cfg) return -1;
    frozen = ga(cfg, A_frozen);
    if (!frozen || getd(cfg, A_forgetting, &forgetting)) goto done;
    Sl = ga(id, A_S);
    if (!Sl) goto done;
    int is_frozen = PyObject_IsTrue(frozen);
    if (is_frozen < 0) goto done;
    if (is_frozen || Sl == Py_None || forgetting > 0.0) {
        result = 0;
        goto done;
    }
    if (getd(cfg, A_gamma, &gamma) || getd(cfg, A_dt, &cfg_dt) || sandwich_load(id, Sl, &st)) goto done;
    double *S = st.S, *W = st.W, *D = st.D, *lp = st.lp, th[4];
    int has_last = st.last != Py_None;
    long n_c1;
    double window_sum, q_e, s2_ref, last_err = 0.0;
    thl = ga(id, A_theta);
    win = thl ? ga(id, A_window) : NULL;
    lasterr = win ? ga(id, A_last_err) : NULL;
    if (!lasterr) goto done;
    if (!PyList_CheckExact(win)) { PyErr_SetString(PyExc_TypeError, "_window must be a list"); goto done; }
    if (seq_to_doubles(thl, th, 4, "_theta") || getl(id, A_n_c1, &n_c1)
        || getd(id, A_window_sum, &window_sum) || getd(id, A_q_e, &q_e) || getd(id, A_s2_ref, &s2_ref))
        goto done;
    if (lasterr != Py_None && (last_err = PyFloat_AsDouble(lasterr)) == -1.0 && PyErr_Occurred()) goto done;
    long lag = st.r.lag, n_cL = st.r.n_cL;
    double c0 = st.r.c0, c1 = st.r.c1, cL = st.r.cL;

    int bad;
    double phi[4] = {traction - brake, -1.0, -speed, -speed * speed};          /* (4) */
    double dtu = dt != 0.0 ? dt : cfg_dt;                                       /* dt or cfg.dt */
    if (G_ACC * dtu == 0.0) { zero_division(); goto done; }
    double y = 1000.0 * (1.0 + gamma) * (speed_next - speed) / (G_ACC * dtu) + grade;
    long n = st.r.n + 1;
    double mu = 1.0 / (double)n;
    double p0 = phi[0], p1 = phi[1], p2 = phi[2], p3 = phi[3];
    double Sp[4] = {S[0] * p0 + S[1] * p1 + S[2] * p2 + S[3] * p3,
                    S[4] * p0 + S[5] * p1 + S[6] * p2 + S[7] * p3,
                    S[8] * p0 + S[9] * p1 + S[10] * p2 + S[11] * p3,
                    S[12] * p0 + S[13] * p1 + S[14] * p2 + S[15] * p3};
    double pSp = p0 * Sp[0] + p1 * Sp[1] + p2 * Sp[2] + p3 * Sp[3];
    if (!(pSp > 0.0)) {                      /* S lost positive definiteness: Python repairs it */
        result = 0;
        goto done;
    }
    double pred_err = y - (th[0] * p0 + th[1] * p1 + th[2] * p2 + th[3] * p3);
    double den = 1.0 + mu * (pSp - 1.0);
    if (den == 0.0 || 1.0 - mu == 0.0) { zero_division(); goto done; }
    double g = mu * pred_err / den;                                             /* (8), (9) */
    double th_new[4] = {th[0] + g * Sp[0], th[1] + g * Sp[1], th[2] + g * Sp[2], th[3] + g * Sp[3]};
    double cden = (1.0 - mu) / mu + pSp;
    if (cden == 0.0) { zero_division(); goto done; }
    double c = 1.0 / cden;                                                      /* (11) */
    double inv = 1.0 / (1.0 - mu);
    double S_new[16];
    for (int i = 0; i < 4; i++)
        for (int j = 0; j < 4; j++)
            S_new[4 * i + j] = (S[4 * i + j] - Sp[i] * Sp[j] * c) * inv;
    double gain_den = 1.0 + mu / (1.0 - mu) * pSp;
    /* _accumulate(phi, contiguous, 1.0): lam = 1, no decay */
    if (contiguous && has_last) {
        double dphi[4] = {phi[0] - lp[0], phi[1] - lp[1], phi[2] - lp[2], phi[3] - lp[3]};
        add_outer(D, dphi);
    } else {
        if (has_last) add_outer(D, lp);
        add_outer(D, phi);
    }
    add_outer(W, phi);
    /* _residual_stats(pred_err / sqrt(gain_den), contiguous, mu) */
    if (gain_den < 0.0) { PyErr_SetString(PyExc_ValueError, "math domain error"); goto done; }
    if (gain_den == 0.0) { zero_division(); goto done; }
    double err = pred_err / sqrt(gain_den);
    if (!contiguous) {
        if (PyList_SetSlice(win, 0, PyList_GET_SIZE(win), NULL)) goto done;
        window_sum = 0.0;
    }
    PyObject *ef = PyFloat_FromDouble(err);
    if (!ef) goto done;
    int app = PyList_Append(win, ef);
    Py_DECREF(ef);
    if (app) goto done;
    window_sum += err;
    if (PyList_GET_SIZE(win) > lag) {
        double first = PyFloat_AsDouble(PyList_GET_ITEM(win, 0));
        if (first == -1.0 && PyErr_Occurred()) goto done;
        if (PyList_SetSlice(win, 0, 1, NULL)) goto done;
        window_sum -= first;
    }
    int have_cL = st.r.have_cL;
    if (PyList_GET_SIZE(win) == lag) {
        n_cL += 1;
        double sq = window_sum * window_sum;
        cL = have_cL ? cL + (sq - cL) / (double)n_cL : sq;
        have_cL = 1;
    }
    c0 += mu * (err * err - c0);
    if (contiguous && lasterr != Py_None) {
        n_c1 += 1;
        double w = 1.0 / (double)n_c1;                 /* mu = 1/n: no forgetting */
        c1 += w * (err * last_err - c1);
    }
    q_e += py_square(pred_err) / gain_den;
    double s2 = n > 4 ? q_e / (double)(n - 4) : s2_ref;

    /* _covariance_flat() and sigma2() of the new state, which the next propagate asks for:
     * the same functions of the same state, computed now from values already at hand */
    double cov[16], sigma2;
    Resid rs = {c0, c1, cL, have_cL, n_cL, lag, n};
    double b_conf;
    if (configured_b(id, cfg, &b_conf) || cov_compute(S_new, W, D, phi, &rs, st.j0, st.s2p, cov)
        || sigma2_compute(&rs, cfg_dt, gamma, b_conf, &sigma2))
        goto done;
    PyObject *cur_cov = ga(id, A_cov);               /* None here (cleared), or a stale list */
    if (!cur_cov) goto done;
    bad = set_list_attr(id, A_cov, cur_cov, 1, cov, 16);
    Py_DECREF(cur_cov);
    if (bad || setd(id, A_sigma2, sigma2)) goto done;
    PyObject *new_last = doubles_to_tuple(phi, 4);
    if (!new_last) goto done;
    bad = sa(id, A_last_phi, new_last);
    Py_DECREF(new_last);
    if (bad || set_list_attr(id, A_theta, thl, 1, th_new, 4) || set_list_attr(id, A_S, Sl, 1, S_new, 16)
        || list16_write(st.Wl, W) || list16_write(st.Dl, D)
        || setd(id, A_window_sum, window_sum) || setl(id, A_n_cL, n_cL)
        || (have_cL && setd(id, A_cL, cL)) || setd(id, A_c0, c0) || setl(id, A_n_c1, n_c1)
        || setd(id, A_c1, c1) || setd(id, A_last_err, err) || setd(id, A_q_e, q_e)
        || setd(id, A_s2, s2) || setl(id, A_n, n))
        goto done;
    result = 1;
done:
    sandwich_release(&st);
    Py_XDECREF(cfg); Py_XDECREF(frozen); Py_XDECREF(Sl); Py_XDECREF(thl); Py_XDECREF(win);
    Py_XDECREF(lasterr);
    return result;
}

static PyObject *ident_update_body(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 8) { PyErr_SetString(PyExc_TypeError, "ident_update takes 8 arguments"); return NULL; }
    double traction = PyFloat_AsDouble(args[1]), brake = PyFloat_AsDouble(args[2]);
    double speed = PyFloat_AsDouble(args[3]), speed_next = PyFloat_AsDouble(args[4]);
    double grade = PyFloat_AsDouble(args[5]);
    double dt = args[6] == Py_None ? 0.0 : PyFloat_AsDouble(args[6]);
    int contiguous = PyObject_IsTrue(args[7]);
    if (PyErr_Occurred() || contiguous < 0) return NULL;
    if (!guard_ok(args[0], args, 1)) Py_RETURN_FALSE;
    int r = ident_update_impl(args[0], traction, brake, speed, speed_next, grade, dt, contiguous);
    if (r < 0) return NULL;
    return Py_NewRef(r ? Py_True : Py_False);
}

/* ident_covariance(ident) -> list of 16 or None
 * _covariance_flat's sandwich for mu = 1/n after the batch (sets ident._cov); None when that
 * is not the case (frozen, before the batch, forgetting) and the Python code runs instead. */
static PyObject *ident_covariance_body(PyObject *self, PyObject *id)
{
    (void)self;
    if (!guard_ok(id, &id, 1)) Py_RETURN_NONE;
    PyObject *cached = ga(id, A_cov);
    if (!cached) return NULL;
    if (cached != Py_None) return cached;
    Py_DECREF(cached);
    PyObject *cfg = NULL, *frozen = NULL, *Sl = NULL, *Jo = NULL, *result = NULL;
    Sandwich st = {0};
    cfg = ga(id, A_cfg);
    frozen = cfg ? ga(cfg, A_frozen) : NULL;
    Sl = frozen ? ga(id, A_S) : NULL;
    Jo = Sl ? ga(id, A_J) : NULL;
    if (!Jo) goto done;
    int is_frozen = PyObject_IsTrue(frozen);
    if (is_frozen < 0) goto done;
    if (is_frozen || Sl == Py_None || Jo != Py_None) { result = Py_NewRef(Py_None); goto done; }
    double cov[16];
    if (sandwich_load(id, Sl, &st)
        || cov_compute(st.S, st.W, st.D, st.last != Py_None ? st.lp : NULL, &st.r, st.j0, st.s2p, cov))
        goto done;
    result = doubles_to_list(cov, 16);
    if (result && sa(id, A_cov, result)) Py_CLEAR(result);
done:
    sandwich_release(&st);
    Py_XDECREF(cfg); Py_XDECREF(frozen); Py_XDECREF(Sl); Py_XDECREF(Jo);
    return result;
}


/* ------------------------------------------------------------------ chain level (models/chain.py,
 * models/estimator.py, models/filters.py EKF): RailCarChain.do_step and .outputs */

static int getb(PyObject *o, int a, int *out)
{
    PyObject *v = ga(o, a);
    if (!v) return -1;
    *out = PyObject_IsTrue(v);
    Py_DECREF(v);
    return *out < 0 ? -1 : 0;
}

static int setb(PyObject *o, int a, int x)
{
    return sa(o, a, x ? Py_True : Py_False);
}

/* ParameterIdentifier._covariance_flat(): the compiled one, or the Python method's list (new
 * reference, a flat list of 16 floats) */
static PyObject *ident_cov_list(PyObject *id)
{
    PyObject *c = ident_covariance_body(NULL, id);
    if (c == Py_None) {
        Py_DECREF(c);
        c = PyObject_CallMethodNoArgs(id, ATTR[A_m_covariance_flat]);
    }
    if (c && (!PyList_CheckExact(c) || PyList_GET_SIZE(c) != 16)) {
        PyErr_SetString(PyExc_TypeError, "_cov: expected a flat list of 16 floats");
        Py_CLEAR(c);
    }
    return c;
}

/* The whole covariance into out[16] */
static int ident_cov(PyObject *id, double *out)
{
    PyObject *c = ident_cov_list(id);
    if (!c) return -1;
    int r = list16_read(c, out);
    Py_DECREF(c);
    return r;
}

/* Its diagonal into out[4] (the outputs need no more) */
static int ident_cov_diag(PyObject *id, double *out)
{
    PyObject *c = ident_cov_list(id);
    if (!c) return -1;
    int r = 0;
    for (int i = 0; r == 0 && i < 4; i++) {
        out[i] = PyFloat_AsDouble(PyList_GET_ITEM(c, 5 * i));
        if (out[i] == -1.0 && PyErr_Occurred()) r = -1;
    }
    Py_DECREF(c);
    return r;
}

/* ParameterIdentifier.sigma2() for mu = 1/n (else the Python method) */
static int ident_sigma2(PyObject *id, double *out)
{
    PyObject *Sl = ga(id, A_S);
    if (!Sl) return -1;
    int s_none = Sl == Py_None;
    Py_DECREF(Sl);
    PyObject *cfg = ga(id, A_cfg);
    if (!cfg) return -1;
    int r = -1;
    if (s_none) { r = getd(cfg, A_sigma2_initial, out); Py_DECREF(cfg); return r; }
    PyObject *cached = ga(id, A_sigma2), *cLo = NULL;
    if (!cached) goto done;
    if (cached != Py_None) {
        *out = PyFloat_AsDouble(cached);
        r = (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
        goto done;
    }
    double forgetting, dt, gamma, c0, c1, cL = 0.0;
    long lag, n_cL, n;
    if (getd(cfg, A_forgetting, &forgetting)) goto done;
    if (forgetting > 0.0) {                      /* not compiled: the Python method */
        PyObject *v = PyObject_CallMethodNoArgs(id, ATTR[A_m_sigma2]);
        if (!v) goto done;
        *out = PyFloat_AsDouble(v);
        Py_DECREF(v);
        r = (*out == -1.0 && PyErr_Occurred()) ? -1 : 0;
        goto done;
    }
    cLo = ga(id, A_cL);
    if (!cLo || getd(cfg, A_dt, &dt) || getd(cfg, A_gamma, &gamma) || getd(id, A_c0, &c0)
        || getd(id, A_c1, &c1) || getl(id, A_LAG, &lag) || getl(id, A_n_cL, &n_cL) || getl(id, A_n, &n))
        goto done;
    if (cLo != Py_None && (cL = PyFloat_AsDouble(cLo)) == -1.0 && PyErr_Occurred()) goto done;
    Resid rs = {c0, c1, cL, cLo != Py_None, n_cL, lag, n};
    double b_conf;
    if (configured_b(id, cfg, &b_conf) || sigma2_compute(&rs, dt, gamma, b_conf, out)) goto done;
    r = setd(id, A_sigma2, *out);
done:
    Py_XDECREF(cached); Py_XDECREF(cLo); Py_DECREF(cfg);
    return r;
}

/* MotionFilter.speed: the filtered speed, never negative */
static int filter_speed(PyObject *f, double *out)
{
    double xh0, vzad_hat;
    if (getd(f, A_xh0, &xh0) || getd(f, A_vzad_hat, &vzad_hat)) return -1;
    double v = xh0 + vzad_hat;
    *out = v > 0.0 ? v : 0.0;
    return 0;
}

/* MotionFilter.predict for the EKF (kind 2), theta = ident._theta, q [(m/s)^2], dt [s] */
static int filter_predict_ekf(PyObject *f, double traction, double brake, const double *theta,
                              double q, double dt)
{
    PyObject *cfg = ga(f, A_cfg);
    if (!cfg) return -1;
    PyObject *profile = ga(f, A_grade_profile);
    Grade gr = {NULL, NULL, NULL, 0};
    int r = -1;
    double speed_hat, x_pos, xh0, length, gamma, p00, p01, p11;
    if (!profile || grade_load(profile, &gr) || filter_speed(f, &speed_hat) || getd(f, A_xh1, &x_pos)
        || getd(f, A_xh0, &xh0) || getd(cfg, A_length, &length) || getd(cfg, A_gamma, &gamma)
        || getd(f, A_p00, &p00) || getd(f, A_p01, &p01) || getd(f, A_p11, &p11))
        goto done;
    double grade = grade_average(&gr, x_pos, length);
    if (1.0 + gamma == 0.0) { zero_division(); goto done; }
    /* ekf_model */
    double k = G_ACC / 1000.0 / (1.0 + gamma) * dt;
    double snf = theta[0] * (traction - brake) - theta[1] - theta[2] * speed_hat
                 - theta[3] * speed_hat * speed_hat - grade;
    double v_next = py_max(speed_hat + k * snf, 0.0);
    double dv = 1.0 - k * (theta[2] + 2.0 * theta[3] * speed_hat);
    double v_next_minus_dv_v = v_next - dv * speed_hat;
    double v_hat = xh0 + 0.0;                      /* vzad_hat = 0.0 for the EKF */
    double v_pred = py_max(v_next_minus_dv_v + dv * v_hat, 0.0);
    double f10 = 0.5 * dt * (1.0 + dv);
    if (setd(f, A_xb0, v_pred - 0.0) || setd(f, A_xb1, x_pos + 0.5 * dt * (v_hat + v_pred))
        || setd(f, A_m00, dv * dv * p00 + q)
        || setd(f, A_m01, dv * (f10 * p00 + p01) + q * 0.5 * dt)
        || setd(f, A_m11, f10 * f10 * p00 + 2.0 * f10 * p01 + p11 + q * dt * dt / 3.0))
        goto done;
    r = 0;
done:
    grade_release(&gr);
    Py_XDECREF(profile); Py_DECREF(cfg);
    return r;
}

/* The distance measurement's variance at position_meas [m^2]: _r1, or with odometry drift
 * (position_std + rel |X|)^2 computed as Python does (libm pow) */
static int position_variance(PyObject *f, PyObject *cfg, double position_meas, double *r1)
{
    double rel;
    if (getd(cfg, A_position_std_rel, &rel)) return -1;
    if (rel != 0.0) {
        double pstd;
        if (getd(cfg, A_position_std, &pstd)) return -1;
        *r1 = py_square(pstd + rel * fabs(position_meas));
        return 0;
    }
    return getd(f, A_r1, r1);
}

/* The posterior of an EKF update (vzad = 0; a car never moves backwards) */
static int store_posterior(PyObject *f, double xh0, double xh1, double p00, double p01, double p11)
{
    double vzad = 0.0;
    if (xh0 + vzad < 0.0) xh0 = -vzad;
    return (setd(f, A_xh1, xh1) || setd(f, A_xh0, xh0) || setd(f, A_p00, p00) || setd(f, A_p01, p01)
            || setd(f, A_p11, p11) || setd(f, A_vzad_hat, vzad)) ? -1 : 0;
}

/* MotionFilter.update for the EKF (vzad = 0) */
static int filter_update_ekf(PyObject *f, double speed_meas, double position_meas)
{
    PyObject *cfg = ga(f, A_cfg);
    if (!cfg) return -1;
    int r = -1;
    double r0, r1, m00, m01, m11, xb0, xb1;
    if (getd(f, A_r0, &r0) || position_variance(f, cfg, position_meas, &r1) || getd(f, A_m00, &m00)
        || getd(f, A_m01, &m01) || getd(f, A_m11, &m11) || getd(f, A_xb0, &xb0) || getd(f, A_xb1, &xb1))
        goto done;
    double vzad = 0.0;
    double s00 = m00 + r0, s11 = m11 + r1;
    double det = s00 * s11 - m01 * m01;
    if (det == 0.0 || r0 == 0.0 || r1 == 0.0) { zero_division(); goto done; }
    double i00 = s11 / det, i01 = -m01 / det, i11 = s00 / det;
    double a00 = m00 * i00 + m01 * i01;
    double a01 = m00 * i01 + m01 * i11;
    double a10 = m01 * i00 + m11 * i01;
    double a11 = m01 * i01 + m11 * i11;
    double p00 = m00 - (a00 * m00 + a01 * m01);                       /* (18) */
    double p01 = m01 - 0.5 * ((a00 * m01 + a01 * m11) + (a10 * m00 + a11 * m01));
    double p11 = m11 - (a10 * m01 + a11 * m11);
    double e0 = speed_meas - vzad - xb0, e1 = position_meas - xb1;
    double k00 = p00 / r0, k01 = p01 / r1, k10 = p01 / r0, k11 = p11 / r1;   /* (17) */
    double xh0 = xb0 + k00 * e0 + k01 * e1;                            /* (15) */
    double xh1 = xb1 + k10 * e0 + k11 * e1;
    r = store_posterior(f, xh0, xh1, p00, p01, p11);
done:
    Py_DECREF(cfg);
    return r;
}

/* MotionFilter.gate for the EKF (vzad = 0): *use_v, *use_x say which measurements the update
 * takes, *fit whether the speed may be identified, *reacquire that the filter restarts */
static int filter_gate_ekf(PyObject *f, double speed_meas, double position_meas, int *use_v,
                           int *use_x, int *fit, int *reacquire)
{
    PyObject *cfg = ga(f, A_cfg);
    if (!cfg) return -1;
    int r = -1;
    double r0, r1, m00, m11, xb0, xb1, gs, fs;
    long vrun, xrun, limit, rejected;
    if (getd(f, A_r0, &r0) || position_variance(f, cfg, position_meas, &r1) || getd(f, A_m00, &m00)
        || getd(f, A_m11, &m11) || getd(f, A_xb0, &xb0) || getd(f, A_xb1, &xb1)
        || getd(f, A_GATE_SIGMAS, &gs) || getd(f, A_FIT_SIGMAS, &fs) || getl(f, A_speed_run, &vrun)
        || getl(f, A_position_run, &xrun) || getl(f, A_REACQUIRE, &limit))
        goto done;
    double e0 = speed_meas - 0.0 - xb0, e1 = position_meas - xb1;
    double s00 = m00 + r0, s11 = m11 + r1;
    double g2 = gs * gs;
    *use_v = e0 * e0 <= g2 * s00;
    *use_x = e1 * e1 <= g2 * s11;
    *fit = *use_v && e0 * e0 <= fs * fs * s00;
    vrun = *use_v ? 0 : vrun + 1;
    xrun = *use_x ? 0 : xrun + 1;
    *reacquire = 0;
    if (xrun >= limit) {                     /* the distance restarts; the speed too if refused */
        long what = *use_v ? 2 : 1;          /* REACQUIRE_DISTANCE, REACQUIRE_BOTH */
        if (what == 1) {
            *fit = 0;
            vrun = 0;
        }
        *use_v = *use_x = *reacquire = 1;
        r = (setb(f, A_speed_fit, *fit) || setl(f, A_speed_run, vrun) || setl(f, A_position_run, 0)
             || setl(f, A_reacquire, what)) ? -1 : 0;
        goto done;
    }
    if (setb(f, A_speed_fit, *fit) || setl(f, A_speed_run, vrun) || setl(f, A_position_run, xrun)
        || getl(f, A_rejected, &rejected) || setl(f, A_rejected, rejected + !*use_v + !*use_x))
        goto done;
    r = 0;
done:
    Py_DECREF(cfg);
    return r;
}

/* MotionFilter._update_one for the EKF (vzad = 0): the speed alone or the distance alone */
static int filter_update_one_ekf(PyObject *f, double speed_meas, double position_meas, int speed)
{
    PyObject *cfg = ga(f, A_cfg);
    if (!cfg) return -1;
    int r = -1;
    double m00, m01, m11, xb0, xb1, s, e, k0, k1, p00, p01, p11;
    if (getd(f, A_m00, &m00) || getd(f, A_m01, &m01) || getd(f, A_m11, &m11) || getd(f, A_xb0, &xb0)
        || getd(f, A_xb1, &xb1))
        goto done;
    if (speed) {
        double r0;
        if (getd(f, A_r0, &r0)) goto done;
        s = m00 + r0;
        e = speed_meas - 0.0 - xb0;
        k0 = m00 / s; k1 = m01 / s;
        p00 = m00 - k0 * m00; p01 = m01 - k0 * m01; p11 = m11 - k1 * m01;
    } else {
        double r1;
        if (position_variance(f, cfg, position_meas, &r1)) goto done;
        s = m11 + r1;
        e = position_meas - xb1;
        k0 = m01 / s; k1 = m11 / s;
        p00 = m00 - k0 * m01; p01 = m01 - k0 * m11; p11 = m11 - k1 * m11;
    }
    r = store_posterior(f, xb0 + k0 * e, xb1 + k1 * e, p00, p01, p11);
done:
    Py_DECREF(cfg);
    return r;
}

/* MotionFilter.hold for the EKF: the posterior is the prediction */
static int filter_hold_ekf(PyObject *f)
{
    PyObject *vals[5] = {NULL};
    static const int FROM[5] = {A_xb0, A_xb1, A_m00, A_m01, A_m11};
    static const int TO[5] = {A_xh0, A_xh1, A_p00, A_p01, A_p11};
    int r = -1;
    for (int i = 0; i < 5; i++)
        if (!(vals[i] = ga(f, FROM[i]))) goto done;
    for (int i = 0; i < 5; i++)
        if (sa(f, TO[i], vals[i])) goto done;
    r = setd(f, A_vzad_hat, 0.0);
done:
    for (int i = 0; i < 5; i++) Py_XDECREF(vals[i]);
    return r;
}

/* OnlineEstimator._excited(dt): *excited = 0 once a steady state has lasted STEADY_TIME */
static int estimator_excited(PyObject *est, PyObject *filt, PyObject *station, double dt, int *excited)
{
    double forces[2], nf, fs, v, sv, sf, st, ss, band, limit;
    int moving;
    PyObject *ft = ga(est, A_forces);
    if (!ft) return -1;
    int bad = seq_to_doubles(ft, forces, 2, "_forces");
    Py_DECREF(ft);
    if (bad || getd(est, A_net_force, &nf) || getd(est, A_FORCE_SMOOTHING, &fs)
        || filter_speed(filt, &v) || getb(station, A_moving, &moving) || getd(est, A_steady_speed, &sv)
        || getd(est, A_steady_force, &sf) || getd(est, A_STEADY_SPEED, &ss) || getd(est, A_force_band, &band))
        return -1;
    double net = forces[0] - forces[1];
    if (fs + dt == 0.0) return zero_division();
    nf = nf + dt / (fs + dt) * (net - nf);
    if (setd(est, A_net_force, nf)) return -1;
    if (!moving || fabs(v - sv) > ss || fabs(nf - sf) > band) {
        *excited = 1;
        return (setd(est, A_steady_speed, v) || setd(est, A_steady_force, nf)
                || setd(est, A_steady_time, 0.0)) ? -1 : 0;
    }
    if (getd(est, A_steady_time, &st) || getd(est, A_STEADY_TIME, &limit)) return -1;
    st += dt;
    *excited = st <= limit;
    return setd(est, A_steady_time, st);
}

/* StationDetector.observe; *stop = 1 when a station stop is confirmed */
static int station_observe(PyObject *st, double speed_meas, double position_meas, double dt, int *stop)
{
    long fast_run, moving_run;
    double v_thr, still_time;
    *stop = 0;
    if (getl(st, A_fast_run, &fast_run) || getd(st, A_v_thr, &v_thr) || getl(st, A_MOVING_RUN, &moving_run))
        return -1;
    fast_run = speed_meas > v_thr ? fast_run + 1 : 0;
    int moving = fast_run >= moving_run;
    if (setl(st, A_fast_run, fast_run) || setb(st, A_moving, moving)) return -1;
    if (moving) {
        if (setd(st, A_still_time, 0.0) || setb(st, A_restarted, 0)) return -1;
        return 0;
    }
    double dwell, x_thr;
    int restarted;
    if (getd(st, A_still_time, &still_time) || getd(st, A_dwell, &dwell) || getb(st, A_restarted, &restarted)
        || getd(st, A_x_thr, &x_thr))
        return -1;
    still_time += dt;
    if (setd(st, A_still_time, still_time)) return -1;
    if (still_time >= dwell && !restarted && fabs(position_meas) < x_thr) {
        *stop = 1;
        return setb(st, A_restarted, 1);
    }
    return 0;
}

typedef struct {      /* the objects one chain step works on (new references) */
    PyObject *chain, *cfg, *fcfg, *plant, *est, *ident, *filt, *station, *vehicle, *pgrade, *egrade;
} ChainObjs;

static void objs_release(ChainObjs *o)
{
    Py_XDECREF(o->cfg); Py_XDECREF(o->fcfg); Py_XDECREF(o->plant); Py_XDECREF(o->est);
    Py_XDECREF(o->ident); Py_XDECREF(o->filt); Py_XDECREF(o->station); Py_XDECREF(o->vehicle);
    Py_XDECREF(o->pgrade); Py_XDECREF(o->egrade);
}

/* No method of any of them replaced (see guard_ok; the record is the chain's) */
static int objs_pristine(const ChainObjs *o)
{
    PyObject *const all[] = {o->chain, o->cfg, o->fcfg, o->plant, o->est, o->ident, o->filt,
                             o->station, o->vehicle, o->pgrade, o->egrade};
    return guard_ok(o->chain, all, (int)(sizeof all / sizeof all[0]));
}

static int objs_load(PyObject *chain, ChainObjs *o)
{
    memset(o, 0, sizeof *o);
    o->chain = chain;
    if (!(o->cfg = ga(chain, A_cfg)) || !(o->fcfg = ga(o->cfg, A_filter))
        || !(o->plant = ga(chain, A_plant))
        || !(o->est = ga(chain, A_estimator))
        || !(o->ident = ga(o->est, A_ident))
        || !(o->filt = ga(o->est, A_filter))
        || !(o->station = ga(o->est, A_station))
        || !(o->vehicle = ga(o->plant, A_p))
        || !(o->pgrade = ga(o->plant, A_grade_profile))
        || !(o->egrade = ga(o->est, A_grade_profile))) {
        objs_release(o);
        return -1;
    }
    return 0;
}

/* OnlineEstimator.propagate (EKF, no refit); before the identifier's first batch the filter's
 * model is the running estimate (ParameterIdentifier.model_theta): the Python method then */
static int estimator_propagate(ChainObjs *o, double traction, double brake, double dt)
{
    PyObject *Sl = ga(o->ident, A_S);
    if (!Sl) return -1;
    int batch_phase = Sl == Py_None;
    Py_DECREF(Sl);
    if (batch_phase) {
        PyObject *r = PyObject_CallMethod(o->est, "propagate", "ddd", traction, brake, dt);
        if (!r) return -1;
        Py_DECREF(r);
        return 0;
    }
    double theta[4], cov[16], speed, gamma, dt_nominal, sigma2;
    PyObject *thl = ga(o->ident, A_theta);
    if (!thl) return -1;
    int bad = seq_to_doubles(thl, theta, 4, "_theta");
    Py_DECREF(thl);
    if (bad || filter_speed(o->filt, &speed) || getd(o->est, A_gamma, &gamma)
        || getd(o->est, A_dt_nominal, &dt_nominal) || ident_cov(o->ident, cov))
        return -1;
    /* process_noise */
    if (1.0 + gamma == 0.0 || dt_nominal == 0.0) return zero_division();
    double k = G_ACC * dt / 1000.0 / (1.0 + gamma);
    double p0 = traction - brake, p1 = -1.0, p2 = -speed, p3 = -speed * speed;
    double along = p0 * (cov[0] * p0 + cov[1] * p1 + cov[2] * p2 + cov[3] * p3)
                   + p1 * (cov[4] * p0 + cov[5] * p1 + cov[6] * p2 + cov[7] * p3)
                   + p2 * (cov[8] * p0 + cov[9] * p1 + cov[10] * p2 + cov[11] * p3)
                   + p3 * (cov[12] * p0 + cov[13] * p1 + cov[14] * p2 + cov[15] * p3);
    double q_param = k * k * along;
    if (ident_sigma2(o->ident, &sigma2)) return -1;
    double q = sigma2 * dt / dt_nominal + q_param;
    if (filter_predict_ekf(o->filt, traction, brake, theta, q, dt)) return -1;
    double forces[2] = {traction, brake};
    PyObject *ft = doubles_to_tuple(forces, 2);
    if (!ft) return -1;
    bad = sa(o->est, A_forces, ft);
    Py_DECREF(ft);
    return bad ? -1 : setd(o->est, A_dt_private, dt);
}

static int call_method0(PyObject *obj, int name)
{
    PyObject *r = PyObject_CallMethodNoArgs(obj, ATTR[name]);
    if (!r) return -1;
    Py_DECREF(r);
    return 0;
}

/* OnlineEstimator.measure (EKF, no refit) */
static int estimator_measure(ChainObjs *o, double speed_meas, double position_meas)
{
    PyObject *prev = ga(o->est, A_prev);
    if (!prev) return -1;
    if (prev == Py_None) {                   /* the first sample: the Python method */
        Py_DECREF(prev);
        PyObject *r = PyObject_CallMethod(o->est, "measure", "dd", speed_meas, position_meas);
        if (!r) return -1;
        Py_DECREF(r);
        return 0;
    }
    double pv[2], dt;
    int bad = seq_to_doubles(prev, pv, 2, "_prev");
    Py_DECREF(prev);
    int moving_before, moving_after, stop;
    if (bad || getd(o->est, A_dt_private, &dt) || getb(o->station, A_moving, &moving_before)
        || station_observe(o->station, speed_meas, position_meas, dt, &stop)
        || getb(o->station, A_moving, &moving_after))
        return -1;
    int use_v = 1, use_x = 1, fit = 1, reacquire = 0, excited, prev_fit;
    if (!stop && filter_gate_ekf(o->filt, speed_meas, position_meas, &use_v, &use_x, &fit, &reacquire))
        return -1;
    if (estimator_excited(o->est, o->filt, o->station, dt, &excited) || getb(o->est, A_prev_fit, &prev_fit))
        return -1;
    double pstd;
    PyObject *fcfg = ga(o->filt, A_cfg);
    if (!fcfg) return -1;
    bad = getd(fcfg, A_position_std, &pstd);
    Py_DECREF(fcfg);
    if (bad) return -1;
    int used = fit && prev_fit && excited && moving_before && moving_after
               && position_meas >= pv[1] - 10.0 * pstd - 1.0;
    if (used) {
        double forces[2], length;
        int contiguous;
        PyObject *ft = ga(o->est, A_forces);
        if (!ft) return -1;
        bad = seq_to_doubles(ft, forces, 2, "_forces");
        Py_DECREF(ft);
        if (bad || getd(o->est, A_length, &length) || getb(o->est, A_pair_used, &contiguous)) return -1;
        PyObject *profile = ga(o->est, A_grade_profile);
        if (!profile) return -1;
        Grade gr;
        bad = grade_load(profile, &gr);
        Py_DECREF(profile);
        if (bad) return -1;
        double grade = grade_average(&gr, pv[1], length);
        grade_release(&gr);
        int r = ident_update_impl(o->ident, forces[0], forces[1], pv[0], speed_meas, grade, dt, contiguous);
        if (r < 0) return -1;
        if (r == 0) {                        /* the batch phase: the Python method */
            PyObject *args = Py_BuildValue("(dddddd)", forces[0], forces[1], pv[0], speed_meas, grade, dt);
            PyObject *kw = args ? Py_BuildValue("{O:O}", ATTR[A_kw_contiguous], contiguous ? Py_True : Py_False) : NULL;
            PyObject *meth = kw ? ga(o->ident, A_m_update) : NULL;
            PyObject *res = meth ? PyObject_Call(meth, args, kw) : NULL;
            Py_XDECREF(args); Py_XDECREF(kw); Py_XDECREF(meth);
            if (!res) return -1;
            Py_DECREF(res);
        }
    }
    if (setb(o->est, A_pair_used, used)) return -1;
    double nv[2] = {speed_meas, position_meas};
    if (!use_x && getd(o->filt, A_xb1, &nv[1])) return -1;   /* a refused distance: its prediction */
    PyObject *nt = doubles_to_tuple(nv, 2);
    if (!nt) return -1;
    bad = sa(o->est, A_prev, nt);
    Py_DECREF(nt);
    if (bad || setb(o->est, A_prev_fit, fit)) return -1;
    if (stop) {
        long stops;
        if (getl(o->est, A_station_stops, &stops) || setl(o->est, A_station_stops, stops + 1)
            || call_method0(o->ident, A_m_restart_mass))
            return -1;
        PyObject *r = PyObject_CallMethod(o->est, "restart_filter", "dd", speed_meas, position_meas);
        if (!r) return -1;
        Py_DECREF(r);
        return 0;
    }
    if (!use_v && !use_x) return filter_hold_ekf(o->filt);
    if (use_v != use_x) return filter_update_one_ekf(o->filt, speed_meas, position_meas, use_v);
    if (reacquire) {                         /* rare: the Python method restarts the filter */
        PyObject *r = PyObject_CallMethod(o->filt, "update", "dd", speed_meas, position_meas);
        if (!r) return -1;
        Py_DECREF(r);
        return 0;
    }
    return filter_update_ekf(o->filt, speed_meas, position_meas);
}

/* RailCarChain._take_sample (no track sensors) */
static int take_sample(ChainObjs *o)
{
    PyObject *s = ga(o->plant, A_state);
    PyObject *ns = s ? ga(o->chain, A_speed_noise) : NULL;
    PyObject *np_ = ns ? ga(o->chain, A_position_noise) : NULL;
    int r = -1;
    double speed, position, sstd, pstd, rel, z1, z2;
    if (!np_ || getd(s, A_speed, &speed) || getd(s, A_position, &position)
        || getd(o->fcfg, A_speed_std, &sstd) || getd(o->fcfg, A_position_std, &pstd)
        || getd(o->fcfg, A_position_std_rel, &rel) || next_normal(ns, &z1))
        goto done;
    double sensor_speed = speed + sstd * z1;
    if (next_normal(np_, &z2)) goto done;
    double sensor_position = position + (pstd + rel * fabs(position)) * z2;
    if (setd(o->chain, A_sensor_speed, sensor_speed) || setd(o->chain, A_sensor_position, sensor_position)
        || estimator_measure(o, sensor_speed, sensor_position))
        goto done;
    r = 0;
done:
    Py_XDECREF(s); Py_XDECREF(ns); Py_XDECREF(np_);
    return r;
}

/* chain_step(chain, current_time, step_size, traction_demand, brake_demand, wind, payload) -> bool
 * RailCarChain.do_step for its compiled configuration (checked by the caller: EKF, no track
 * sensors, est.method 0, no forgetting). False, with nothing changed, when an input is bad (the
 * Python method then raises StepRejected with its message) or a method it replicates was
 * replaced (guard_ok; the Python method then runs the step). */
static PyObject *chain_step_body(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    (void)self;
    if (nargs != 7) { PyErr_SetString(PyExc_TypeError, "chain_step takes 7 arguments"); return NULL; }
    double ct = PyFloat_AsDouble(args[1]), step = PyFloat_AsDouble(args[2]);
    double td = PyFloat_AsDouble(args[3]), bd = PyFloat_AsDouble(args[4]);
    double wind = PyFloat_AsDouble(args[5]), payload = PyFloat_AsDouble(args[6]);
    if (PyErr_Occurred()) return NULL;
    if (!(isfinite(step) && step > 0.0) || !isfinite(ct) || !isfinite(td) || td < 0.0
        || !isfinite(bd) || bd < 0.0 || !isfinite(wind) || !isfinite(payload)) {
        steps_declined++;
        Py_RETURN_FALSE;
    }
    ChainObjs o;
    if (objs_load(args[0], &o)) return NULL;
    PyObject *p = NULL, *result = NULL;
    if (!objs_pristine(&o)) {
        steps_declined++;
        result = Py_NewRef(Py_False);
        goto done;
    }
    double start, base_mass, plant_time, ts;
    long sample_index;
    if (getd(o.chain, A_start_time, &start) || getd(o.chain, A_base_mass, &base_mass)
        || getd(o.plant, A_time, &plant_time) || getd(o.cfg, A_sample_period, &ts)
        || getl(o.chain, A_sample_index, &sample_index))
        goto done;
    ct -= start;
    double mass = base_mass + payload;
    double t_end = ct + step;
    double eps = 1e-9 * py_max(1.0, fabs(t_end));
    if (mass <= 0.0 || fabs(ct - plant_time) > eps) {
        steps_declined++;
        result = Py_NewRef(Py_False);
        goto done;
    }
    if (!(p = ga(o.plant, A_p)) || setd(p, A_mass, mass)) goto done;
    for (;;) {
        double t_sample = (double)(sample_index + 1) * ts;
        if (t_sample > t_end + eps) {
            if (getd(o.plant, A_time, &plant_time)) goto done;
            if (plant_time < t_end - eps && advance_impl(o.plant, t_end, td, bd, wind)) goto done;
            break;
        }
        double ti, bi;
        if (advance_impl(o.plant, t_sample, td, bd, wind) || getd(o.plant, A_traction_impulse, &ti)
            || getd(o.plant, A_brake_impulse, &bi) || estimator_propagate(&o, ti / ts, bi / ts, ts)
            || setd(o.plant, A_traction_impulse, 0.0) || setd(o.plant, A_brake_impulse, 0.0))
            goto done;
        sample_index += 1;
        if (setl(o.chain, A_sample_index, sample_index) || take_sample(&o)) goto done;
    }
    steps_compiled++;
    result = Py_NewRef(Py_True);
done:
    Py_XDECREF(p);
    objs_release(&o);
    return result;
}

static const char *OUTPUT_KEYS[] = {
    "car.speed", "car.position", "car.acceleration", "car.traction_force", "car.brake_force",
    "car.grade", "car.mode", "car.total_mass", "sensor.speed", "sensor.position",
    "sensor.track_speed", "sensor.track_time", "est.mass", "est.mass_std", "est.A0", "est.A1",
    "est.A2", "est.A0_std", "est.A1_std", "est.A2_std", "est.sigma2", "est.samples",
    "est.station_stops", "filter.speed", "filter.position", "filter.speed_std",
    "filter.position_std",
};
#define N_OUT ((int)(sizeof OUTPUT_KEYS / sizeof OUTPUT_KEYS[0]))
static PyObject *OUT_KEY[N_OUT];

/* chain_outputs(chain) -> dict: RailCarChain.outputs() (the caller checks: no refit); None
 * when a method it replicates was replaced (guard_ok) */
static PyObject *chain_outputs_body(PyObject *self, PyObject *chain)
{
    (void)self;
    ChainObjs o;
    if (objs_load(chain, &o)) return NULL;
    if (!objs_pristine(&o)) {
        objs_release(&o);
        Py_RETURN_NONE;                      /* the Python method computes the outputs */
    }
    PyObject *vals[N_OUT] = {NULL};
    PyObject *s = NULL, *p = NULL, *thl = NULL, *Sl = NULL, *d = NULL;
    double th[4], cov[4], sigma2, p00, p11, fspeed;      /* cov: the diagonal */
    s = ga(o.plant, A_state);
    p = s ? ga(o.plant, A_p) : NULL;
    thl = p ? ga(o.ident, A_theta) : NULL;
    Sl = thl ? ga(o.ident, A_S) : NULL;
    if (!Sl || seq_to_doubles(thl, th, 4, "_theta") || ident_cov_diag(o.ident, cov)
        || ident_sigma2(o.ident, &sigma2) || filter_speed(o.filt, &fspeed)
        || getd(o.filt, A_p00, &p00) || getd(o.filt, A_p11, &p11))
        goto done;
    static const int STATE_ATTRS[7] = {A_speed, A_position, A_acceleration, A_traction_force,
                                       A_brake_force, A_grade, A_mode};
    for (int i = 0; i < 7; i++)
        if (!(vals[i] = ga(s, STATE_ATTRS[i]))) goto done;
    if (!(vals[7] = ga(p, A_mass))
        || !(vals[8] = ga(o.chain, A_sensor_speed))
        || !(vals[9] = ga(o.chain, A_sensor_position))
        || !(vals[10] = ga(o.chain, A_track_speed))
        || !(vals[11] = ga(o.chain, A_track_time)))
        goto done;
    double mass = th[0] > 0.0 ? 1.0 / (G_ACC * th[0]) : INFINITY;
    double den = G_ACC * py_square(th[0]);
    if (den == 0.0) { zero_division(); goto done; }
    double mass_std = sqrt(py_max(cov[0], 0.0)) / den;
    double sd[4];
    for (int i = 0; i < 4; i++) sd[i] = cov[i] > 0.0 ? sqrt(cov[i]) : 0.0;
    double est[9] = {mass, mass_std, th[1], th[2], th[3], sd[1], sd[2], sd[3], sigma2};
    for (int i = 0; i < 9; i++)
        if (!(vals[12 + i] = PyFloat_FromDouble(est[i]))) goto done;
    if (Sl != Py_None) vals[21] = ga(o.ident, A_n);
    else {
        PyObject *by = ga(o.ident, A_batch_y);
        if (by) { Py_ssize_t n = PyObject_Length(by); Py_DECREF(by); vals[21] = n < 0 ? NULL : PyLong_FromSsize_t(n); }
    }
    if (!vals[21] || !(vals[22] = ga(o.est, A_station_stops))
        || !(vals[23] = PyFloat_FromDouble(fspeed)) || !(vals[24] = ga(o.filt, A_xh1))
        || !(vals[25] = PyFloat_FromDouble(p00 > 0.0 ? sqrt(p00) : 0.0))
        || !(vals[26] = PyFloat_FromDouble(p11 > 0.0 ? sqrt(p11) : 0.0)))
        goto done;
    d = _PyDict_NewPresized(N_OUT);
    if (!d) goto done;
    for (int i = 0; i < N_OUT; i++)
        if (PyDict_SetItem(d, OUT_KEY[i], vals[i])) { Py_CLEAR(d); goto done; }
done:
    for (int i = 0; i < N_OUT; i++) Py_XDECREF(vals[i]);
    Py_XDECREF(s); Py_XDECREF(p); Py_XDECREF(thl); Py_XDECREF(Sl);
    objs_release(&o);
    return d;
}


/* The exported functions: each body runs between call_enter and call_leave (the dict cache). */
#define EXPORT_FASTCALL(name)                                                              \
    static PyObject *name(PyObject *self, PyObject *const *args, Py_ssize_t nargs)         \
    {                                                                                      \
        call_enter();                                                                      \
        PyObject *r = name##_body(self, args, nargs);                                      \
        call_leave();                                                                      \
        return r;                                                                          \
    }
#define EXPORT_O(name)                                                                     \
    static PyObject *name(PyObject *self, PyObject *arg)                                   \
    {                                                                                      \
        call_enter();                                                                      \
        PyObject *r = name##_body(self, arg);                                              \
        call_leave();                                                                      \
        return r;                                                                          \
    }
EXPORT_FASTCALL(plant_advance)
EXPORT_FASTCALL(ident_update)
EXPORT_FASTCALL(chain_step)
EXPORT_O(chain_outputs)
EXPORT_O(ident_covariance)

/* ------------------------------------------------------------------ module */

static PyObject *set_constants(PyObject *self, PyObject *g)
{
    (void)self;
    double v = PyFloat_AsDouble(g);
    if (v == -1.0 && PyErr_Occurred()) return NULL;
    G_ACC = v;
    Py_RETURN_NONE;
}

static PyObject *step_counts(PyObject *self, PyObject *unused)
{
    (void)self; (void)unused;
    return Py_BuildValue("(KK)", steps_compiled, steps_declined);
}

static PyObject *guard_walks(PyObject *self, PyObject *unused)
{
    (void)self; (void)unused;
    return PyLong_FromUnsignedLongLong(full_checks);
}

static PyMethodDef METHODS[] = {
    {"guard_walks", (PyCFunction)guard_walks, METH_NOARGS,
     "guard_walks() -> int: instance dicts walked looking for replaced methods, since import"},
    {"step_counts", (PyCFunction)step_counts, METH_NOARGS,
     "step_counts() -> (compiled, declined): chain_step calls since import"},
    {"set_constants", (PyCFunction)set_constants, METH_O, "set_constants(G): gravity [m/s^2]"},
    {"plant_advance", (PyCFunction)(void (*)(void))plant_advance, METH_FASTCALL,
     "plant_advance(plant, t_end, traction_demand, brake_demand, wind) -> bool: CarPlant.advance"},
    {"ident_update", (PyCFunction)(void (*)(void))ident_update, METH_FASTCALL,
     "ident_update(ident, F, B, V, V_next, grade, dt, contiguous) -> bool: recursive LS step"},
    {"ident_covariance", (PyCFunction)ident_covariance, METH_O,
     "ident_covariance(ident) -> list | None: the sandwich covariance (mu = 1/n)"},
    {"chain_step", (PyCFunction)(void (*)(void))chain_step, METH_FASTCALL,
     "chain_step(chain, t, h, F, B, wind, payload) -> bool: RailCarChain.do_step (EKF path)"},
    {"chain_outputs", (PyCFunction)chain_outputs, METH_O, "chain_outputs(chain) -> dict: RailCarChain.outputs()"},
    {"remember_classes", remember_classes, METH_VARARGS,
     "remember_classes(*classes): their state (first call wins); a later change of one sends its objects to Python"},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef MODULE = {PyModuleDef_HEAD_INIT, "_fastcore",
    "Compiled bodies of the chain's per-step hot paths (bit-identical to the Python code).", -1, METHODS,
    NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__fastcore(void)
{
    for (int i = 0; i < A_count; i++) {
        ATTR[i] = PyUnicode_InternFromString(ATTR_NAMES[i]);
        if (!ATTR[i]) return NULL;
    }
    for (int i = 0; i < N_OUT; i++) {
        OUT_KEY[i] = PyUnicode_InternFromString(OUTPUT_KEYS[i]);
        if (!OUT_KEY[i]) return NULL;
    }
    return PyModule_Create(&MODULE);
}
