/* native_host_bench.c -- a plain C FMI 2.0 co-simulation host that times an extracted FMU
 * (benchmarks/native_benchmark.py compiles it with -O2 and runs it).
 *
 *   native_host_bench UNZIPDIR MODEL_ID GUID STEPS REPEAT IN_VRS REAL_VRS INT_VRS [PARAMS [CYCLE]]
 *
 * IN_VRS, REAL_VRS and INT_VRS are comma-separated value references: the three demand inputs
 * (traction, brake, wind), and every Real and Integer output. PARAMS, optional, sets parameters
 * before initialisation: comma-separated iVR=VALUE (Integer) or rVR=VALUE (Real), e.g.
 * "i32=0,r44=5" (a configuration other than the FMU's defaults; "" for none). CYCLE, optional,
 * repeats the demands every CYCLE seconds (e.g. 180: 20 s traction, coast, brake from 120 s to
 * a stop, 30 s standing), so that the car runs most of the time instead of standing after the
 * first 150 s (identification only works while the car moves). Each repeat instantiates the FMU
 * (UNZIPDIR/binaries/linux64/MODEL_ID.so, dlopen'ed once), initialises it and runs STEPS steps
 * of 0.1 s: fmi2SetReal of the inputs (benchmark.py's demands: traction 40 kN for 20 s, brake
 * 30 kN from 120 s to 150 s), fmi2DoStep, fmi2GetReal and fmi2GetInteger of all outputs. Only
 * the step loop is timed. Prints "steps_per_s <best> checksum <sum of outputs>" (the checksum
 * keeps the reads live). Exit 1 on any status other than fmi2OK. */
#define _POSIX_C_SOURCE 200809L
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>
#include <time.h>

#include "fmi2Functions.h"

#define STEP 0.1
#define MAX_VRS 256

static void logger(fmi2ComponentEnvironment env, fmi2String instance, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    va_list ap;
    (void)env;
    fprintf(stderr, "[%s %d %s] ", instance ? instance : "?", (int)status,
            category ? category : "");
    va_start(ap, message);
    vfprintf(stderr, message, ap);
    va_end(ap);
    fputc('\n', stderr);
}

static size_t parse_vrs(const char *s, fmi2ValueReference *out) {
    size_t n = 0;
    char *end;
    while (*s && n < MAX_VRS) {
        out[n++] = (fmi2ValueReference)strtoul(s, &end, 10);
        if (end == s) break;
        s = *end == ',' ? end + 1 : end;
    }
    return n;
}

/* Sets "iVR=V,rVR=V,..." on c; 0, or -1 on a malformed item or a refused value. */
static int set_parameters(const char *s, fmi2Component c, fmi2SetRealTYPE *set_real,
                          fmi2SetIntegerTYPE *set_integer) {
    while (*s) {
        char kind = *s++, *end;
        fmi2ValueReference vr = (fmi2ValueReference)strtoul(s, &end, 10);
        if ((kind != 'i' && kind != 'r') || end == s || *end != '=') {
            fprintf(stderr, "PARAMS: expected iVR=VALUE or rVR=VALUE at \"%s\"\n", s - 1);
            return -1;
        }
        s = end + 1;
        if (kind == 'r') {
            fmi2Real v = strtod(s, &end);
            if (end == s || set_real(c, &vr, 1, &v) != fmi2OK) return -1;
        } else {
            fmi2Integer v = (fmi2Integer)strtol(s, &end, 10);
            if (end == s || set_integer(c, &vr, 1, &v) != fmi2OK) return -1;
        }
        s = *end == ',' ? end + 1 : end;
    }
    return 0;
}

