/* A plain C host for tests/fmu_tests/test_native3_sanitized.py: one native backend (RailCar, or
 * RailCarEstimator with -DNATIVE_ESTIMATOR) behind the FMI 3.0 glue (fmu_src/c/fmi3_glue.c) and
 * the C core, linked in (no dlopen, no Python), built with -fsanitize=address,undefined
 * -fno-sanitize-recover=all.
 *
 *   native3_cycles MODE RESOURCES TOKEN BAD_PROFILE BARE_RESOURCES
 *
 * RESOURCES: absolute path (trailing '/') of a folder holding profiles/steep_grades.csv, beside a
 * modelDescription.xml whose instantiationToken is TOKEN (the glue checks it at every
 * instantiation); BAD_PROFILE: absolute path of a grade profile whose line 3 is not a number;
 * BARE_RESOURCES: a folder with profiles/steep_grades.csv and no modelDescription.xml beside it.
 *
 * MODE "main" runs, in order:
 *   1. the bad-input catalogue: NaN, +inf, -inf, negative forces, step 0, a negative step, a time
 *      that does not continue -> fmi3Discard with "step discarded: " naming the variable (the
 *      step size, the time), terminateSimulation false, lastSuccessfulTime = the current point,
 *      the outputs and "time" unchanged; after every good step the outputs are bit-identical to
 *      a run that never saw a bad input;
 *   2. fmi3Reset after a run with another parameter (and a profile, a discard) gives outputs
 *      bit-identical to a fresh instance over 200 steps; one input one ulp off does differ;
 *   3. 100 failed initialisations (bad parameters, a missing and a malformed profile file) ->
 *      fmi3ExitInitializationMode fmi3Error naming the parameter (file and line); in the error
 *      state getFloat64 works and doStep/set/enterInitializationMode are refused; then
 *      (fmi3Terminate and) fmi3Reset, a good initialisation, a step, free;
 *   4. the glue's refusals on a live instance, state by state (instantiated, initialization
 *      mode, step mode, terminated): wrong state, unknown value references, wrong type accessors
 *      (all FMI 3 types), nValues != nValueReferences, NULL arrays and strings, bad UTF-8, fixed
 *      parameters in step mode, the independent variable, unknown log categories, NULL doStep
 *      out-arguments, every function this FMU does not provide; each -> fmi3Error with a logged
 *      message naming the reason. A twin instance gets the same good calls only: after each
 *      refusal the next good step is fmi3OK and every output bit-identical to the twin's;
 *   5. instantiation refusals (model exchange, scheduled execution, wrong / NULL token, bad
 *      resource paths, NULL / empty name, event mode, intermediate variables) -> NULL with the
 *      reason logged; accepted forms (file: URIs, no trailing '/', no modelDescription.xml
 *      beside: token not checked); a NULL logger; loggingOn; fmi3FreeInstance(NULL), a double
 *      free, calls on a freed instance and on pointers that never were instances -> fmi3Error,
 *      never dereferenced (ASan would report it);
 *   6. 1,000 cycles instantiate / enter + exit initialisation (a grade profile whose path the
 *      host passes in a 4 KB buffer of its own) / 20 steps / a refused call / terminate / free,
 *      plus one refused instantiation (wrong token) per cycle. Prints "live_bytes CYCLE BYTES"
 *      (ASan's count of bytes the program holds, quarantine excluded) and "rss_kb CYCLE KB"
 *      after cycles 100 and 1000.
 * MODE "twin_control": section 4 with the first input one ulp off at every step of one twin:
 *   must fail ("differs from the twin"), proving that comparison can.
 * MODE "null_resources": fmi3InstantiateCoSimulation with resourcePath = NULL, which FMI 3.0
 *   allows (see tests/fmu_tests/test_native3_sanitized.py), then a default run and a relative profile
 *   looked up in the working directory.
 *
 * Leak controls (the test's proof that the memory checks can fail):
 *   -DNATIVE3_LEAK_HOST      the host skips freeing its 4 KB profile-path buffer each cycle;
 *   -DNATIVE3_LEAK_INSTANCE  the host skips fmi3FreeInstance each cycle.
 * Prints "ok" at the end; a failed expectation prints "FAILED line N: ..." and exits 1. */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ASan's allocator statistics (sanitizer/allocator_interface.h, not always installed) */
size_t __sanitizer_get_current_allocated_bytes(void);

#include "fmi3Functions.h"

#ifdef NATIVE_ESTIMATOR
#include "native_estimator_table.h"
#define VARS NES_VARS
#define NVARS NES_NVARS
#define MODEL "RailCarEstimator"
#define TRACTION "traction_force"
#define BRAKE "brake_force"
#define BAD_NAME "est.mass_initial"
#define INT_PARAMETER "est.batch_size"
#define OTHER_VALUE 20
#define FIRST_OUTPUT "est.mass"
#define INT_OUTPUT "est.samples"
#else
#include "native_railcar_table.h"
#define VARS NRC_VARS
#define NVARS NRC_NVARS
#define MODEL "RailCar"
#define TRACTION "traction_force_demand"
#define BRAKE "brake_force_demand"
#define BAD_NAME "car.mass"
#define INT_PARAMETER "seed"
#define OTHER_VALUE 7
#define FIRST_OUTPUT "car.speed"
#define INT_OUTPUT "car.mode"
#endif

#define PROFILE "track.grade_profile"
#define GOOD_PROFILE "profiles/steep_grades.csv"
#define DT 0.1
#define MAX_OUT 64
#define TIME_VR ((fmi3ValueReference)NVARS) /* fmi3_glue.c: "time" follows the backend's table */

/* ------------------------------------------------------------------ host side */

static int env_tag;                         /* &env_tag is every instance's environment */
static char last_message[16384], last_category[128];
static int last_status = -1, n_messages, wrong_env;

static void log_cb(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                   fmi3String message) {
    if (env != (fmi3InstanceEnvironment)&env_tag) wrong_env++;
    snprintf(last_message, sizeof last_message, "%s", message ? message : "(NULL)");
    snprintf(last_category, sizeof last_category, "%s", category ? category : "(NULL)");
    last_status = (int)status;
    n_messages++;
}

static const char *resources, *token, *bad_profile, *bare_resources;
static int n_refused;
static int twin_control;      /* mode "twin_control": one twin's first input one ulp off */

#define FAIL(...)                                                                              \
    do {                                                                                       \
        printf("FAILED line %d: ", __LINE__);                                                  \
        printf(__VA_ARGS__);                                                                   \
        printf(" (last message: %s)\n", last_message);                                         \
        exit(1);                                                                               \
    } while (0)

