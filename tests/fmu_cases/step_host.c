/* step_host: the smallest FMI 2.0 / FMI 3.0 co-simulation host that builds on Linux and on
 * Windows (mingw-w64; run under Wine in tests/fmu_tests/test_cross_platform.py). It loads a
 * native FMU's binary, steps it with constant real inputs and prints the real outputs after
 * initialisation and after every step as the hex bit patterns of the doubles (exact, and the
 * same text whichever C library prints it).
 *
 *   step_host fmi2|fmi3 BINARY RESOURCES TOKEN STEP N [VR=VALUE ...] -- OUTVR ...
 *
 *   RESOURCES  passed as it is: FMI 2's fmuResourceLocation (a file: URI) or FMI 3's
 *              resourcePath (a native path ending in the separator)
 *   TOKEN      the guid (FMI 2) or instantiationToken (FMI 3)
 *   STEP, N    N steps doStep(k STEP, STEP) from time 0
 *   VR=VALUE   a real input or parameter set before initialisation and before every step
 *   OUTVR      the value references of the real outputs to print
 *
 * Output: one line per row, "<k> <hex bits of output 1> ...". Exit status 0, or 2 on a failed
 * call (said on stderr with the FMU's messages), 3 on bad arguments or a library that will not
 * load.
 */
#if !defined(_WIN32)
#define _POSIX_C_SOURCE 200809L
#endif

#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef _WIN32
#define WIN32_LEAN_AND_MEAN
#include <windows.h>
typedef HMODULE library_t;
#else
#include <dlfcn.h>
typedef void *library_t;
#endif

#include "fmi2FunctionTypes.h"
#include "fmi3FunctionTypes.h"

#define MAX_VARS 64

static library_t library;

static void fail(int code, const char *fmt, ...) {
    va_list ap;
    va_start(ap, fmt);
    fputs("step_host: ", stderr);
    vfprintf(stderr, fmt, ap);
    fputc('\n', stderr);
    va_end(ap);
    exit(code);
}

/* The address of `name` in the binary, as a generic function pointer (copied, not cast, from
   the object pointer dlsym returns). */
typedef void (*any_function)(void);
static any_function symbol(const char *name) {
    any_function f = NULL;
#ifdef _WIN32
    FARPROC p = GetProcAddress(library, name);
    memcpy(&f, &p, sizeof f);
#else
    void *p = dlsym(library, name);
    memcpy(&f, &p, sizeof f);
#endif
    if (!f) fail(3, "the binary has no %s", name);
    return f;
}
#define RESOLVE(type, name) ((type)symbol(#name))

static void print_row(int k, const double *values, size_t n) {
    size_t i;
    printf("%d", k);
    for (i = 0; i < n; i++) {
        unsigned long long bits;
        memcpy(&bits, &values[i], sizeof bits);
        printf(" %016llx", bits);
    }
    printf("\n");
}

static void log_fmi2(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                 fmi2String category, fmi2String message, ...) {
    (void)env;
    fprintf(stderr, "step_host: [%s] %d %s: %s\n", instance, (int)status, category, message);
}

static void log_fmi3(fmi3InstanceEnvironment env, fmi3Status status, fmi3String category,
                 fmi3String message) {
    (void)env;
    fprintf(stderr, "step_host: %d %s: %s\n", (int)status, category, message);
}

static void check(int status, const char *call) {
    if (status > 1) fail(2, "%s returned %d", call, status);
}