static double now(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

#define LOAD(name)                                                                  \
    name##TYPE *name;                                                               \
    sym = dlsym(lib, #name);                                                        \
    memcpy(&name, &sym, sizeof name); /* POSIX: a data pointer holds a function's */ \
    if (!sym) {                                                                     \
        fprintf(stderr, "missing %s\n", #name);                                     \
        return 1;                                                                   \
    }

#define CHECK(call)                                                                 \
    if ((call) != fmi2OK) {                                                         \
        fprintf(stderr, "%s failed\n", #call);                                      \
        return 1;                                                                   \
    }

int main(int argc, char **argv) {
    char path[4096], resources[4200];
    fmi2ValueReference in_vr[MAX_VRS], real_vr[MAX_VRS], int_vr[MAX_VRS];
    fmi2Real reals[MAX_VRS], inputs[3];
    fmi2Integer ints[MAX_VRS];
    size_t n_in, n_real, n_int, i;
    long steps, repeat, k, r;
    double best = 1e300, checksum = 0.0;
    void *lib, *sym;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};

    double cycle = argc == 11 ? atof(argv[10]) : 0.0;
    if (argc < 9 || argc > 11 || cycle < 0.0) {
        fprintf(stderr, "usage: %s UNZIPDIR MODEL_ID GUID STEPS REPEAT IN_VRS REAL_VRS INT_VRS"
                " [PARAMS [CYCLE]]\n",
                argv[0]);
        return 2;
    }
    snprintf(path, sizeof path, "%s/binaries/linux64/%s.so", argv[1], argv[2]);
    snprintf(resources, sizeof resources, "file://%s/resources", argv[1]);
    steps = atol(argv[4]);
    repeat = atol(argv[5]);
    n_in = parse_vrs(argv[6], in_vr);
    n_real = parse_vrs(argv[7], real_vr);
    n_int = parse_vrs(argv[8], int_vr);
    if (n_in != 3) {
        fprintf(stderr, "IN_VRS: three value references expected\n");
        return 2;
    }
    lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "dlopen %s: %s\n", path, dlerror());
        return 1;
    }
    {
        LOAD(fmi2Instantiate)
        LOAD(fmi2SetupExperiment)
        LOAD(fmi2EnterInitializationMode)
        LOAD(fmi2ExitInitializationMode)
        LOAD(fmi2SetReal)
        LOAD(fmi2SetInteger)
        LOAD(fmi2DoStep)
        LOAD(fmi2GetReal)
        LOAD(fmi2GetInteger)
        LOAD(fmi2Terminate)
        LOAD(fmi2FreeInstance)
        for (r = 0; r < repeat; r++) {
            double t0, dt;
            fmi2Component c = fmi2Instantiate("bench", fmi2CoSimulation, argv[3], resources, &cb,
                                              fmi2False, fmi2False);
            if (!c) {
                fprintf(stderr, "fmi2Instantiate failed\n");
                return 1;
            }
            if (argc >= 10 && set_parameters(argv[9], c, fmi2SetReal, fmi2SetInteger)) {
                fprintf(stderr, "setting PARAMS \"%s\" failed\n", argv[9]);
                return 1;
            }
            CHECK(fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0))
            CHECK(fmi2EnterInitializationMode(c))
            CHECK(fmi2ExitInitializationMode(c))
            t0 = now();
            for (k = 0; k < steps; k++) {
                double t = (double)k * STEP;
                double ts = cycle > 0.0 ? fmod(t, cycle) : t;   /* the schedule's time */
                inputs[0] = ts < 20.0 ? 40e3 : 0.0;
                inputs[1] = (120.0 < ts && ts < 150.0) ? 30e3 : 0.0;
                inputs[2] = 0.0;
                CHECK(fmi2SetReal(c, in_vr, n_in, inputs))
                CHECK(fmi2DoStep(c, t, STEP, fmi2True))
                CHECK(fmi2GetReal(c, real_vr, n_real, reals))
                CHECK(fmi2GetInteger(c, int_vr, n_int, ints))
                checksum += reals[0] + (double)ints[0];
            }
            dt = now() - t0;
            if (dt < best) best = dt;
            CHECK(fmi2Terminate(c))
            fmi2FreeInstance(c);
        }
    }
    for (i = 0; i < n_real; i++) checksum += reals[i];
    for (i = 0; i < n_int; i++) checksum += (double)ints[i];
    printf("steps_per_s %.1f checksum %.17g\n", (double)steps / best, checksum);
    dlclose(lib);
    return 0;
}
