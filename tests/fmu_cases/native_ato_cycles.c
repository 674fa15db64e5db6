/* A plain C host for the native AtoController (fmu_src/c/native_ato.c) under ASan/UBSan/LSan:
 * the backend, the glue (FMI 2.0 by default, FMI 3.0 with -DATO_FMI3) and the C core linked in
 * (no dlopen, no Python), built with -fsanitize=address,undefined -fno-sanitize-recover=all by
 * tests/fmu_tests/test_native_sanitized.py (FMI 2) and test_native3_sanitized.py (FMI 3).
 *
 *   native_ato_cycles RESOURCES TOKEN
 *
 * RESOURCES: the resources folder (FMI 2: a file: URI; FMI 3: an absolute path ending in '/')
 * beside a modelDescription.xml whose guid (FMI 2) / instantiationToken (FMI 3) is TOKEN. On
 * the default span (span.stop 2000 m, no profiles), the host driving a point-mass car from the
 * commands (speed and position fed back as the filter's, the configured car as the estimate):
 *   1. a clean run of RUN_STEPS steps: the car starts, the outputs are finite, the Booleans read;
 *   2. a bad input (filter.speed NaN at step BAD_AT) -> Warning, the safe brake (no traction,
 *      brake >= car.brake_force_max, ato.mode 9); a step of 0 -> Discard, outputs unchanged;
 *   3. reset: an instance run with car.mass 35 t and ato.replan false, reset, run as the clean
 *      run: bit-identical to it at every step; with filter.speed one ulp off it differs;
 *   4. FAILED_INITS failed initialisations (ato.safe_brake 0, span.stop -100) -> Error naming
 *      the parameter, then reset, a good initialisation, a step, free;
 *   5. CYCLES cycles instantiate / initialise / 10 steps / terminate / free. Prints
 *      "live_bytes CYCLE BYTES" (ASan's count of bytes held, quarantine excluded) and
 *      "rss_kb CYCLE KB" after cycles CYCLE_A and CYCLES.
 * Prints "ok" at the end; any failed expectation prints "FAILED line N: ..." and exits 1. */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* ASan's allocator statistics (sanitizer/allocator_interface.h, not always installed) */
size_t __sanitizer_get_current_allocated_bytes(void);

#ifdef ATO_FMI3
#include "fmi3Functions.h"
#else
#include "fmi2Functions.h"
#endif
#include "native_ato_table.h"

#define DT 0.1              /* [s] */
#define RUN_STEPS 300       /* 30 s: the car accelerates, the plan is re-made 15 times */
#define BAD_AT 120
#define FAILED_INITS 20
#define CYCLE_A 20
#define CYCLES 200
#define BRAKE_MAX 45000.0   /* [N] car.brake_force_max's start value */
#define SAFE_MODE 9

static const unsigned OUTPUT_VRS[] = {
    NAT_VR_TRACTION_FORCE_DEMAND, NAT_VR_BRAKE_FORCE_DEMAND, NAT_VR_ATO_PLANNED_SPEED,
    NAT_VR_ATO_PREDICTED_ARRIVAL, NAT_VR_ATO_PAYLOAD};
#define N_OUT (sizeof OUTPUT_VRS / sizeof OUTPUT_VRS[0])

static const char *resources, *token;
static char last_message[2048];

#define FAIL(...)                                                                              \
    do {                                                                                       \
        printf("FAILED line %d: ", __LINE__);                                                  \
        printf(__VA_ARGS__);                                                                   \
        printf(" (last message: %s)\n", last_message);                                         \
        exit(1);                                                                               \
    } while (0)
#define CHECK(cond, ...)                                                                       \
    do {                                                                                       \
        if (!(cond)) FAIL(__VA_ARGS__);                                                        \
    } while (0)

/* ------------------------------------------- the few calls the host makes, in either version */

