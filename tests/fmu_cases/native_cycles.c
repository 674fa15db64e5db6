/* A plain C host for tests/fmu_tests/test_native_sanitized.py: one native FMI 2.0 backend (RailCar, or
 * RailCarEstimator with -DNATIVE_ESTIMATOR), the glue and the C core linked in (no dlopen, no
 * Python), built with -fsanitize=address,undefined -fno-sanitize-recover=all.
 *
 *   native_cycles RESOURCE_URI GUID BAD_PROFILE_PATH
 *
 * RESOURCE_URI is a folder holding profiles/steep_grades.csv, beside a modelDescription.xml
 * whose guid is GUID (the glue checks it at each fmi2Instantiate); BAD_PROFILE_PATH an absolute path
 * to a grade profile whose line 3 is not a number. Runs, in order:
 *   1. the bad-input catalogue: NaN, +inf, negative traction, negative brake force, step 0, a
 *      negative step, a time that does not continue -> fmi2Discard with a message naming the
 *      variable (or the step size / the time); the next good step is fmi2OK, and the run's
 *      outputs after every good step are bit-identical to a run that never saw a bad input;
 *   2. reset: an instance run with another parameter (and a discard), reset, run with the
 *      defaults, gives outputs bit-identical to a fresh instance over 200 steps; the same run
 *      with one input one ulp off does differ (the comparison is not vacuous);
 *   3. 100 failed initialisations (bad parameters, a missing and a malformed profile file), each
 *      refused with fmi2Error naming the parameter (file and line), then reset, a good
 *      initialisation, a step, free;
 *   4. 1,000 cycles instantiate / setup / enter + exit initialisation (with a grade profile) /
 *      20 steps / terminate / free. Prints "rss_kb CYCLE KB" and "live_bytes CYCLE BYTES" (ASan's
 *      count of bytes the program holds, quarantine excluded) after cycles 100 and 1000.
 * With -DNATIVE_CYCLES_LEAK the host itself leaks 4 KB a cycle (the test's negative control).
 * Prints "ok" at the end; any failed expectation prints "FAILED line N: ..." and exits 1. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

/* ASan's allocator statistics (sanitizer/allocator_interface.h, not always installed) */
size_t __sanitizer_get_current_allocated_bytes(void);

#include "fmi2Functions.h"

#ifdef NATIVE_ESTIMATOR
#include "native_estimator_table.h"
#define VARS NES_VARS
#define NVARS NES_NVARS
#define TRACTION "traction_force"
#define BRAKE "brake_force"
#define BAD_NAME "est.mass_initial"
#define OTHER_PARAMETER "est.batch_size"
#define OTHER_VALUE 20
#else
#include "native_railcar_table.h"
#define VARS NRC_VARS
#define NVARS NRC_NVARS
#define TRACTION "traction_force_demand"
#define BRAKE "brake_force_demand"
#define BAD_NAME "car.mass"
#define OTHER_PARAMETER "seed"
#define OTHER_VALUE 7
#endif

#define DT 0.1
#define MAX_OUT 64

/* ------------------------------------------------------------------ host side */

static char last_message[2048];
static int n_messages;

static void log_cb(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env;
    (void)name;
    (void)status;
    (void)category;
    snprintf(last_message, sizeof last_message, "%s", message ? message : "");
    n_messages++;
}

static fmi2CallbackFunctions callbacks = {log_cb, calloc, free, NULL, NULL};
static const char *resource_uri, *guid, *bad_profile;

#define FAIL(...)                                                                              \
    do {                                                                                       \
        printf("FAILED line %d: ", __LINE__);                                                  \
        printf(__VA_ARGS__);                                                                   \
        printf(" (last message: %s)\n", last_message);                                         \
        exit(1);                                                                               \
    } while (0)

