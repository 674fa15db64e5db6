/* A plain C FMI 2.0 host for tests/fmu_tests/test_fmu_calls.py: no Python of its own. Run it with
 * libpython preloaded (LD_PRELOAD) so that the FMU binary finds the Python C API; the FMU then
 * starts the interpreter itself.
 *
 *   c_host LIBRARY RESOURCE_URI GUID VR_MASS VR_TRACTION VR_SPEED
 *
 * Prints one line per call: "<what> <status>" (and values), then "end". The last part
 * finalises the interpreter behind the FMU's back: the next call must return fmi2Fatal, and
 * freeing that instance must not crash.
 */
#define _POSIX_C_SOURCE 200809L
#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                   fmi2String category, fmi2String message, ...) {
    va_list ap;
    (void)env;
    printf("log [%d] %s %s: ", (int)status, name ? name : "?", category ? category : "-");
    va_start(ap, message);
    vprintf(message, ap);
    va_end(ap);
    printf("\n");
}

#define LOAD(name) name##TYPE *name = (name##TYPE *)dlsym(lib, #name)

int main(int argc, char **argv) {
    void *lib;
    fmi2CallbackFunctions cb = {logger, NULL, NULL, NULL, NULL};
    fmi2Component c;
    fmi2ValueReference mass, traction, speed;
    fmi2Real v, t = 0.0;
    int k, s, ok = 1;
    if (argc != 7) return 2;
    mass = (fmi2ValueReference)atoi(argv[4]);
    traction = (fmi2ValueReference)atoi(argv[5]);
    speed = (fmi2ValueReference)atoi(argv[6]);
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        printf("dlopen failed: %s\n", dlerror());
        return 3;
    }
    LOAD(fmi2Instantiate);
    LOAD(fmi2FreeInstance);
    LOAD(fmi2SetupExperiment);
    LOAD(fmi2EnterInitializationMode);
    LOAD(fmi2ExitInitializationMode);
    LOAD(fmi2Reset);
    LOAD(fmi2SetReal);
    LOAD(fmi2GetReal);
    LOAD(fmi2DoStep);

    c = fmi2Instantiate("c_host", fmi2CoSimulation, argv[3], argv[2], &cb, fmi2False, fmi2False);
    printf("instantiate %d\n", c != NULL);
    if (!c) return 4;

    /* a failed initialisation, then reset and a good one */
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    fmi2EnterInitializationMode(c);
    v = 0.0;
    fmi2SetReal(c, &mass, 1, &v);
    printf("bad-init %d\n", (int)fmi2ExitInitializationMode(c));
    printf("reset %d\n", (int)fmi2Reset(c));
    fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    fmi2EnterInitializationMode(c);
    v = 30e3;
    fmi2SetReal(c, &traction, 1, &v);
    printf("good-init %d\n", (int)fmi2ExitInitializationMode(c));
    for (k = 0; k < 10; k++, t += 0.1)
        if ((s = fmi2DoStep(c, t, 0.1, fmi2True)) != fmi2OK) ok = 0;
    s = fmi2GetReal(c, &speed, 1, &v);
    printf("steps %d speed %d %.17g\n", ok, s, v);
    fmi2FreeInstance(c);
    fmi2FreeInstance(c);               /* second free: nothing happens */
    printf("freed\n");

    /* the interpreter finalised by the host: the FMU can only say so (fmi2Fatal) */
    c = fmi2Instantiate("c_host2", fmi2CoSimulation, argv[3], argv[2], &cb, fmi2False, fmi2False);
    printf("instantiate2 %d\n", c != NULL);
    {
        typedef int ensure_t(void);
        typedef int finalize_t(void);
        ensure_t *ensure = (ensure_t *)dlsym(RTLD_DEFAULT, "PyGILState_Ensure");
        finalize_t *finalize = (finalize_t *)dlsym(RTLD_DEFAULT, "Py_FinalizeEx");
        if (ensure && finalize) {
            ensure();
            printf("finalize %d\n", finalize());
        }
    }
    printf("after-finalize %d\n", (int)fmi2SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0));
    fmi2FreeInstance(c);
    printf("end\n");
    return 0;
}