#ifdef ATO_FMI3
typedef fmi3Instance Inst;
static void log_fmi3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                 fmi3String message) {
    (void)env;
    (void)status;
    (void)category;
    snprintf(last_message, sizeof last_message, "%s", message ? message : "");
}
static Inst instantiate(void) {
    return fmi3InstantiateCoSimulation("ato", token, resources, fmi3False, fmi3True, fmi3False,
                                       fmi3False, NULL, 0, NULL, log_fmi3, NULL);
}
static int enter_init(Inst m) {
    return (int)fmi3EnterInitializationMode(m, fmi3False, 0.0, 0.0, fmi3False, 0.0);
}
static int exit_init(Inst m) { return (int)fmi3ExitInitializationMode(m); }
static int do_step(Inst m, double t, double h) {
    fmi3Boolean event, terminate, early;
    fmi3Float64 last;
    return (int)fmi3DoStep(m, t, h, fmi3True, &event, &terminate, &early, &last);
}
static int set_real(Inst m, unsigned vr, double x) {
    fmi3ValueReference r = vr;
    return (int)fmi3SetFloat64(m, &r, 1, &x, 1);
}
static int set_int(Inst m, unsigned vr, int x) {
    fmi3ValueReference r = vr;
    fmi3Int32 v = x;
    return (int)fmi3SetInt32(m, &r, 1, &v, 1);
}
static int set_bool(Inst m, unsigned vr, int x) {
    fmi3ValueReference r = vr;
    fmi3Boolean v = x ? fmi3True : fmi3False;
    return (int)fmi3SetBoolean(m, &r, 1, &v, 1);
}
static int get_reals(Inst m, const unsigned *vr, size_t n, double *out) {
    fmi3ValueReference r[16];
    size_t i;
    for (i = 0; i < n; i++) r[i] = vr[i];
    return (int)fmi3GetFloat64(m, r, n, out, n);
}
static int get_int(Inst m, unsigned vr) {
    fmi3ValueReference r = vr;
    fmi3Int32 v = -1;
    CHECK(fmi3GetInt32(m, &r, 1, &v, 1) == fmi3OK, "fmi3GetInt32(%u)", vr);
    return v;
}
static int get_bool(Inst m, unsigned vr) {
    fmi3ValueReference r = vr;
    fmi3Boolean v = fmi3False;
    CHECK(fmi3GetBoolean(m, &r, 1, &v, 1) == fmi3OK, "fmi3GetBoolean(%u)", vr);
    return v ? 1 : 0;
}
static int reset(Inst m) { return (int)fmi3Reset(m); }
static int terminate(Inst m) { return (int)fmi3Terminate(m); }
static void free_instance(Inst m) { fmi3FreeInstance(m); }
#define OK fmi3OK
#define WARNING fmi3Warning
#define DISCARD fmi3Discard
#define ERROR fmi3Error
#else
typedef fmi2Component Inst;
static void log_fmi2(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                 fmi2String category, fmi2String message, ...) {
    (void)env;
    (void)name;
    (void)status;
    (void)category;
    snprintf(last_message, sizeof last_message, "%s", message ? message : "");
}
static fmi2CallbackFunctions callbacks = {log_fmi2, calloc, free, NULL, NULL};
static Inst instantiate(void) {
    return fmi2Instantiate("ato", fmi2CoSimulation, token, resources, &callbacks, fmi2False,
                           fmi2True);
}
static int enter_init(Inst m) {
    int s = (int)fmi2SetupExperiment(m, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    return s != fmi2OK ? s : (int)fmi2EnterInitializationMode(m);
}
static int exit_init(Inst m) { return (int)fmi2ExitInitializationMode(m); }
static int do_step(Inst m, double t, double h) { return (int)fmi2DoStep(m, t, h, fmi2True); }
static int set_real(Inst m, unsigned vr, double x) {
    fmi2ValueReference r = vr;
    return (int)fmi2SetReal(m, &r, 1, &x);
}
static int set_int(Inst m, unsigned vr, int x) {
    fmi2ValueReference r = vr;
    fmi2Integer v = x;
    return (int)fmi2SetInteger(m, &r, 1, &v);
}
static int set_bool(Inst m, unsigned vr, int x) {
    fmi2ValueReference r = vr;
    fmi2Boolean v = x ? fmi2True : fmi2False;
    return (int)fmi2SetBoolean(m, &r, 1, &v);
}
static int get_reals(Inst m, const unsigned *vr, size_t n, double *out) {
    fmi2ValueReference r[16];
    size_t i;
    for (i = 0; i < n; i++) r[i] = vr[i];
    return (int)fmi2GetReal(m, r, n, out);
}
static int get_int(Inst m, unsigned vr) {
    fmi2ValueReference r = vr;
    fmi2Integer v = -1;
    CHECK(fmi2GetInteger(m, &r, 1, &v) == fmi2OK, "fmi2GetInteger(%u)", vr);
    return v;
}
static int get_bool(Inst m, unsigned vr) {
    fmi2ValueReference r = vr;
    fmi2Boolean v = fmi2False;
    CHECK(fmi2GetBoolean(m, &r, 1, &v) == fmi2OK, "fmi2GetBoolean(%u)", vr);
    return v ? 1 : 0;
}
static int reset(Inst m) { return (int)fmi2Reset(m); }
static int terminate(Inst m) { return (int)fmi2Terminate(m); }
static void free_instance(Inst m) { fmi2FreeInstance(m); }
#define OK fmi2OK
#define WARNING fmi2Warning
#define DISCARD fmi2Discard
#define ERROR fmi2Error
#endif

/* --------------------------------------------------------------------------- the car */

typedef struct {
    double v, x;            /* [m/s], [m] */
} Car;

/* The filter's and estimator's inputs of step k for the car; `nudge`: the speed one ulp up. */
static void feed(Inst m, const Car *car, int k, int nudge) {
    double v = nudge ? nextafter(car->v, INFINITY) : car->v;
    CHECK(set_real(m, NAT_VR_FILTER_SPEED, v) == OK, "set filter.speed");
    CHECK(set_real(m, NAT_VR_FILTER_POSITION, car->x) == OK, "set filter.position");
    CHECK(set_real(m, NAT_VR_FILTER_SPEED_STD, 0.05) == OK, "set filter.speed_std");
    CHECK(set_real(m, NAT_VR_FILTER_POSITION_STD, 0.1) == OK, "set filter.position_std");
    CHECK(set_int(m, NAT_VR_EST_STATUS, 1) == OK, "set est.status");
    CHECK(set_int(m, NAT_VR_EST_SAMPLES, 50 + k) == OK, "set est.samples");
}

/* The car under the commands over one step: a point mass of 30 t, resistance left out. */
static void move(Car *car, const double out[N_OUT]) {
    double a = (out[0] - out[1]) / 30000.0;
    car->v = car->v + a * DT > 0.0 ? car->v + a * DT : 0.0;
    car->x += car->v * DT;
}

static Inst started(int replan, double mass) {
    Inst m = instantiate();
    CHECK(m != NULL, "instantiate");
    CHECK(enter_init(m) == OK, "enter initialisation");
    CHECK(set_bool(m, NAT_VR_ATO_REPLAN, replan) == OK, "set ato.replan");
    CHECK(set_real(m, NAT_VR_CAR_MASS, mass) == OK, "set car.mass");
    CHECK(exit_init(m) == OK, "exit initialisation");
    return m;
}

/* `steps` steps from rest; outputs after each step into rows (may be NULL); filter.speed one
   ulp up from step nudge_at on (-1: never). */
static void run(Inst m, int steps, double (*rows)[N_OUT], int nudge_at) {
    Car car = {0.0, 0.0};
    double out[N_OUT];
    int k;
    for (k = 0; k < steps; k++) {
        feed(m, &car, k, nudge_at >= 0 && k >= nudge_at);
        CHECK(do_step(m, k * DT, DT) == OK, "step %d", k);
        CHECK(get_reals(m, OUTPUT_VRS, N_OUT, out) == OK, "get outputs at step %d", k);
        if (rows) memcpy(rows[k], out, sizeof out);
        move(&car, out);
    }
}

static int first_difference(double (*a)[N_OUT], double (*b)[N_OUT], int steps) {
    int k;
    for (k = 0; k < steps; k++)
        if (memcmp(a[k], b[k], sizeof a[k]) != 0) return k;
    return -1;
}

static double clean_rows[RUN_STEPS][N_OUT], other_rows[RUN_STEPS][N_OUT];

/* ------------------------------------------------------------------------------ the parts */

static void clean_run(void) {
    Inst m = started(1, 30.0);
    int k, moved = 0, replans;
    size_t j;
    CHECK(get_bool(m, NAT_VR_ATO_REPLAN) == 1 && get_bool(m, NAT_VR_ATO_FINISHED) == 0,
          "Booleans after initialisation");
    run(m, RUN_STEPS, clean_rows, -1);
    for (k = 0; k < RUN_STEPS; k++) {
        for (j = 0; j < N_OUT; j++) CHECK(isfinite(clean_rows[k][j]), "output %u at step %d", (unsigned)j, k);
        moved |= clean_rows[k][0] > 0.0;
    }
    CHECK(moved, "no traction in %d steps", RUN_STEPS);
    replans = get_int(m, NAT_VR_ATO_REPLANS);
    CHECK(replans >= 5, "re-plans: %d", replans);
    CHECK(get_bool(m, NAT_VR_ATO_FINISHED) == 0, "finished after 30 s of a 125 s span");
    CHECK(terminate(m) == OK, "terminate");
    free_instance(m);
    printf("clean_run %d steps, %d re-plans\n", RUN_STEPS, replans);
}

static void bad_input_and_step(void) {
    Inst m = started(1, 30.0);
    Car car = {0.0, 0.0};
    double out[N_OUT], before[N_OUT];
    int k, status;
    for (k = 0; k < BAD_AT; k++) {
        feed(m, &car, k, 0);
        CHECK(do_step(m, k * DT, DT) == OK, "step %d", k);
        CHECK(get_reals(m, OUTPUT_VRS, N_OUT, out) == OK, "outputs");
        move(&car, out);
    }
    CHECK(get_reals(m, OUTPUT_VRS, N_OUT, before) == OK, "outputs");
    feed(m, &car, k, 0);
    CHECK(do_step(m, k * DT, 0.0) == DISCARD, "a step of 0 s is not discarded");
    CHECK(get_reals(m, OUTPUT_VRS, N_OUT, out) == OK && memcmp(out, before, sizeof out) == 0,
          "a discarded step changed the outputs");
    CHECK(set_real(m, NAT_VR_FILTER_SPEED, NAN) == OK, "set NaN");
    status = do_step(m, k * DT, DT);
    CHECK(status == WARNING, "filter.speed NaN: status %d, not Warning", status);
    CHECK(strstr(last_message, "filter.speed") != NULL, "the warning names no filter.speed");
    CHECK(get_reals(m, OUTPUT_VRS, N_OUT, out) == OK, "outputs");
    CHECK(out[0] == 0.0 && out[1] >= BRAKE_MAX && get_int(m, NAT_VR_ATO_MODE) == SAFE_MODE,
          "no safe brake: traction %g, brake %g, mode %d", out[0], out[1],
          get_int(m, NAT_VR_ATO_MODE));
    CHECK(terminate(m) == OK, "terminate");
    free_instance(m);
    printf("bad_input warning with the safe brake; step of 0 discarded\n");
}

static void reset_is_fresh(void) {
    Inst m = started(0, 35.0);
    int differs;
    run(m, RUN_STEPS / 3, NULL, -1);
    CHECK(reset(m) == OK, "reset");
    CHECK(enter_init(m) == OK && exit_init(m) == OK, "initialisation after reset");
    run(m, RUN_STEPS, other_rows, -1);
    differs = first_difference(clean_rows, other_rows, RUN_STEPS);
    CHECK(differs < 0, "after reset, step %d differs from a fresh instance", differs);
    CHECK(reset(m) == OK && enter_init(m) == OK && exit_init(m) == OK, "reset again");
    run(m, RUN_STEPS, other_rows, 10);
    differs = first_difference(clean_rows, other_rows, RUN_STEPS);
    CHECK(differs >= 0, "filter.speed one ulp off from step 10 on changed nothing");
    CHECK(terminate(m) == OK, "terminate");
    free_instance(m);
    printf("reset %d steps x %u outputs bit-identical to a fresh instance; one ulp off differs "
           "from step %d\n", RUN_STEPS, (unsigned)N_OUT, differs);
}

static void failed_inits(void) {
    int i;
    for (i = 0; i < FAILED_INITS; i++) {
        Inst m = instantiate();
        const char *name = i % 2 ? "span.stop" : "ato.safe_brake";
        CHECK(m != NULL, "instantiate");
        CHECK(enter_init(m) == OK, "enter initialisation");
        CHECK(set_real(m, i % 2 ? NAT_VR_SPAN_STOP : NAT_VR_ATO_SAFE_BRAKE, i % 2 ? -100.0 : 0.0)
              == OK, "set %s", name);
        CHECK(exit_init(m) == ERROR, "a bad %s accepted", name);
        CHECK(strstr(last_message, name) != NULL, "the error names no %s", name);
        CHECK(reset(m) == OK && enter_init(m) == OK && exit_init(m) == OK, "good init after reset");
        CHECK(do_step(m, 0.0, DT) == OK, "a step after reset");
        free_instance(m);
    }
    printf("failed_inits %d refused naming the parameter\n", FAILED_INITS);
}

static long rss_kb(void) {
    long pages = 0, resident = 0;
    FILE *f = fopen("/proc/self/statm", "r");
    if (f) {
        if (fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
        fclose(f);
    }
    return resident * 4;
}

static void cycles(void) {
    int i;
    for (i = 1; i <= CYCLES; i++) {
        Inst m = started(1, 30.0);
        run(m, 10, NULL, -1);
        CHECK(terminate(m) == OK, "terminate");
        free_instance(m);
        if (i == CYCLE_A || i == CYCLES) {
            printf("rss_kb %d %ld\n", i, rss_kb());
            printf("live_bytes %d %lu\n", i,
                   (unsigned long)__sanitizer_get_current_allocated_bytes());
        }
    }
    printf("cycles %d\n", CYCLES);
}

int main(int argc, char **argv) {
    if (argc != 3) {
        fprintf(stderr, "usage: %s RESOURCES TOKEN\n", argv[0]);
        return 2;
    }
    resources = argv[1];
    token = argv[2];
    clean_run();
    bad_input_and_step();
    reset_is_fresh();
    failed_inits();
    cycles();
    printf("ok\n");
    return 0;
}