#define EXPECT(call, want)                                                                     \
    do {                                                                                       \
        fmi2Status s_ = (call);                                                                \
        if (s_ != (want)) FAIL("%s -> %d, not %d", #call, (int)s_, (int)(want));              \
    } while (0)

#define EXPECT_MESSAGE(part)                                                                   \
    do {                                                                                       \
        if (!strstr(last_message, (part))) FAIL("the message does not name '%s'", (part));   \
    } while (0)

static fmi2ValueReference vr_of(const char *name) {
    int k;
    for (k = 0; k < NVARS; k++)
        if (VARS[k].name && strcmp(VARS[k].name, name) == 0) return (fmi2ValueReference)k;
    printf("FAILED: no variable %s\n", name);
    exit(1);
}

static void set_real(fmi2Component c, const char *name, double value) {
    fmi2ValueReference vr = vr_of(name);
    EXPECT(fmi2SetReal(c, &vr, 1, &value), fmi2OK);
}

static void set_integer(fmi2Component c, const char *name, int value) {
    fmi2ValueReference vr = vr_of(name);
    fmi2Integer v = value;
    EXPECT(fmi2SetInteger(c, &vr, 1, &v), fmi2OK);
}

static void set_string(fmi2Component c, const char *name, const char *value) {
    fmi2ValueReference vr = vr_of(name);
    EXPECT(fmi2SetString(c, &vr, 1, &value), fmi2OK);
}

static fmi2Component instantiate(void) {
    fmi2Component c = fmi2Instantiate("cycles", fmi2CoSimulation, guid, resource_uri,
                                      &callbacks, fmi2False, fmi2False);
    if (!c) FAIL("fmi2Instantiate returned NULL");
    return c;
}

static void enter_init(fmi2Component c) {
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
}

/* A fresh instance with the default parameters, initialised. */
static fmi2Component fresh(void) {
    fmi2Component c = instantiate();
    enter_init(c);
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
    return c;
}

/* The inputs of step k (deterministic: accelerating, coasting, braking; the estimator's
   measurements follow a 30 t car under those forces). `perturb`: the first input (RailCar's
   traction demand, the estimator's measured speed) one ulp up. */
static void set_inputs(fmi2Component c, int k, int perturb) {
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

/* Every output (Reals, then Integers as doubles) -> out; their number. */
static int outputs(fmi2Component c, double *out) {
    int k, n = 0;
    for (k = 0; k < NVARS; k++) {
        fmi2ValueReference vr = (fmi2ValueReference)k;
        if (!VARS[k].name || VARS[k].causality != GLUE_OUTPUT) continue;
        if (n >= MAX_OUT) FAIL("more than %d outputs", MAX_OUT);
        if (VARS[k].type == GLUE_REAL) {
            EXPECT(fmi2GetReal(c, &vr, 1, &out[n]), fmi2OK);
        } else {
            fmi2Integer i;
            EXPECT(fmi2GetInteger(c, &vr, 1, &i), fmi2OK);
            out[n] = (double)i;
        }
        n++;
    }
    if (n == 0) FAIL("no outputs");
    return n;
}

/* Steps 0 .. n-1 of the standard run, outputs after each into rows[k * MAX_OUT ...]. */
static int run(fmi2Component c, int n, double *rows, int perturb_at) {
    int k, nout = 0;
    for (k = 0; k < n; k++) {
        set_inputs(c, k, k == perturb_at);
        EXPECT(fmi2DoStep(c, DT * k, DT, fmi2True), fmi2OK);
        nout = outputs(c, rows + (size_t)k * MAX_OUT);
    }
    return nout;
}

static int same_bits(const double *a, const double *b, size_t n) {
    return memcmp(a, b, n * sizeof *a) == 0;
}

/* ------------------------------------------------------------------ 1. bad inputs */

typedef struct {
    const char *what;
    const char *input;       /* the input set to `value` (NULL: none) */
    double value;
    double time_offset, step; /* the doStep's currentTime offset and step size */
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
    static double with_bad[N * MAX_OUT], clean[N * MAX_OUT];
    fmi2Component a = fresh(), b = fresh();
    int k, nout = 0, discards = 0;
    memset(with_bad, 0, sizeof with_bad);
    memset(clean, 0, sizeof clean);
    for (k = 0; k < N; k++) {
        if (k % 5 == 2 && k / 5 < NCASES) {
            const bad_case *bc = &cases[k / 5];
            double before[MAX_OUT], after[MAX_OUT];
            int n0 = outputs(a, before);
            set_inputs(a, k, 0);
            if (bc->input) set_real(a, bc->input, bc->value);
            last_message[0] = '\0';
            EXPECT(fmi2DoStep(a, DT * k + bc->time_offset, bc->step, fmi2True), fmi2Discard);
            if (strncmp(last_message, "step discarded: ", 16) != 0)
                FAIL("%s: no 'step discarded: ' message", bc->what);
            EXPECT_MESSAGE(bc->named);
            outputs(a, after);
            if (!same_bits(before, after, (size_t)n0)) FAIL("%s changed the outputs", bc->what);
            discards++;
        }
        set_inputs(a, k, 0);            /* the good inputs again, the step at the right time */
        EXPECT(fmi2DoStep(a, DT * k, DT, fmi2True), fmi2OK);
        nout = outputs(a, with_bad + (size_t)k * MAX_OUT);
        set_inputs(b, k, 0);
        EXPECT(fmi2DoStep(b, DT * k, DT, fmi2True), fmi2OK);
        outputs(b, clean + (size_t)k * MAX_OUT);
        if (!same_bits(with_bad + (size_t)k * MAX_OUT, clean + (size_t)k * MAX_OUT, (size_t)nout))
            FAIL("after the discards, step %d differs from a clean run", k);
    }
    if (discards != NCASES) FAIL("%d bad inputs tried, not %d", discards, (int)NCASES);
    EXPECT(fmi2Terminate(a), fmi2OK);
    EXPECT(fmi2Terminate(b), fmi2OK);
    fmi2FreeInstance(a);
    fmi2FreeInstance(b);
    printf("bad_inputs %d discarded, each followed by a good step; %d outputs bit-identical to a "
           "clean run\n", discards, nout);
}

/* ------------------------------------------------------------------ 2. reset */

static void reset_is_fresh(void) {
    enum { N = 200 };
    static double after_reset[N * MAX_OUT], fresh_rows[N * MAX_OUT], perturbed[N * MAX_OUT];
    fmi2Component a = instantiate(), b, p;
    int k, nout, differ = -1;
    memset(after_reset, 0, sizeof after_reset);
    memset(fresh_rows, 0, sizeof fresh_rows);
    memset(perturbed, 0, sizeof perturbed);
    /* a history to forget: another parameter, some steps, a discarded one */
    enter_init(a);
#ifdef NATIVE_ESTIMATOR
    set_integer(a, OTHER_PARAMETER, OTHER_VALUE);
#else
    set_integer(a, OTHER_PARAMETER, OTHER_VALUE);
    set_string(a, "track.grade_profile", "profiles/steep_grades.csv");
#endif
    EXPECT(fmi2ExitInitializationMode(a), fmi2OK);
    for (k = 0; k < 150; k++) {
        set_inputs(a, k + 7, 0);
        EXPECT(fmi2DoStep(a, DT * k, DT, fmi2True), fmi2OK);
    }
    set_real(a, TRACTION, NAN);
    EXPECT(fmi2DoStep(a, DT * k, DT, fmi2True), fmi2Discard);
    EXPECT(fmi2Reset(a), fmi2OK);
    enter_init(a);
    EXPECT(fmi2ExitInitializationMode(a), fmi2OK);
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
    fmi2FreeInstance(a);
    fmi2FreeInstance(b);
    fmi2FreeInstance(p);
    printf("reset %d steps x %d outputs bit-identical to a fresh instance; one ulp off differs "
           "from step %d\n", N, nout, differ);
}

/* ------------------------------------------------------------------ 3. failed initialisations */

static void failed_inits(void) {
    int i;
    for (i = 0; i < 100; i++) {
        fmi2Component c = instantiate();
        const char *named;
        double out[MAX_OUT];
        enter_init(c);
        switch (i % 4) {
        case 0:
            set_real(c, BAD_NAME, -1.0);
            named = BAD_NAME;
            break;
        case 1:
#ifdef NATIVE_ESTIMATOR
            set_integer(c, "est.batch_size", 0);
            named = "est.batch_size";
#else
            set_real(c, "sensor.sample_period", 0.0);
            named = "sensor.sample_period";
#endif
            break;
        case 2:
            set_string(c, "track.grade_profile", "no/such/file.csv");
            named = "no/such/file.csv";
            break;
        default:
            set_string(c, "track.grade_profile", bad_profile);
            named = "line 3";
            break;
        }
        last_message[0] = '\0';
        EXPECT(fmi2ExitInitializationMode(c), fmi2Error);
        EXPECT_MESSAGE("initialisation failed: ");
        EXPECT_MESSAGE(named);
        if (i % 4 >= 2) EXPECT_MESSAGE("track.grade_profile");
        if (i % 4 == 3) EXPECT_MESSAGE(bad_profile);
        EXPECT(fmi2Reset(c), fmi2OK);
        enter_init(c);
        if (i % 8 == 7) set_string(c, "track.grade_profile", "profiles/steep_grades.csv");
        EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
        set_inputs(c, 0, 0);
        EXPECT(fmi2DoStep(c, 0.0, DT, fmi2True), fmi2OK);
        outputs(c, out);
        fmi2FreeInstance(c);
    }
    printf("failed_inits 100 refused naming the parameter or file and line, each reset and run\n");
}

/* ------------------------------------------------------------------ 4. cycles */

static long rss_kb(void) {
    long size = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (!f) return -1;
    if (fscanf(f, "%ld %ld", &size, &resident) != 2) resident = -1;
    fclose(f);
    return resident < 0 ? -1 : resident * (sysconf(_SC_PAGESIZE) / 1024);
}

#ifdef NATIVE_CYCLES_LEAK
static void *volatile leaked;          /* the test's proof that a leak is seen: 4 KB a cycle */
#endif

static void cycles(void) {
    int i, k;
    for (i = 1; i <= 1000; i++) {
        fmi2Component c = instantiate();
        double out[MAX_OUT];
        enter_init(c);
        set_string(c, "track.grade_profile", "profiles/steep_grades.csv");
        EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
        for (k = 0; k < 20; k++) {
            set_inputs(c, k, 0);
            EXPECT(fmi2DoStep(c, DT * k, DT, fmi2True), fmi2OK);
        }
        outputs(c, out);
        EXPECT(fmi2Terminate(c), fmi2OK);
        fmi2FreeInstance(c);
#ifdef NATIVE_CYCLES_LEAK
        leaked = malloc(4096);
        if (leaked) memset(leaked, i & 0xff, 4096);
#endif
        if (i == 100 || i == 1000) {
            printf("rss_kb %d %ld\n", i, rss_kb());
            printf("live_bytes %d %lu\n", i,
                   (unsigned long)__sanitizer_get_current_allocated_bytes());
        }
    }
    printf("cycles 1000\n");
}

int main(int argc, char **argv) {
    if (argc != 4) {
        fprintf(stderr, "usage: native_cycles RESOURCE_URI GUID BAD_PROFILE_PATH\n");
        return 2;
    }
    setvbuf(stdout, NULL, _IOLBF, 0);   /* a sanitizer's exit does not flush stdio */
    resource_uri = argv[1];
    guid = argv[2];
    bad_profile = argv[3];
    bad_inputs();
    reset_is_fresh();
    failed_inits();
    cycles();
    printf("messages %d\nok\n", n_messages);
    return 0;
}
