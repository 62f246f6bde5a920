/* A minimal native FMI 2.0 co-simulation host for the tests: load the FMU binary, run a
 * drive cycle read from a text file (one current in A per line, held for one step of h s),
 * print the final voltage and SoC, and whether libpython is mapped into this process.
 * Usage: host BINARY RESOURCE_URI GUID CURRENTS.txt STEP_S SOC0 OBSERVER VOLTAGES.txt|-
 * With HOST_PRIVATE_LIB=path set it first maps that library RTLD_LOCAL (as a host that embeds
 * Python for itself). Built for Linux (dlopen, BINARY.so) and for Windows (LoadLibrary,
 * BINARY.dll: the win64 binary under Wine; libpython is then reported as -1). */
#ifdef _WIN32
#include <windows.h>
#else
#define _POSIX_C_SOURCE 199309L
#include <dlfcn.h>
#include <time.h>
#endif
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "test_logger.h"

#ifdef _WIN32
typedef HMODULE Library;
#define open_library(path) LoadLibraryA(path)
#define symbol(lib, name) ((void *)GetProcAddress(lib, name))
#define close_library(lib) FreeLibrary(lib)
static double seconds(void) {
    LARGE_INTEGER now, freq;
    QueryPerformanceCounter(&now);
    QueryPerformanceFrequency(&freq);
    return (double)now.QuadPart / (double)freq.QuadPart;
}
static int libpython_mapped(void) { return -1; }
#else
typedef void *Library;
#define open_library(path) dlopen(path, RTLD_NOW | RTLD_LOCAL)
#define symbol(lib, name) dlsym(lib, name)
#define close_library(lib) dlclose(lib)
static double seconds(void) {
    struct timespec now;
    clock_gettime(CLOCK_MONOTONIC, &now);
    return now.tv_sec + 1e-9 * now.tv_nsec;
}
static int libpython_mapped(void) {
    char line[1024];
    int found = 0;
    FILE *f = fopen("/proc/self/maps", "r");
    if (!f) return -1;
    while (fgets(line, sizeof line, f))
        if (strstr(line, "libpython")) found = 1;
    fclose(f);
    return found;
}
#endif

#define LOAD(name) fmi2##name##TYPE *name = (fmi2##name##TYPE *)symbol(lib, "fmi2" #name); \
    if (!name) { fprintf(stderr, "missing fmi2" #name "\n"); return 2; }

int main(int argc, char **argv) {
    Library lib;
    fmi2CallbackFunctions cb = {logger, calloc, free, NULL, NULL};
    fmi2ValueReference vr_in[] = {0, 1}, vr_out[] = {3, 4, 5}, vr_soc0 = 7, vr_obs = 9;
    double h, soc0, out[3], cur, volt = 0.0, t = 0.0;
    int observer, steps = 0, errors = 0;
    FILE *fc, *fv = NULL;
    fmi2Component c;
    if (argc < 9) { fprintf(stderr, "usage: see source\n"); return 2; }
    if (getenv("HOST_PRIVATE_LIB")) {   /* a library the host maps for itself, not global */
        if (!open_library(getenv("HOST_PRIVATE_LIB"))) {
            fprintf(stderr, "cannot load %s\n", getenv("HOST_PRIVATE_LIB"));
            return 2;
        }
    }
    lib = open_library(argv[1]);
    if (!lib) { fprintf(stderr, "cannot load %s\n", argv[1]); return 2; }
    LOAD(Instantiate) LOAD(SetupExperiment) LOAD(EnterInitializationMode)
    LOAD(ExitInitializationMode) LOAD(SetReal) LOAD(SetInteger) LOAD(GetReal) LOAD(DoStep)
    LOAD(Terminate) LOAD(FreeInstance)
    h = atof(argv[5]);
    soc0 = atof(argv[6]);
    observer = atoi(argv[7]);
    c = Instantiate("host", fmi2CoSimulation, argv[3], argv[2], &cb, fmi2False, fmi2True);
    if (!c) { fprintf(stderr, "instantiate failed\n"); return 2; }
    SetupExperiment(c, fmi2False, 0.0, 0.0, fmi2False, 0.0);
    EnterInitializationMode(c);
    SetReal(c, &vr_soc0, 1, &soc0);
    SetInteger(c, &vr_obs, 1, &observer);
    if (ExitInitializationMode(c) != fmi2OK) { fprintf(stderr, "init failed\n"); return 2; }
    fc = fopen(argv[4], "r");
    if (strcmp(argv[8], "-") != 0) fv = fopen(argv[8], "r");
    {
        /* read the inputs first, so that the timed loop only sets, steps and gets */
        size_t cap = 1024, n = 0, k;
        double *ci = malloc(cap * sizeof *ci), *vi = malloc(cap * sizeof *vi), elapsed, t0;
        while (fscanf(fc, "%lf", &cur) == 1) {
            if (fv && fscanf(fv, "%lf", &volt) != 1) volt = 0.0;
            if (n == cap) {
                cap *= 2;
                ci = realloc(ci, cap * sizeof *ci);
                vi = realloc(vi, cap * sizeof *vi);
            }
            ci[n] = cur;
            vi[n++] = volt;
        }
        t0 = seconds();
        for (k = 0; k < n; k++) {
            double in[2];
            in[0] = ci[k];
            in[1] = vi[k];
            SetReal(c, vr_in, 2, in);
            if (DoStep(c, t, h, fmi2True) != fmi2OK) errors++; /* refused: time stays */
            else t += h;
            GetReal(c, vr_out, 3, out);
            steps++;
        }
        elapsed = seconds() - t0;
        printf("us_per_step %.4f\n", n ? 1e6 * elapsed / n : 0.0);
        free(ci);
        free(vi);
    }
    GetReal(c, vr_out, 3, out);
    Terminate(c);
    FreeInstance(c);
    fclose(fc);
    if (fv) fclose(fv);
    printf("steps %d errors %d voltage %.17g soc %.17g soc_std %.17g libpython %d\n", steps,
           errors, out[0], out[1], out[2], libpython_mapped());
    close_library(lib);
    return 0;
}
