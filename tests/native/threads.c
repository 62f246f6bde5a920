/* A native FMI 2.0 co-simulation host for the tests that runs N instances of one FMU at once, one
 * per thread (FMI 2.0 allows different instances to be called from different threads):
 * instance k steps 2000 s of 1 s at a constant current of -(1 + 0.5 k) A from the FMU's defaults
 * and prints its final voltage and the number of calls that did not return fmi2OK.
 * Usage: threads BINARY.so RESOURCE_URI GUID N   (1 <= N <= 16) */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>

#include "fmi2Functions.h"
#include "test_logger.h"

#define STEPS 2000

static void *lib;
static const char *resources, *guid;

#define LOAD(name) fmi2##name##TYPE *name = (fmi2##name##TYPE *)dlsym(lib, "fmi2" #name)

static void *run(void *arg) {
    long k = (long)arg;
    char name[16];
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2ValueReference vr_current = 0, vr_voltage = 3;
    double current = -1.0 - 0.5 * (double)k, voltage = 0.0;
    int failed = 0;
    LOAD(Instantiate);
    LOAD(SetupExperiment);
    LOAD(EnterInitializationMode);
    LOAD(ExitInitializationMode);
    LOAD(SetReal);
    LOAD(GetReal);
    LOAD(DoStep);
    LOAD(Terminate);
    LOAD(FreeInstance);
    snprintf(name, sizeof name, "i%ld", k);
    fmi2Component c = Instantiate(name, fmi2CoSimulation, guid, resources, &cb, fmi2False,
                                  fmi2False);
    if (!c) {
        printf("instance %ld failed\n", k);
        return NULL;
    }
    failed += SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0) != fmi2OK;
    failed += EnterInitializationMode(c) != fmi2OK;
    failed += ExitInitializationMode(c) != fmi2OK;
    for (int s = 0; s < STEPS; s++) {
        failed += SetReal(c, &vr_current, 1, &current) != fmi2OK;
        failed += DoStep(c, (double)s, 1.0, fmi2True) != fmi2OK;
    }
    failed += GetReal(c, &vr_voltage, 1, &voltage) != fmi2OK;
    failed += Terminate(c) != fmi2OK;
    FreeInstance(c);
    printf("instance %ld voltage %.17g failed %d\n", k, voltage, failed);
    return NULL;
}

int main(int argc, char **argv) {
    pthread_t threads[16];
    int n = argc > 4 ? atoi(argv[4]) : 0;
    if (n < 1 || n > 16) {
        fprintf(stderr, "usage: see source\n");
        return 2;
    }
    lib = dlopen(argv[1], RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        fprintf(stderr, "dlopen: %s\n", dlerror());
        return 2;
    }
    resources = argv[2];
    guid = argv[3];
    for (long k = 0; k < n; k++) pthread_create(&threads[k], NULL, run, (void *)k);
    for (long k = 0; k < n; k++) pthread_join(threads[k], NULL);
    return 0;
}