#define EXPECT(call, want)                                                                     \
    do {                                                                                       \
        fmi3Status s_ = (call);                                                                \
        if (s_ != (want)) FAIL("%s -> %d, not %d", #call, (int)s_, (int)(want));              \
    } while (0)

#define EXPECT_MESSAGE(part)                                                                   \
    do {                                                                                       \
        if (!strstr(last_message, (part))) FAIL("the message does not name '%s'", (part));   \
    } while (0)

/* A refused call: fmi3Error, and an error message containing `part` logged by this call. */
#define REFUSED(call, part)                                                                    \
    do {                                                                                       \
        fmi3Status s_;                                                                         \
        last_message[0] = '\0';                                                                \
        last_status = -1;                                                                      \
        s_ = (call);                                                                           \
        if (s_ != fmi3Error) FAIL("%s -> %d, not fmi3Error", #call, (int)s_);                 \
        if (last_status != (int)fmi3Error || strcmp(last_category, "logStatusError") != 0)     \
            FAIL("%s logged no error (status %d, category %s)", #call, last_status,            \
                 last_category);                                                               \
        if (!strstr(last_message, (part))) FAIL("%s: the message does not name '%s'", #call,   \
                                                (part));                                       \
        n_refused++;                                                                           \
    } while (0)

/* A call on something that is not a live instance: fmi3Error, the host's logger not called
   (the glue cannot know it without touching the pointer). */
#define DEAD(call)                                                                             \
    do {                                                                                       \
        int before_ = n_messages;                                                              \
        fmi3Status s_ = (call);                                                                \
        if (s_ != fmi3Error) FAIL("%s on a dead instance -> %d", #call, (int)s_);             \
        if (n_messages != before_) FAIL("%s on a dead instance called the logger", #call);    \
        n_refused++;                                                                           \
    } while (0)

static fmi3ValueReference vr_of(const char *name) {
    int k;
    for (k = 0; k < NVARS; k++)
        if (VARS[k].name && strcmp(VARS[k].name, name) == 0) return (fmi3ValueReference)k;
    printf("FAILED: no variable %s\n", name);
    exit(1);
}

static void set_real(fmi3Instance c, const char *name, double value) {
    fmi3ValueReference vr = vr_of(name);
    EXPECT(fmi3SetFloat64(c, &vr, 1, &value, 1), fmi3OK);
}

static void set_int(fmi3Instance c, const char *name, int value) {
    fmi3ValueReference vr = vr_of(name);
    fmi3Int32 v = value;
    EXPECT(fmi3SetInt32(c, &vr, 1, &v, 1), fmi3OK);
}

static void set_string(fmi3Instance c, const char *name, const char *value) {
    fmi3ValueReference vr = vr_of(name);
    EXPECT(fmi3SetString(c, &vr, 1, &value, 1), fmi3OK);
}

static double get_time(fmi3Instance c) {
    fmi3ValueReference vr = TIME_VR;
    double t = NAN;
    EXPECT(fmi3GetFloat64(c, &vr, 1, &t, 1), fmi3OK);
    return t;
}

static int same_bits(const double *a, const double *b, size_t n) {
    return memcmp(a, b, n * sizeof *a) == 0;
}

static fmi3Instance instantiate_at(const char *path) {
    fmi3Instance c = fmi3InstantiateCoSimulation("cycles3", token, path, fmi3False, fmi3False,
                                                 fmi3False, fmi3False, NULL, 0,
                                                 (fmi3InstanceEnvironment)&env_tag, log_cb, NULL);
    if (!c) FAIL("fmi3InstantiateCoSimulation(%s) returned NULL", path ? path : "NULL");
    return c;
}

static fmi3Instance instantiate(void) { return instantiate_at(resources); }

static void enter_init(fmi3Instance c) {
    EXPECT(fmi3EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0), fmi3OK);
}

/* A fresh instance with the default parameters, initialised. */
static fmi3Instance fresh(void) {
    fmi3Instance c = instantiate();
    enter_init(c);
    EXPECT(fmi3ExitInitializationMode(c), fmi3OK);
    return c;
}

/* fmi3DoStep, checking its out-arguments against the status (no event mode, no early return;
   terminateSimulation only on an error; lastSuccessfulTime the end of the step, or its start
   when it was discarded). */
static fmi3Status do_step(fmi3Instance c, double t, double h) {
    fmi3Boolean event = fmi3True, terminate = fmi3True, early = fmi3True;
    double last = NAN, want = t + h;
    fmi3Status s = fmi3DoStep(c, t, h, fmi3True, &event, &terminate, &early, &last);
    if (s == fmi3OK || s == fmi3Discard) {
        if (event || early || terminate)
            FAIL("doStep(%g, %g) -> %d with eventHandlingNeeded %d, earlyReturn %d, "
                 "terminateSimulation %d", t, h, (int)s, event, early, terminate);
        if (s == fmi3Discard) want = t;
        if (memcmp(&last, &want, sizeof last) != 0)
            FAIL("doStep(%g, %g) -> %d: lastSuccessfulTime %.17g, not %.17g", t, h, (int)s, last,
                 want);
    }
    return s;
}

/* The inputs of step k (deterministic: accelerating, coasting, braking; the estimator's
   measurements follow a 30 t car under those forces). `perturb`: the first input (RailCar's
   traction demand, the estimator's measured speed) one ulp up. */
static void set_inputs(fmi3Instance c, int k, int perturb) {
    int phase = k % 120;
    double traction = phase < 60 ? 15e3 : 0.0, brake = phase >= 90 ? 15e3 : 0.0;
#ifdef NATIVE_ESTIMATOR
    double v = 0.0, x = 0.0;
    int j;
    for (j = 0; j <= k; j++) {         /* the state at the end of step k */
        int ph = j % 120;
        double a = ph < 60 ? 0.5 : ph < 90 ? -0.02 : -0.5;
        v = v + a * DT > 0.0 ? v + a * DT : 0.0;
        x += v * DT;
    }
    v += 0.02 * sin(0.7 * k);
    set_real(c, TRACTION, traction);
    set_real(c, BRAKE, brake);
    set_real(c, "sensor.speed", perturb ? nextafter(v, 1e300) : v);
    set_real(c, "sensor.position", x + 0.3 * cos(0.3 * k));
    if (k % 40 == 39) {
        set_real(c, "sensor.track_speed", v);
        set_real(c, "sensor.track_time", DT * k);
    }
#else
    set_real(c, TRACTION, perturb ? nextafter(2 * traction, 1e300) : 2 * traction);
    set_real(c, BRAKE, brake);
    set_real(c, "wind_speed", k % 50 < 25 ? 2.0 : -1.0);
#endif
}

/* Every output (Float64, then Int32 as doubles) -> out; their number. */
static int outputs(fmi3Instance c, double *out) {
    int k, n = 0;
    for (k = 0; k < NVARS; k++) {
        fmi3ValueReference vr = (fmi3ValueReference)k;
        if (!VARS[k].name || VARS[k].causality != GLUE_OUTPUT) continue;
        if (n >= MAX_OUT) FAIL("more than %d outputs", MAX_OUT);
        if (VARS[k].type == GLUE_REAL) {
            EXPECT(fmi3GetFloat64(c, &vr, 1, &out[n], 1), fmi3OK);
        } else {
            fmi3Int32 i;
            EXPECT(fmi3GetInt32(c, &vr, 1, &i, 1), fmi3OK);
            out[n] = (double)i;
        }
        n++;
    }
    if (n == 0) FAIL("no outputs");
    return n;
}

/* Steps 0 .. n-1 of the standard run, outputs after each into rows[k * MAX_OUT ...]. */
static int run(fmi3Instance c, int n, double *rows, int perturb_at) {
    int k, nout = 0;
    for (k = 0; k < n; k++) {
        set_inputs(c, k, k == perturb_at);
        EXPECT(do_step(c, DT * k, DT), fmi3OK);
        nout = outputs(c, rows + (size_t)k * MAX_OUT);
    }
    return nout;
}

/* One good step k on both instances; the outputs must agree bit for bit. */
static void twin_step(fmi3Instance a, fmi3Instance b, int k, const char *after) {
    double oa[MAX_OUT], ob[MAX_OUT];
    int n;
    set_inputs(a, k, twin_control);
    set_inputs(b, k, 0);
    EXPECT(do_step(a, DT * k, DT), fmi3OK);
    EXPECT(do_step(b, DT * k, DT), fmi3OK);
    n = outputs(a, oa);
    outputs(b, ob);
    if (!same_bits(oa, ob, (size_t)n)) FAIL("after %s, step %d differs from the twin", after, k);
    if (get_time(a) != DT * k + DT) FAIL("after step %d, time is %.17g", k, get_time(a));
}

/* ------------------------------------------------------------------ 1. bad inputs */

typedef struct {
    const char *what;
    const char *input;       /* the input set to `value` (NULL: none) */
    double value;
    double time_offset, step; /* the doStep's currentCommunicationPoint offset and step size */
    const char *named;       /* the message must contain this */
} bad_case;

static void bad_inputs(void) {
    static const bad_case cases[] = {
        {"NaN traction", TRACTION, NAN, 0.0, DT, TRACTION},
        {"+inf traction", TRACTION, INFINITY, 0.0, DT, TRACTION},
        {"-inf brake", BRAKE, -INFINITY, 0.0, DT, BRAKE},
        {"negative traction", TRACTION, -1.0, 0.0, DT, TRACTION},
        {"negative brake", BRAKE, -5e3, 0.0, DT, BRAKE},
        {"step 0", NULL, 0.0, 0.0, 0.0, "communication step size"},
        {"negative step", NULL, 0.0, 0.0, -DT, "communication step size"},
        {"time jumps ahead", NULL, 0.0, 0.5, DT, "does not continue"},
        {"time goes back", NULL, 0.0, -0.3, DT, "does not continue"},
    };
    enum { N = 60, NCASES = sizeof cases / sizeof cases[0] };
    fmi3Instance a = fresh(), b = fresh();
    int k, discards = 0;
    for (k = 0; k < N; k++) {
        if (k % 5 == 2 && k / 5 < NCASES) {
            const bad_case *bc = &cases[k / 5];
            double before[MAX_OUT], after[MAX_OUT], t0 = get_time(a);
            int n0 = outputs(a, before);
            set_inputs(a, k, 0);
            if (bc->input) set_real(a, bc->input, bc->value);
            last_message[0] = '\0';
            last_status = -1;
            EXPECT(do_step(a, DT * k + bc->time_offset, bc->step), fmi3Discard);
            if (strncmp(last_message, "step discarded: ", 16) != 0 ||
                last_status != (int)fmi3Discard || strcmp(last_category, "logStatusDiscard"))
                FAIL("%s: no 'step discarded: ' message with status and category Discard",
                     bc->what);
            EXPECT_MESSAGE(bc->named);
            outputs(a, after);
            if (!same_bits(before, after, (size_t)n0)) FAIL("%s changed the outputs", bc->what);
            if (get_time(a) != t0) FAIL("%s moved the time", bc->what);
            discards++;
        }
        twin_step(a, b, k, "the discards");   /* the good inputs again, at the right time */
    }
    if (discards != NCASES) FAIL("%d bad inputs tried, not %d", discards, (int)NCASES);
    EXPECT(fmi3Terminate(a), fmi3OK);
    EXPECT(fmi3Terminate(b), fmi3OK);
    fmi3FreeInstance(a);
    fmi3FreeInstance(b);
    printf("bad_inputs %d discarded, each followed by a good step bit-identical to a clean run\n",
           discards);
}

/* ------------------------------------------------------------------ 2. reset */

static void reset_is_fresh(void) {
    enum { N = 200 };
    static double after_reset[N * MAX_OUT], fresh_rows[N * MAX_OUT], perturbed[N * MAX_OUT];
    fmi3Instance a = instantiate(), b, p;
    int k, nout, differ = -1;
    memset(after_reset, 0, sizeof after_reset);
    memset(fresh_rows, 0, sizeof fresh_rows);
    memset(perturbed, 0, sizeof perturbed);
    /* a history to forget: another parameter, a profile, steps, a discarded one */
    enter_init(a);
    set_int(a, INT_PARAMETER, OTHER_VALUE);
    set_string(a, PROFILE, GOOD_PROFILE);
    EXPECT(fmi3ExitInitializationMode(a), fmi3OK);
    for (k = 0; k < 150; k++) {
        set_inputs(a, k + 7, 0);
        EXPECT(do_step(a, DT * k, DT), fmi3OK);
    }
    set_real(a, TRACTION, NAN);
    EXPECT(do_step(a, DT * k, DT), fmi3Discard);
    EXPECT(fmi3Reset(a), fmi3OK);
    enter_init(a);
    EXPECT(fmi3ExitInitializationMode(a), fmi3OK);
    nout = run(a, N, after_reset, -1);

    b = fresh();
    run(b, N, fresh_rows, -1);
    for (k = 0; k < N; k++)
        if (!same_bits(after_reset + (size_t)k * MAX_OUT, fresh_rows + (size_t)k * MAX_OUT,
                       (size_t)nout))
            FAIL("after reset, step %d differs from a fresh instance", k);

    p = fresh();                          /* one input one ulp off at step 20 */
    run(p, N, perturbed, 20);
    for (k = 0; k < N && differ < 0; k++)
        if (!same_bits(perturbed + (size_t)k * MAX_OUT, fresh_rows + (size_t)k * MAX_OUT,
                       (size_t)nout))
            differ = k;
    if (differ < 0) FAIL("one ulp changed nothing: the comparison is vacuous");
    fmi3FreeInstance(a);
    fmi3FreeInstance(b);
    fmi3FreeInstance(p);
    printf("reset %d steps x %d outputs bit-identical to a fresh instance; one ulp off differs "
           "from step %d\n", N, nout, differ);
}

/* ------------------------------------------------------------------ 3. failed initialisations */

static void failed_inits(void) {
    int i;
    for (i = 0; i < 100; i++) {
        fmi3Instance c = instantiate();
        fmi3ValueReference out_vr = vr_of(FIRST_OUTPUT), in_vr = vr_of(TRACTION);
        const char *named;
        double out[MAX_OUT], x = 1.0;
        enter_init(c);
        switch (i % 4) {
        case 0:
            set_real(c, BAD_NAME, -1.0);
            named = BAD_NAME;
            break;
        case 1:
#ifdef NATIVE_ESTIMATOR
            set_int(c, INT_PARAMETER, 0);
            named = INT_PARAMETER;
#else
            set_real(c, "sensor.sample_period", 0.0);
            named = "sensor.sample_period";
#endif
            break;
        case 2:                        /* '%' reaches the host as it is */
            set_string(c, PROFILE, "no/such/file%s%%d.csv");
            named = "no/such/file%s%%d.csv";
            break;
        default:
            set_string(c, PROFILE, bad_profile);
            named = "line 3";
            break;
        }
        last_message[0] = '\0';
        EXPECT(fmi3ExitInitializationMode(c), fmi3Error);
        EXPECT_MESSAGE("initialisation failed: ");
        EXPECT_MESSAGE(named);
        if (i % 4 >= 2) EXPECT_MESSAGE(PROFILE);
        if (i % 4 == 3) EXPECT_MESSAGE(bad_profile);
        if (i % 10 == 0) {             /* the error state: get only, then terminate or reset */
            EXPECT(fmi3GetFloat64(c, &out_vr, 1, out, 1), fmi3OK);
            REFUSED(do_step(c, 0.0, DT), "not allowed in state 'error'");
            REFUSED(fmi3SetFloat64(c, &in_vr, 1, &x, 1), "not allowed in state 'error'");
            REFUSED(fmi3EnterInitializationMode(c, fmi3False, 0.0, 0.0, fmi3False, 0.0),
                    "not allowed in state 'error'");
            REFUSED(fmi3ExitInitializationMode(c), "not allowed in state 'error'");
        }
        if (i % 2) EXPECT(fmi3Terminate(c), fmi3OK);
        EXPECT(fmi3Reset(c), fmi3OK);
        enter_init(c);
        if (i % 8 == 7) set_string(c, PROFILE, GOOD_PROFILE);
        EXPECT(fmi3ExitInitializationMode(c), fmi3OK);
        set_inputs(c, 0, 0);
        EXPECT(do_step(c, 0.0, DT), fmi3OK);
        outputs(c, out);
        fmi3FreeInstance(c);
    }
    printf("failed_inits 100 refused naming the parameter or file and line, each reset and run\n");
}

/* ------------------------------------------------------------------ 4. refusals on a live instance */

/* Every FMI 3 function this FMU does not provide -> fmi3Error "not supported". */
static void unsupported(fmi3Instance c) {
    fmi3ValueReference vr = vr_of(FIRST_OUTPUT);
    fmi3FMUState state = (fmi3FMUState)&env_tag;
    fmi3Byte bytes[8] = {0};
    fmi3Float64 f[2] = {0.0, 0.0};
    fmi3Int32 order = 1;
    fmi3Boolean b1 = fmi3False, b2 = fmi3False, b3 = fmi3False, b4 = fmi3False, b5 = fmi3False;
    fmi3UInt64 u1 = 0, u2 = 0;
    fmi3IntervalQualifier q = fmi3IntervalNotYetKnown;
    size_t n = 7, idx[1] = {0};
    fmi3ValueReference deps[1] = {0};
    fmi3DependencyKind kinds[1] = {fmi3Independent};
    /* FMU states are provided (tests/fmu_tests/test_fmu_state.py); a state pointer that is
       not a live state of this FMU is refused without being read */
    REFUSED(fmi3GetFMUState(c, &state), "is not a live FMU state of this FMU");
    if (state != (fmi3FMUState)&env_tag) FAIL("fmi3GetFMUState wrote a state");
    REFUSED(fmi3SetFMUState(c, state), "is not a live FMU state of this FMU");
    REFUSED(fmi3FreeFMUState(c, &state), "is not a live FMU state of this FMU");
    REFUSED(fmi3SerializedFMUStateSize(c, state, &n), "is not a live FMU state of this FMU");
    if (n != 7) FAIL("fmi3SerializedFMUStateSize wrote a size");
    REFUSED(fmi3SerializeFMUState(c, state, bytes, sizeof bytes),
            "is not a live FMU state of this FMU");
    REFUSED(fmi3DeserializeFMUState(c, bytes, sizeof bytes, &state),
            "is not a live FMU state of this FMU");
    REFUSED(fmi3GetDirectionalDerivative(c, &vr, 1, &vr, 1, f, 1, f + 1, 1),
            "providesDirectionalDerivatives = false");
    REFUSED(fmi3GetAdjointDerivative(c, &vr, 1, &vr, 1, f, 1, f + 1, 1),
            "providesAdjointDerivatives = false");
    REFUSED(fmi3GetNumberOfVariableDependencies(c, vr, &n), "not supported");
    REFUSED(fmi3GetVariableDependencies(c, vr, idx, deps, idx, kinds, 1), "not supported");
    REFUSED(fmi3EnterConfigurationMode(c), "not supported");
    REFUSED(fmi3ExitConfigurationMode(c), "not supported");
    REFUSED(fmi3EnterEventMode(c), "hasEventMode = false");
    REFUSED(fmi3EnterStepMode(c), "not supported");
    REFUSED(fmi3EvaluateDiscreteStates(c), "not supported");
    REFUSED(fmi3UpdateDiscreteStates(c, &b1, &b2, &b3, &b4, &b5, f), "not supported");
    REFUSED(fmi3EnterContinuousTimeMode(c), "no model exchange");
    REFUSED(fmi3CompletedIntegratorStep(c, fmi3True, &b1, &b2), "no model exchange");
    REFUSED(fmi3SetTime(c, 1.0), "no model exchange");
    REFUSED(fmi3SetContinuousStates(c, f, 1), "no model exchange");
    REFUSED(fmi3GetContinuousStateDerivatives(c, f, 1), "no model exchange");
    REFUSED(fmi3GetEventIndicators(c, f, 1), "no model exchange");
    REFUSED(fmi3GetContinuousStates(c, f, 1), "no model exchange");
    REFUSED(fmi3GetNominalsOfContinuousStates(c, f, 1), "no model exchange");
    REFUSED(fmi3GetNumberOfEventIndicators(c, &n), "no model exchange");
    REFUSED(fmi3GetNumberOfContinuousStates(c, &n), "no model exchange");
    REFUSED(fmi3GetOutputDerivatives(c, &vr, 1, &order, f, 1), "maxOutputDerivativeOrder = 0");
    REFUSED(fmi3ActivateModelPartition(c, vr, 0.0), "no scheduled execution");
    REFUSED(fmi3GetIntervalDecimal(c, &vr, 1, f, &q), "no clocks");
    REFUSED(fmi3GetIntervalFraction(c, &vr, 1, &u1, &u2, &q), "no clocks");
    REFUSED(fmi3GetShiftDecimal(c, &vr, 1, f), "no clocks");
    REFUSED(fmi3GetShiftFraction(c, &vr, 1, &u1, &u2), "no clocks");
    REFUSED(fmi3SetIntervalDecimal(c, &vr, 1, f), "no clocks");
    REFUSED(fmi3SetIntervalFraction(c, &vr, 1, &u1, &u2), "no clocks");
    REFUSED(fmi3SetShiftDecimal(c, &vr, 1, f), "no clocks");
    REFUSED(fmi3SetShiftFraction(c, &vr, 1, &u1, &u2), "no clocks");
    if (f[0] != 0.0 || f[1] != 0.0 || n != 7 || b1 || u1 || u2)
        FAIL("a refused call wrote into its out-arguments");
}

/* Get and set of every FMI 3 type none of our variables has, on a real variable -> refused
   naming the type; with no value reference at all -> fmi3OK (nothing to do). */
static void foreign_types(fmi3Instance c, int setting) {
    fmi3ValueReference vr = vr_of(FIRST_OUTPUT);
    fmi3Float32 f32 = 0;
    fmi3Int8 i8 = 0;
    fmi3UInt8 u8 = 0;
    fmi3Int16 i16 = 0;
    fmi3UInt16 u16 = 0;
    fmi3UInt32 u32 = 0;
    fmi3Int64 i64 = 0;
    fmi3UInt64 u64 = 0;
    fmi3Boolean b = fmi3False;
    fmi3Clock clk = fmi3False;
    fmi3Binary bin = NULL;
    size_t size = 0;
    if (!setting) {
        REFUSED(fmi3GetFloat32(c, &vr, 1, &f32, 1), "not a Float32");
        REFUSED(fmi3GetInt8(c, &vr, 1, &i8, 1), "not an Int8");
        REFUSED(fmi3GetUInt8(c, &vr, 1, &u8, 1), "not a UInt8");
        REFUSED(fmi3GetInt16(c, &vr, 1, &i16, 1), "not an Int16");
        REFUSED(fmi3GetUInt16(c, &vr, 1, &u16, 1), "not a UInt16");
        REFUSED(fmi3GetUInt32(c, &vr, 1, &u32, 1), "not a UInt32");
        REFUSED(fmi3GetInt64(c, &vr, 1, &i64, 1), "not an Int64");
        REFUSED(fmi3GetUInt64(c, &vr, 1, &u64, 1), "not a UInt64");
        REFUSED(fmi3GetBoolean(c, &vr, 1, &b, 1), "not a Boolean");
        REFUSED(fmi3GetBinary(c, &vr, 1, &size, &bin, 1), "not a Binary");
        REFUSED(fmi3GetClock(c, &vr, 1, &clk), "not a Clock");
        EXPECT(fmi3GetFloat32(c, NULL, 0, NULL, 0), fmi3OK);
        EXPECT(fmi3GetBoolean(c, NULL, 0, NULL, 0), fmi3OK);
        EXPECT(fmi3GetBinary(c, NULL, 0, NULL, NULL, 0), fmi3OK);
    } else {
        vr = vr_of(TRACTION);         /* an input: only the type is wrong */
        REFUSED(fmi3SetFloat32(c, &vr, 1, &f32, 1), "not a Float32");
        REFUSED(fmi3SetInt8(c, &vr, 1, &i8, 1), "not an Int8");
        REFUSED(fmi3SetUInt8(c, &vr, 1, &u8, 1), "not a UInt8");
        REFUSED(fmi3SetInt16(c, &vr, 1, &i16, 1), "not an Int16");
        REFUSED(fmi3SetUInt16(c, &vr, 1, &u16, 1), "not a UInt16");
        REFUSED(fmi3SetUInt32(c, &vr, 1, &u32, 1), "not a UInt32");
        REFUSED(fmi3SetInt64(c, &vr, 1, &i64, 1), "not an Int64");
        REFUSED(fmi3SetUInt64(c, &vr, 1, &u64, 1), "not a UInt64");
        REFUSED(fmi3SetBoolean(c, &vr, 1, &b, 1), "not a Boolean");
        REFUSED(fmi3SetBinary(c, &vr, 1, &size, &bin, 1), "not a Binary");
        REFUSED(fmi3SetClock(c, &vr, 1, &clk), "not a Clock");
        EXPECT(fmi3SetInt64(c, NULL, 0, NULL, 0), fmi3OK);
        EXPECT(fmi3SetBoolean(c, NULL, 0, NULL, 0), fmi3OK);
    }
    if (f32 != 0 || i8 || u8 || i16 || u16 || u32 || i64 || u64 || b || clk || bin || size)
        FAIL("a refused get wrote a value");
}

/* Value references, types, counts and pointers, in any state where get and set are allowed. */
static void bad_references(fmi3Instance c, int in_step_mode) {
    fmi3ValueReference out = vr_of(FIRST_OUTPUT), in = vr_of(TRACTION), par = vr_of(BAD_NAME),
                       ipar = vr_of(INT_PARAMETER), iout = vr_of(INT_OUTPUT), str = vr_of(PROFILE),
                       unknown[3] = {TIME_VR + 1, 100000, UINT32_MAX}, mixed[2], t = TIME_VR;
    double d[2] = {-7.0, -7.0}, x = 1.0;
    fmi3Int32 i[2] = {-7, -7};
    fmi3String s[2] = {NULL, NULL};
    fmi3String bad_utf8 = "profiles/\xff.csv", null_string = NULL;
    int k;
    char name[64];
    for (k = 0; k < 3; k++) {
        snprintf(name, sizeof name, "value reference %lu", (unsigned long)unknown[k]);
        REFUSED(fmi3GetFloat64(c, &unknown[k], 1, d, 1), name);
        REFUSED(fmi3SetFloat64(c, &unknown[k], 1, &x, 1), name);
        REFUSED(fmi3GetInt32(c, &unknown[k], 1, i, 1), name);
        REFUSED(fmi3GetString(c, &unknown[k], 1, s, 1), name);
    }
    /* a bad one after a good one: nothing is read (or written: see the callers' twin runs) */
    mixed[0] = out;
    mixed[1] = unknown[0];
    REFUSED(fmi3GetFloat64(c, mixed, 2, d, 2), "valueReferences[1]");
    if (d[0] != -7.0 || d[1] != -7.0) FAIL("a refused getFloat64 wrote values");
    /* wrong type accessors */
    REFUSED(fmi3GetInt32(c, &out, 1, i, 1), "a Float64 variable, not an Int32");
    REFUSED(fmi3GetFloat64(c, &iout, 1, d, 1), "an Int32 variable, not a Float64");
    REFUSED(fmi3GetFloat64(c, &ipar, 1, d, 1), "an Int32 variable, not a Float64");
    REFUSED(fmi3GetString(c, &par, 1, s, 1), "a Float64 variable, not a String");
    REFUSED(fmi3GetFloat64(c, &str, 1, d, 1), "a String variable, not a Float64");
    REFUSED(fmi3GetInt32(c, &t, 1, i, 1), "'time', a Float64 variable, not an Int32");
    REFUSED(fmi3SetInt32(c, &in, 1, i, 1), "a Float64 variable, not an Int32");
    REFUSED(fmi3SetFloat64(c, &ipar, 1, &x, 1), "an Int32 variable, not a Float64");
    REFUSED(fmi3SetFloat64(c, &str, 1, &x, 1), "a String variable, not a Float64");
    REFUSED(fmi3SetString(c, &in, 1, s, 1), "a Float64 variable, not a String");
    if (d[0] != -7.0 || i[0] != -7 || s[0]) FAIL("a refused get wrote values");
    foreign_types(c, 0);
    foreign_types(c, 1);
    /* counts and pointers */
    REFUSED(fmi3GetFloat64(c, &out, 1, d, 2), "nValues = 2 but nValueReferences = 1");
    REFUSED(fmi3GetFloat64(c, &out, 1, d, 0), "nValues = 0 but nValueReferences = 1");
    REFUSED(fmi3SetFloat64(c, &in, 1, &x, 2), "nValues = 2 but nValueReferences = 1");
    REFUSED(fmi3GetInt32(c, &iout, 1, i, 3), "nValues = 3");
    REFUSED(fmi3GetFloat64(c, NULL, 1, d, 1), "valueReferences[] is NULL");
    REFUSED(fmi3SetFloat64(c, NULL, 1, &x, 1), "valueReferences[] is NULL");
    REFUSED(fmi3GetFloat64(c, &out, 1, NULL, 1), "values[] is NULL");
    REFUSED(fmi3SetFloat64(c, &in, 1, NULL, 1), "values[] is NULL");
    REFUSED(fmi3GetString(c, &str, 1, NULL, 1), "values[] is NULL");
    EXPECT(fmi3GetFloat64(c, NULL, 0, NULL, 0), fmi3OK);   /* nothing asked: fine */
    EXPECT(fmi3SetFloat64(c, NULL, 0, NULL, 0), fmi3OK);
    /* what cannot be set */
    REFUSED(fmi3SetFloat64(c, &out, 1, &x, 1), "is an output and cannot be set");
    REFUSED(fmi3SetInt32(c, &iout, 1, i, 1), "is an output and cannot be set");
    REFUSED(fmi3SetFloat64(c, &t, 1, &x, 1), "is the independent variable and cannot be set");
    if (!in_step_mode) {             /* (in step mode the fixed parameter is refused first) */
        REFUSED(fmi3SetString(c, &str, 1, &null_string, 1), "values[0] for '" PROFILE "'");
        REFUSED(fmi3SetString(c, &str, 1, &bad_utf8, 1), "is not valid UTF-8");
    }
    /* log categories */
    {
        fmi3String cats[2] = {"logAll", "logNoSuchThing"}, none[1] = {NULL};
        REFUSED(fmi3SetDebugLogging(c, fmi3True, 2, cats), "'logNoSuchThing' is not a log category");
        REFUSED(fmi3SetDebugLogging(c, fmi3True, 1, NULL), "categories[] is NULL");
        REFUSED(fmi3SetDebugLogging(c, fmi3True, 1, none), "categories[0] is NULL");
        EXPECT(fmi3SetDebugLogging(c, fmi3False, 1, cats), fmi3OK);
    }
}

static void live_refusals(void) {
    enum { N = 40 };
    fmi3Instance a = instantiate(), b = instantiate();
    fmi3ValueReference out = vr_of(FIRST_OUTPUT), in = vr_of(TRACTION), par = vr_of(BAD_NAME),
                       ipar = vr_of(INT_PARAMETER), str = vr_of(PROFILE), mixed[2];
    fmi3Boolean flag = fmi3False;
    double d = -7.0, x = 30.0, last = 0.0, pair[2];
    fmi3Int32 seven = 7;
    fmi3String profile = GOOD_PROFILE;
    int k, start_refused = n_refused;
    double oa[MAX_OUT], ob[MAX_OUT];

    /* instantiated */
    REFUSED(fmi3GetFloat64(a, &out, 1, &d, 1), "fmi3GetFloat64: not allowed in state 'instantiated'");
    if (d != -7.0) FAIL("a refused getFloat64 wrote a value");
    REFUSED(do_step(a, 0.0, DT), "fmi3DoStep: not allowed in state 'instantiated'");
    REFUSED(fmi3ExitInitializationMode(a), "not allowed in state 'instantiated'");
    REFUSED(fmi3Terminate(a), "fmi3Terminate: not allowed in state 'instantiated'");
    REFUSED(fmi3EnterInitializationMode(a, fmi3False, 0.0, NAN, fmi3False, 0.0),
            "startTime = nan is not finite");
    REFUSED(fmi3EnterInitializationMode(a, fmi3False, 0.0, INFINITY, fmi3False, 0.0),
            "is not finite");
    REFUSED(fmi3EnterInitializationMode(a, fmi3False, 0.0, 1.0, fmi3True, 0.5),
            "stopTime = 0.5 is before startTime = 1");
    REFUSED(fmi3SetFloat64(a, &out, 1, &x, 1), "is an output and cannot be set");
    unsupported(a);
    enter_init(a);
    enter_init(b);

    /* initialization mode */
    REFUSED(fmi3EnterInitializationMode(a, fmi3False, 0.0, 0.0, fmi3False, 0.0),
            "not allowed in state 'initialization mode'");
    REFUSED(do_step(a, 0.0, DT), "fmi3DoStep: not allowed in state 'initialization mode'");
    REFUSED(fmi3Terminate(a), "not allowed in state 'initialization mode'");
    bad_references(a, 0);
    unsupported(a);
    /* a refused set of two parameters sets neither (if it did, the twins' runs would differ) */
    mixed[0] = par;
    mixed[1] = out;
    pair[0] = 31.0;
    pair[1] = 1.0;
    REFUSED(fmi3SetFloat64(a, mixed, 2, pair, 2), "'" FIRST_OUTPUT "' (value reference");
    EXPECT_MESSAGE("is an output and cannot be set");
    EXPECT(fmi3ExitInitializationMode(a), fmi3OK);
    EXPECT(fmi3ExitInitializationMode(b), fmi3OK);
    if (get_time(a) != 0.0) FAIL("time after initialisation is %g", get_time(a));

    /* step mode, a good step after each group of refusals */
    for (k = 0; k < N; k++) {
        switch (k % 8) {
        case 1:
            REFUSED(fmi3SetFloat64(a, &par, 1, &x, 1),
                    "'" BAD_NAME "' (value reference");
            EXPECT_MESSAGE("can be set only before fmi3ExitInitializationMode");
            REFUSED(fmi3SetInt32(a, &ipar, 1, &seven, 1), "parameter of variability fixed");
            REFUSED(fmi3SetString(a, &str, 1, &profile, 1), "not in state 'step mode'");
            break;
        case 2:
            REFUSED(fmi3EnterInitializationMode(a, fmi3False, 0.0, 0.0, fmi3False, 0.0),
                    "not allowed in state 'step mode'");
            REFUSED(fmi3ExitInitializationMode(a), "not allowed in state 'step mode'");
            break;
        case 3:
            set_inputs(a, k, 0);
            REFUSED(fmi3DoStep(a, DT * k, DT, fmi3True, NULL, &flag, &flag, &last),
                    "an out-argument");
            REFUSED(fmi3DoStep(a, DT * k, DT, fmi3True, &flag, NULL, &flag, &last),
                    "an out-argument");
            REFUSED(fmi3DoStep(a, DT * k, DT, fmi3True, &flag, &flag, NULL, &last),
                    "an out-argument");
            REFUSED(fmi3DoStep(a, DT * k, DT, fmi3True, &flag, &flag, &flag, NULL),
                    "an out-argument");
            break;
        case 4:
            bad_references(a, 1);
            break;
        case 5:
            unsupported(a);
            break;
        case 6:
            /* the good inputs, then a refused set of a changed traction with a bad reference:
               if the traction were taken, the step would differ from the twin's */
            set_inputs(a, k, 0);
            mixed[0] = in;
            mixed[1] = par;
            pair[0] = 1234.5;
            pair[1] = 31.0;
            REFUSED(fmi3SetFloat64(a, mixed, 2, pair, 2), "can be set only before");
            mixed[1] = TIME_VR + 1;
            REFUSED(fmi3SetFloat64(a, mixed, 2, pair, 2), "is not a variable");
            break;
        default:
            break;
        }
        twin_step(a, b, k, "refused calls");
    }

    /* terminated */
    EXPECT(fmi3Terminate(a), fmi3OK);
    EXPECT(fmi3Terminate(b), fmi3OK);
    REFUSED(do_step(a, DT * N, DT), "fmi3DoStep: not allowed in state 'terminated'");
    REFUSED(fmi3SetFloat64(a, &in, 1, &x, 1), "not allowed in state 'terminated'");
    REFUSED(fmi3Terminate(a), "fmi3Terminate: not allowed in state 'terminated'");
    REFUSED(fmi3EnterInitializationMode(a, fmi3False, 0.0, 0.0, fmi3False, 0.0),
            "not allowed in state 'terminated'");
    k = outputs(a, oa);                 /* get still works, and agrees */
    outputs(b, ob);
    if (!same_bits(oa, ob, (size_t)k)) FAIL("after termination the outputs differ");
    if (get_time(a) != DT * (N - 1) + DT) FAIL("time after termination is %g", get_time(a));
    unsupported(a);
    /* and reset makes it new again */
    EXPECT(fmi3Reset(a), fmi3OK);
    EXPECT(fmi3Reset(b), fmi3OK);
    enter_init(a);
    enter_init(b);
    EXPECT(fmi3ExitInitializationMode(a), fmi3OK);
    EXPECT(fmi3ExitInitializationMode(b), fmi3OK);
    for (k = 0; k < 10; k++) twin_step(a, b, k, "terminate and reset");
    fmi3FreeInstance(a);
    fmi3FreeInstance(b);
    if (wrong_env) FAIL("%d messages came with another instanceEnvironment", wrong_env);
    printf("refusals %d on a live instance, each fmi3Error with its reason logged; %d good steps "
           "bit-identical to the twin\n", n_refused - start_refused, N + 10);
}

/* ------------------------------------------------------------------ 5. instantiation, dead instances */

static fmi3Instance try_instantiate(const char *name, const char *tok, const char *path,
                                    fmi3Boolean event_mode, size_t n_required,
                                    fmi3LogMessageCallback log) {
    fmi3ValueReference required[1] = {0};
    return fmi3InstantiateCoSimulation(name, tok, path, fmi3False, fmi3False, event_mode,
                                       fmi3False, n_required ? required : NULL, n_required,
                                       (fmi3InstanceEnvironment)&env_tag, log, NULL);
}

#define NOT_MADE(call, part)                                                                   \
    do {                                                                                       \
        fmi3Instance c_;                                                                       \
        last_message[0] = '\0';                                                                \
        last_status = -1;                                                                      \
        c_ = (call);                                                                           \
        if (c_) FAIL("%s made an instance", #call);                                          \
        if (last_status != (int)fmi3Error) FAIL("%s logged no error", #call);                 \
        if (!strstr(last_message, (part))) FAIL("%s: the message does not name '%s'", #call,   \
                                                (part));                                       \
        n_refused++;                                                                           \
    } while (0)

/* Instantiated at `path`, a relative profile found under it, a step, free. */
static void usable_at(const char *path, const char *tok) {
    fmi3Instance c = try_instantiate("cycles3", tok, path, fmi3False, 0, log_cb);
    double out[MAX_OUT];
    if (!c) FAIL("instantiation at %s refused", path);
    enter_init(c);
    set_string(c, PROFILE, GOOD_PROFILE);
    EXPECT(fmi3ExitInitializationMode(c), fmi3OK);
    set_inputs(c, 0, 0);
    EXPECT(do_step(c, 0.0, DT), fmi3OK);
    outputs(c, out);
    fmi3FreeInstance(c);
}

static void instantiation_and_dead_instances(void) {
    size_t len = strlen(resources);
    char *no_slash = malloc(len + 1), *uri = malloc(len + 32), *long_path = malloc(3001);
    fmi3Instance c, live;
    fmi3ValueReference in = vr_of(TRACTION);
    fmi3FMUState state = NULL;
    fmi3Boolean flag;
    double d = 0.0, last;
    void *junk = malloc(1);
    static double rows[5 * MAX_OUT];
    int stack_thing = 0, start_refused = n_refused, before;
    if (!no_slash || !uri || !long_path || !junk) FAIL("out of memory");

    if (strcmp(fmi3GetVersion(), "3.0") != 0) FAIL("fmi3GetVersion() = %s", fmi3GetVersion());
    NOT_MADE(fmi3InstantiateModelExchange("me", token, resources, fmi3False, fmi3False,
                                          (fmi3InstanceEnvironment)&env_tag, log_cb),
             "co-simulation only (no <ModelExchange>)");
    NOT_MADE(fmi3InstantiateScheduledExecution("se", token, resources, fmi3False, fmi3False,
                                               (fmi3InstanceEnvironment)&env_tag, log_cb, NULL,
                                               NULL, NULL),
             "co-simulation only (no <ScheduledExecution>)");
    NOT_MADE(try_instantiate("x", "{not-the-token}", resources, fmi3False, 0, log_cb),
             "instantiationToken '{not-the-token}' is not the one");
    EXPECT_MESSAGE(token);
    NOT_MADE(try_instantiate("x", NULL, resources, fmi3False, 0, log_cb),
             "instantiationToken is NULL");
    NOT_MADE(try_instantiate("x", token, "relative/resources/", fmi3False, 0, log_cb),
             "resourcePath 'relative/resources/' is not an absolute path");
    NOT_MADE(try_instantiate("x", token, "http://example.org/resources/", fmi3False, 0, log_cb),
             "'http://example.org/resources/' is not an absolute path");
    NOT_MADE(try_instantiate("x", token, "", fmi3False, 0, log_cb),
             "resourcePath '' is not an absolute path");
    /* a long one with '%' in it: the message carries it unchanged (the glue's '%' escaping for
       its FMI 2 style logger, undone for FMI 3, and its long-message path) */
    memset(long_path, 'a', 3000);
    long_path[3000] = '\0';
    memcpy(long_path, "100%%-%s-%n/", 12);
    NOT_MADE(try_instantiate("x", token, long_path, fmi3False, 0, log_cb), long_path);
    NOT_MADE(try_instantiate(NULL, token, resources, fmi3False, 0, log_cb),
             "instanceName is NULL or empty");
    NOT_MADE(try_instantiate("", token, resources, fmi3False, 0, log_cb),
             "instanceName is NULL or empty");
    NOT_MADE(try_instantiate("x", token, resources, fmi3True, 0, log_cb),
             "eventModeUsed = true, but this FMU has no event mode");
    NOT_MADE(try_instantiate("x", token, resources, fmi3False, 1, log_cb),
             "requiredIntermediateVariables given");
    /* refused without a logger: NULL, nothing called */
    before = n_messages;
    if (try_instantiate("x", "{not-the-token}", resources, fmi3False, 0, NULL) ||
        try_instantiate("x", token, "relative", fmi3False, 0, NULL) ||
        fmi3InstantiateModelExchange("me", token, resources, fmi3False, fmi3False, NULL, NULL))
        FAIL("an instance without a logger was made where it should have been refused");
    if (n_messages != before) FAIL("a NULL logger was replaced");

    /* accepted forms: no trailing '/', file: URIs, a folder with no modelDescription.xml beside
       it (the token cannot be checked: any is taken, as fmi3_glue.c's check_token says) */
    memcpy(no_slash, resources, len + 1);
    while (len > 1 && no_slash[len - 1] == '/') no_slash[--len] = '\0';
    usable_at(no_slash, token);
    snprintf(uri, len + 32, "file://%s", no_slash);
    usable_at(uri, token);
    snprintf(uri, len + 32, "file://localhost%s/", no_slash);
    usable_at(uri, token);
    snprintf(uri, len + 32, "file:%s", no_slash);
    usable_at(uri, token);
    usable_at(bare_resources, "{any token at all}");

    /* loggingOn: the instantiation's debug message only when asked for */
    before = n_messages;
    c = try_instantiate("x", token, resources, fmi3False, 0, log_cb);
    if (!c || n_messages != before) FAIL("loggingOn = false, yet a debug message");
    fmi3FreeInstance(c);
    c = fmi3InstantiateCoSimulation("x", token, resources, fmi3False, fmi3True, fmi3False,
                                    fmi3False, NULL, 0, (fmi3InstanceEnvironment)&env_tag, log_cb,
                                    NULL);
    if (!c || n_messages != before + 1 || last_status != (int)fmi3OK) FAIL("loggingOn = true, no "
                                                                          "debug message");
    EXPECT_MESSAGE(MODEL " instantiated");
    fmi3FreeInstance(c);

    /* an instance without a logger: refusals and discards are statuses only */
    before = n_messages;
    c = try_instantiate("quiet", token, resources, fmi3False, 0, NULL);
    if (!c) FAIL("no instance without a logger");
    EXPECT(do_step(c, 0.0, DT), fmi3Error);
    enter_init(c);
    set_string(c, PROFILE, "no/such/file.csv");
    EXPECT(fmi3ExitInitializationMode(c), fmi3Error);
    EXPECT(fmi3Reset(c), fmi3OK);
    enter_init(c);
    EXPECT(fmi3ExitInitializationMode(c), fmi3OK);
    set_real(c, TRACTION, NAN);
    EXPECT(do_step(c, 0.0, DT), fmi3Discard);
    set_real(c, TRACTION, 0.0);
    EXPECT(do_step(c, 0.0, DT), fmi3OK);
    EXPECT(fmi3SetFMUState(c, NULL), fmi3Error);
    fmi3FreeInstance(c);
    if (n_messages != before) FAIL("an instance without a logger logged");

    /* dead instances: NULL, freed (twice), never made -- refused without being touched */
    fmi3FreeInstance(NULL);
    live = fresh();                    /* one live instance alongside: untouched by all this */
    c = fresh();
    fmi3FreeInstance(c);
    fmi3FreeInstance(c);               /* a double free: ignored (the registry knows) */
    {
        fmi3Instance dead[4];
        int j;
        dead[0] = NULL;
        dead[1] = c;
        dead[2] = junk;                /* 1 byte: any read of an instance field would overflow */
        dead[3] = &stack_thing;
        for (j = 0; j < 4; j++) {
            DEAD(fmi3EnterInitializationMode(dead[j], fmi3False, 0.0, 0.0, fmi3False, 0.0));
            DEAD(fmi3ExitInitializationMode(dead[j]));
            DEAD(fmi3DoStep(dead[j], 0.0, DT, fmi3True, &flag, &flag, &flag, &last));
            DEAD(fmi3GetFloat64(dead[j], &in, 1, &d, 1));
            DEAD(fmi3SetFloat64(dead[j], &in, 1, &d, 1));
            DEAD(fmi3GetInt32(dead[j], NULL, 0, NULL, 0));
            DEAD(fmi3GetBoolean(dead[j], NULL, 0, NULL, 0));
            DEAD(fmi3SetBoolean(dead[j], NULL, 0, NULL, 0));
            DEAD(fmi3Terminate(dead[j]));
            DEAD(fmi3Reset(dead[j]));
            DEAD(fmi3SetDebugLogging(dead[j], fmi3True, 0, NULL));
            DEAD(fmi3GetFMUState(dead[j], &state));
            DEAD(fmi3EnterEventMode(dead[j]));
            if (j > 0) fmi3FreeInstance(dead[j]);  /* ignored */
        }
    }
    run(live, 5, rows, -1);
    fmi3FreeInstance(live);
    free(junk);
    free(no_slash);
    free(uri);
    free(long_path);
    printf("instantiation_and_dead %d refusals (no instance made, or not a live instance); 5 "
           "accepted resource path forms\n", n_refused - start_refused);
}

/* ------------------------------------------------------------------ 6. cycles */

static long rss_kb(void) {
    long size = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f) return -1;
    if (fscanf(f, "%ld %ld", &size, &resident) != 2) resident = -1;
    fclose(f);
    return resident < 0 ? -1 : resident * (sysconf(_SC_PAGESIZE) / 1024);
}

static void cycles(void) {
    int i, k;
    fmi3ValueReference par = vr_of(BAD_NAME);
    double x = 31.0;
    for (i = 1; i <= 1000; i++) {
        fmi3Instance c = instantiate();
        double out[MAX_OUT];
        char *path = malloc(4096);     /* the host's own buffer for the profile's path */
        if (!path) FAIL("out of memory");
        memset(path, 0, 4096);
        snprintf(path, 4096, "%s", GOOD_PROFILE);
        enter_init(c);
        set_string(c, PROFILE, path);  /* the glue copies it: the host may free it now */
#ifndef NATIVE3_LEAK_HOST
        free(path);
#endif
        EXPECT(fmi3ExitInitializationMode(c), fmi3OK);
        for (k = 0; k < 20; k++) {
            set_inputs(c, k, 0);
            EXPECT(do_step(c, DT * k, DT), fmi3OK);
        }
        REFUSED(fmi3SetFloat64(c, &par, 1, &x, 1), "can be set only before");
        outputs(c, out);
        EXPECT(fmi3Terminate(c), fmi3OK);
#ifndef NATIVE3_LEAK_INSTANCE
        fmi3FreeInstance(c);
#endif
        NOT_MADE(try_instantiate("x", "{not-the-token}", resources, fmi3False, 0, log_cb),
                 "is not the one");
        if (i == 100 || i == 1000) {
            printf("rss_kb %d %ld\n", i, rss_kb());
            printf("live_bytes %d %lu\n", i,
                   (unsigned long)__sanitizer_get_current_allocated_bytes());
        }
    }
    printf("cycles 1000\n");
}

/* ------------------------------------------------------------------ NULL resourcePath */

/* FMI 3.0 lets a host pass resourcePath = NULL (no resources it can provide); an FMU that can
   work without them must instantiate. Ours can: no profile by default, and a relative profile
   is then looked up in the working directory (fmu_src/c/native_common.c). */
static void null_resources(void) {
    fmi3Instance c = try_instantiate("noresources", token, NULL, fmi3False, 0, log_cb);
    double out[MAX_OUT];
    int k;
    if (!c) FAIL("fmi3InstantiateCoSimulation with resourcePath = NULL returned NULL");
    enter_init(c);
    EXPECT(fmi3ExitInitializationMode(c), fmi3OK);
    for (k = 0; k < 20; k++) {
        set_inputs(c, k, 0);
        EXPECT(do_step(c, DT * k, DT), fmi3OK);
    }
    outputs(c, out);
    EXPECT(fmi3Reset(c), fmi3OK);
    enter_init(c);
    set_string(c, PROFILE, "no/such/file.csv");
    EXPECT(fmi3ExitInitializationMode(c), fmi3Error);
    EXPECT_MESSAGE("no/such/file.csv");
    fmi3FreeInstance(c);
    printf("null_resources instantiated, 20 steps, a relative profile looked up in the working "
           "directory\n");
}

int main(int argc, char **argv) {
    if (argc != 6) {
        fprintf(stderr, "usage: native3_cycles MODE RESOURCES TOKEN BAD_PROFILE BARE_RESOURCES\n");
        return 2;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);   /* a sanitizer's exit does not flush stdio */
    resources = argv[2];
    token = argv[3];
    bad_profile = argv[4];
    bare_resources = argv[5];
    if (strcmp(argv[1], "main") == 0) {
        bad_inputs();
        reset_is_fresh();
        failed_inits();
        live_refusals();
        instantiation_and_dead_instances();
        cycles();
    } else if (strcmp(argv[1], "twin_control") == 0) {
        twin_control = 1;              /* must fail: the twin comparison sees one ulp */
        live_refusals();
    } else if (strcmp(argv[1], "null_resources") == 0) {
        null_resources();
    } else {
        fprintf(stderr, "unknown mode %s\n", argv[1]);
        return 2;
    }
    if (wrong_env) FAIL("%d messages came with another instanceEnvironment", wrong_env);
    printf("messages %d refused %d\nok\n", n_messages, n_refused);
    return 0;
}