int main(int argc, char **argv) {
    unsigned int in_vr[MAX_VARS], out_vr[MAX_VARS];
    double in_value[MAX_VARS], out_value[MAX_VARS];
    size_t n_in = 0, n_out = 0;
    double step;
    int n, k, a, fmi3;
    if (argc < 8) fail(3, "usage: step_host fmi2|fmi3 BINARY RESOURCES TOKEN STEP N [VR=VALUE ...] -- OUTVR ...");
    fmi3 = strcmp(argv[1], "fmi3") == 0;
    step = strtod(argv[5], NULL);
    n = atoi(argv[6]);
    for (a = 7; a < argc && strcmp(argv[a], "--") != 0; a++) {
        char *eq = strchr(argv[a], '=');
        if (!eq || n_in == MAX_VARS) fail(3, "bad input '%s'", argv[a]);
        in_vr[n_in] = (unsigned int)strtoul(argv[a], NULL, 10);
        in_value[n_in++] = strtod(eq + 1, NULL);
    }
    for (a++; a < argc && n_out < MAX_VARS; a++) out_vr[n_out++] = (unsigned int)strtoul(argv[a], NULL, 10);
    if (n_out == 0) fail(3, "no output value references after --");
#ifdef _WIN32
    library = LoadLibraryA(argv[2]);
    if (!library) fail(3, "%s: cannot load (error %lu)", argv[2], (unsigned long)GetLastError());
#else
    library = dlopen(argv[2], RTLD_NOW | RTLD_LOCAL);
    if (!library) fail(3, "%s: cannot load: %s", argv[2], dlerror());
#endif
    if (!fmi3) {
        fmi2CallbackFunctions callbacks = {log_fmi2, calloc, free, NULL, NULL};
        fmi2Component c = RESOLVE(fmi2InstantiateTYPE *, fmi2Instantiate)(
            "step_host", fmi2CoSimulation, argv[4], argv[3], &callbacks, fmi2False, fmi2False);
        fmi2SetRealTYPE *set = RESOLVE(fmi2SetRealTYPE *, fmi2SetReal);
        fmi2GetRealTYPE *get = RESOLVE(fmi2GetRealTYPE *, fmi2GetReal);
        fmi2DoStepTYPE *do_step = RESOLVE(fmi2DoStepTYPE *, fmi2DoStep);
        if (!c) fail(2, "fmi2Instantiate returned NULL");
        check(RESOLVE(fmi2SetupExperimentTYPE *, fmi2SetupExperiment)(c, fmi2False, 0.0, 0.0,
                                                                     fmi2False, 0.0),
              "fmi2SetupExperiment");
        check(RESOLVE(fmi2EnterInitializationModeTYPE *, fmi2EnterInitializationMode)(c),
              "fmi2EnterInitializationMode");
        check(set(c, in_vr, n_in, in_value), "fmi2SetReal");
        check(RESOLVE(fmi2ExitInitializationModeTYPE *, fmi2ExitInitializationMode)(c),
              "fmi2ExitInitializationMode");
        check(get(c, out_vr, n_out, out_value), "fmi2GetReal");
        print_row(0, out_value, n_out);
        for (k = 0; k < n; k++) {
            check(set(c, in_vr, n_in, in_value), "fmi2SetReal");
            check(do_step(c, k * step, step, fmi2True), "fmi2DoStep");
            check(get(c, out_vr, n_out, out_value), "fmi2GetReal");
            print_row(k + 1, out_value, n_out);
        }
        check(RESOLVE(fmi2TerminateTYPE *, fmi2Terminate)(c), "fmi2Terminate");
        RESOLVE(fmi2FreeInstanceTYPE *, fmi2FreeInstance)(c);
    } else {
        fmi3Instance c = RESOLVE(fmi3InstantiateCoSimulationTYPE *, fmi3InstantiateCoSimulation)(
            "step_host", argv[4], argv[3], fmi3False, fmi3False, fmi3False, fmi3False, NULL, 0,
            NULL, log_fmi3, NULL);
        fmi3SetFloat64TYPE *set = RESOLVE(fmi3SetFloat64TYPE *, fmi3SetFloat64);
        fmi3GetFloat64TYPE *get = RESOLVE(fmi3GetFloat64TYPE *, fmi3GetFloat64);
        fmi3DoStepTYPE *do_step = RESOLVE(fmi3DoStepTYPE *, fmi3DoStep);
        if (!c) fail(2, "fmi3InstantiateCoSimulation returned NULL");
        check(RESOLVE(fmi3EnterInitializationModeTYPE *, fmi3EnterInitializationMode)(
                  c, fmi3False, 0.0, 0.0, fmi3False, 0.0),
              "fmi3EnterInitializationMode");
        check(set(c, in_vr, n_in, in_value, n_in), "fmi3SetFloat64");
        check(RESOLVE(fmi3ExitInitializationModeTYPE *, fmi3ExitInitializationMode)(c),
              "fmi3ExitInitializationMode");
        check(get(c, out_vr, n_out, out_value, n_out), "fmi3GetFloat64");
        print_row(0, out_value, n_out);
        for (k = 0; k < n; k++) {
            fmi3Boolean event = fmi3False, terminate = fmi3False, early = fmi3False;
            fmi3Float64 last = 0.0;
            check(set(c, in_vr, n_in, in_value, n_in), "fmi3SetFloat64");
            check(do_step(c, k * step, step, fmi3True, &event, &terminate, &early, &last),
                  "fmi3DoStep");
            check(get(c, out_vr, n_out, out_value, n_out), "fmi3GetFloat64");
            print_row(k + 1, out_value, n_out);
        }
        check(RESOLVE(fmi3TerminateTYPE *, fmi3Terminate)(c), "fmi3Terminate");
        RESOLVE(fmi3FreeInstanceTYPE *, fmi3FreeInstance)(c);
    }
    return 0;
}
