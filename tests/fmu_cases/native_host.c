/* A C host for tests/fmu_tests/test_native_fmu.py's sanitizer run: the native RailCar backend, the glue and
 * the core linked in (no dlopen), built with -fsanitize=address,undefined.
 *
 *   native_host RESOURCE_URI GUID VR_CAR_MASS VR_TRACTION VR_GRADE_PROFILE VR_SPEED_PROFILE VR_CAR_SPEED
 *
 * Runs: a good instance with a relative grade profile (steps, a NaN traction discarded, the
 * retry), a bad parameter (fmi2Error), reset and a good initialisation, a missing profile file,
 * fmi2GetString, then frees everything. Prints "ok" at the end; any failed expectation exits 1. */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"

static void log_cb(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    (void)env;
    (void)name;
    printf("log [%d] %s: %s\n", (int)status, category ? category : "-", message);
}

#define EXPECT(call, want)                                                                     \
    do {                                                                                       \
        fmi2Status s_ = (call);                                                                \
        if (s_ != (want)) {                                                                    \
            printf("FAILED line %d: %s -> %d, not %d\n", __LINE__, #call, (int)s_, (int)(want)); \
            exit(1);                                                                           \
        }                                                                                      \
    } while (0)

int main(int argc, char **argv) {
    fmi2CallbackFunctions cb = {log_cb, calloc, free, NULL, NULL};
    fmi2ValueReference vr_mass, vr_traction, vr_grade, vr_speed_profile, out_speed;
    fmi2Real value, speed;
    fmi2String s, grade = "profiles/steep_grades.csv", missing = "no/such.csv";
    fmi2Component c;
    int k;
    if (argc != 8) return 2;
    vr_mass = (fmi2ValueReference)atoi(argv[3]);
    vr_traction = (fmi2ValueReference)atoi(argv[4]);
    vr_grade = (fmi2ValueReference)atoi(argv[5]);
    vr_speed_profile = (fmi2ValueReference)atoi(argv[6]);
    out_speed = (fmi2ValueReference)atoi(argv[7]);
    c = fmi2Instantiate("host", fmi2CoSimulation, argv[2], argv[1], &cb, fmi2False, fmi2True);
    if (!c) return 1;
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    EXPECT(fmi2SetString(c, &vr_grade, 1, &grade), fmi2OK);
    EXPECT(fmi2GetString(c, &vr_grade, 1, &s), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2OK);
    for (k = 0; k < 400; k++) {
        value = k == 100 ? NAN : 30e3;
        EXPECT(fmi2SetReal(c, &vr_traction, 1, &value), fmi2OK);
        EXPECT(fmi2DoStep(c, 0.1 * (k < 100 ? k : k - 1), 0.1, fmi2True),
               k == 100 ? fmi2Discard : fmi2OK);
    }
    EXPECT(fmi2GetReal(c, &out_speed, 1, &speed), fmi2OK);
    if (!(speed > 1.0)) return 1;
    EXPECT(fmi2Reset(c), fmi2OK);
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    value = -1.0;
    EXPECT(fmi2SetReal(c, &vr_mass, 1, &value), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);
    EXPECT(fmi2Reset(c), fmi2OK);
    EXPECT(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0), fmi2OK);
    EXPECT(fmi2EnterInitializationMode(c), fmi2OK);
    EXPECT(fmi2SetString(c, &vr_speed_profile, 1, &missing), fmi2OK);
    EXPECT(fmi2ExitInitializationMode(c), fmi2Error);
    EXPECT(fmi2Terminate(c), fmi2OK);
    fmi2FreeInstance(c);
    printf("ok\n");
    return 0;
}
