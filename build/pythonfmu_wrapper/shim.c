/* LMNCell: the linux64 entry library of the pythonfmu FMU (binaries/linux64/<id>.so).
 *
 * pythonfmu's wrapper leaves Python's symbols to the host process (pythonfmu >= 0.7 does not
 * link libpython on Linux), so a host without Python (a C or C++ tool) cannot even load it:
 * "undefined symbol: _Py_NoneStruct". This library has no Python symbols. At the first
 * fmi2Instantiate it makes sure the process has a Python and then loads the wrapper, built
 * next to it as <id>_python.so, and forwards every FMI call to it:
 *   - a Python host (fmpy, libcosimpy, ...) already has one: nothing is loaded;
 *   - a libpython mapped but not global (a host that embeds Python privately) is made global;
 *   - otherwise $LMNCELL_LIBPYTHON if set (then only it; $PYTHONHOME as that Python needs),
 *     else the building Python's library (LMNCELL_LIBPYTHON_PATH, told its home
 *     LMNCELL_PYTHON_HOME), else its soname (LMNCELL_LIBPYTHON_SONAME) on the default search
 *     path, loaded RTLD_GLOBAL.
 * Where none can be loaded, fmi2Instantiate logs why (with what to do) and returns NULL.
 * fmi2GetVersion and fmi2GetTypesPlatform answer without Python. */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <link.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <wchar.h>

#include "fmi2Functions.h"

#ifndef LMNCELL_LIBPYTHON_PATH
#define LMNCELL_LIBPYTHON_PATH ""
#endif
#ifndef LMNCELL_LIBPYTHON_SONAME
#define LMNCELL_LIBPYTHON_SONAME ""
#endif
#ifndef LMNCELL_PYTHON_HOME /* the building Python's sys.base_prefix[:base_exec_prefix] */
#define LMNCELL_PYTHON_HOME ""
#endif
#define WIDE_(s) L##s
#define WIDE(s) WIDE_(s)
#ifndef LMNCELL_INNER
#define LMNCELL_INNER "LMNCell_python.so"
#endif
#ifndef LMNCELL_MIN_PYTHON /* the oldest Python the FMU's runtime runs on (MIN_HOST_PYTHON) */
#define LMNCELL_MIN_PYTHON "3.10"
#endif

#define FMI2_FUNCTIONS(X) \
    X(SetDebugLogging) X(Instantiate) X(FreeInstance) X(SetupExperiment) \
    X(EnterInitializationMode) X(ExitInitializationMode) X(Terminate) X(Reset) X(GetReal) \
    X(GetInteger) X(GetBoolean) X(GetString) X(SetReal) X(SetInteger) X(SetBoolean) X(SetString) \
    X(GetFMUstate) X(SetFMUstate) X(FreeFMUstate) X(SerializedFMUstateSize) X(SerializeFMUstate) \
    X(DeSerializeFMUstate) X(GetDirectionalDerivative) X(SetRealInputDerivatives) \
    X(GetRealOutputDerivatives) X(DoStep) X(CancelStep) X(GetStatus) X(GetRealStatus) \
    X(GetIntegerStatus) X(GetBooleanStatus) X(GetStringStatus)

#define FIELD(name) fmi2##name##TYPE *name;
static struct { FMI2_FUNCTIONS(FIELD) } inner;
static pthread_once_t load_once = PTHREAD_ONCE_INIT;
static int loaded;
static char why[8192];

static int find_mapped_libpython(struct dl_phdr_info *info, size_t size, void *data) {
    const char *base = strrchr(info->dlpi_name, '/');
    (void)size;
    base = base ? base + 1 : info->dlpi_name;
    if (strncmp(base, "libpython3", 10) == 0) {
        snprintf((char *)data, 1024, "%s", info->dlpi_name);
        return 1;
    }
    return 0;
}

/* The building Python's library, loaded here: tell it its home, which it would otherwise
 * derive from the first python3 on the host's PATH (perhaps another installation, whose standard
 * library then does not match: "No module named '_struct'"). $PYTHONHOME, where set, wins. */
static void set_home(void *lib) {
    static const wchar_t home[] = WIDE(LMNCELL_PYTHON_HOME);
    void (*set)(const wchar_t *) = (void (*)(const wchar_t *))dlsym(lib, "Py_SetPythonHome");
    if (home[0] && set && !getenv("PYTHONHOME")) set(home);
}

/* 1 when the process can resolve Python's symbols globally (loading libpython if needed). */
static int ensure_python(void) {
    char mapped[1024] = "";
    const char *env = getenv("LMNCELL_LIBPYTHON");
    const char *candidates[2] = {LMNCELL_LIBPYTHON_PATH, LMNCELL_LIBPYTHON_SONAME};
    size_t n = 0;
    if (dlsym(RTLD_DEFAULT, "Py_IsInitialized")) return 1;
    dl_iterate_phdr(find_mapped_libpython, mapped);
    if (mapped[0] && dlopen(mapped, RTLD_NOW | RTLD_GLOBAL | RTLD_NOLOAD)) return 1;
    if (env && env[0]) {
        if (dlopen(env, RTLD_NOW | RTLD_GLOBAL)) return 1;
        n = (size_t)snprintf(why, sizeof why, "LMNCELL_LIBPYTHON=%s cannot be loaded (%s)", env,
                             dlerror());
    } else {
        for (int k = 0; k < 2; k++) {
            void *lib;
            if (!candidates[k][0]) continue;
            if ((lib = dlopen(candidates[k], RTLD_NOW | RTLD_GLOBAL))) {
                if (k == 0) set_home(lib);
                return 1;
            }
            n += (size_t)snprintf(why + n, n < sizeof why ? sizeof why - n : 0, "%s%s", n ? "; " : "",
                                  dlerror());
        }
    }
    if (n < sizeof why)
        snprintf(why + n, sizeof why - n, ": this host has no Python. The FMU needs Python " LMNCELL_MIN_PYTHON
                 " or later with numpy: set LMNCELL_LIBPYTHON to that Python's libpython3.x.so and "
                 "PYTHONPATH to its site-packages, or use the native FMU (lmncell build-fmu "
                 "--native)");
    return 0;
}

static void load(void) {
    Dl_info self;
    char path[4096];
    void *lib;
    if (!ensure_python()) return;
    if (!dladdr((void *)&ensure_python, &self) || !self.dli_fname) {
        snprintf(why, sizeof why, "cannot locate the FMU's own library to find %s", LMNCELL_INNER);
        return;
    }
    snprintf(path, sizeof path, "%s", self.dli_fname);
    char *slash = strrchr(path, '/');
    snprintf(slash ? slash + 1 : path, sizeof path - (size_t)(slash ? slash + 1 - path : 0), "%s",
             LMNCELL_INNER);
    lib = dlopen(path, RTLD_NOW | RTLD_LOCAL);
    if (!lib) {
        snprintf(why, sizeof why, "cannot load the FMU's Python wrapper: %s", dlerror());
        return;
    }
#define RESOLVE(name)                                                                        \
    if (!(inner.name = (fmi2##name##TYPE *)dlsym(lib, "fmi2" #name))) {                      \
        snprintf(why, sizeof why, "%s has no fmi2" #name, path);                             \
        return;                                                                              \
    }
    FMI2_FUNCTIONS(RESOLVE)
    loaded = 1;
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    pthread_once(&load_once, load);
    if (!loaded) {
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, instanceName ? instanceName : "",
                              fmi2Error, "logStatusError", "%s", why);
        return NULL;
    }
    return inner.Instantiate(instanceName, fmuType, fmuGUID, fmuResourceLocation, functions,
                             visible, loggingOn);
}

/* Every other call takes an instance, which exists only once the wrapper is loaded. */
#define GUARD(c) if (!loaded || !(c)) return fmi2Error

void fmi2FreeInstance(fmi2Component c) {
    if (loaded && c) inner.FreeInstance(c);
}

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n,
                               const fmi2String categories[]) {
    GUARD(c);
    return inner.SetDebugLogging(c, on, n, categories);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    GUARD(c);
    return inner.SetupExperiment(c, toleranceDefined, tolerance, startTime, stopTimeDefined,
                                 stopTime);
}

#define FORWARD(name)                                                                        \
    fmi2Status fmi2##name(fmi2Component c) {                                                 \
        GUARD(c);                                                                            \
        return inner.name(c);                                                                \
    }
FORWARD(EnterInitializationMode)
FORWARD(ExitInitializationMode)
FORWARD(Terminate)
FORWARD(Reset)
FORWARD(CancelStep)

#define GET_SET(Kind, Type)                                                                  \
    fmi2Status fmi2Get##Kind(fmi2Component c, const fmi2ValueReference vr[], size_t n,      \
                             Type value[]) {                                                 \
        GUARD(c);                                                                            \
        return inner.Get##Kind(c, vr, n, value);                                             \
    }                                                                                        \
    fmi2Status fmi2Set##Kind(fmi2Component c, const fmi2ValueReference vr[], size_t n,      \
                             const Type value[]) {                                           \
        GUARD(c);                                                                            \
        return inner.Set##Kind(c, vr, n, value);                                             \
    }
GET_SET(Real, fmi2Real)
GET_SET(Integer, fmi2Integer)
GET_SET(Boolean, fmi2Boolean)
GET_SET(String, fmi2String)

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *state) {
    GUARD(c);
    return inner.GetFMUstate(c, state);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate state) {
    GUARD(c);
    return inner.SetFMUstate(c, state);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *state) {
    GUARD(c);
    return inner.FreeFMUstate(c, state);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate state, size_t *size) {
    GUARD(c);
    return inner.SerializedFMUstateSize(c, state, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate state, fmi2Byte bytes[],
                                 size_t size) {
    GUARD(c);
    return inner.SerializeFMUstate(c, state, bytes, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte bytes[], size_t size,
                                   fmi2FMUstate *state) {
    GUARD(c);
    return inner.DeSerializeFMUstate(c, bytes, size, state);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference unknown[],
                                        size_t nUnknown, const fmi2ValueReference known[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    GUARD(c);
    return inner.GetDirectionalDerivative(c, unknown, nUnknown, known, nKnown, dvKnown,
                                          dvUnknown);
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t n, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    GUARD(c);
    return inner.SetRealInputDerivatives(c, vr, n, order, value);
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t n, const fmi2Integer order[], fmi2Real value[]) {
    GUARD(c);
    return inner.GetRealOutputDerivatives(c, vr, n, order, value);
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    GUARD(c);
    return inner.DoStep(c, t, h, noSetPrior);
}

#define STATUS(Kind, Type)                                                                   \
    fmi2Status fmi2Get##Kind##Status(fmi2Component c, const fmi2StatusKind s, Type *value) { \
        GUARD(c);                                                                            \
        return inner.Get##Kind##Status(c, s, value);                                         \
    }
fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    GUARD(c);
    return inner.GetStatus(c, s, value);
}
STATUS(Real, fmi2Real)
STATUS(Integer, fmi2Integer)
STATUS(Boolean, fmi2Boolean)
STATUS(String, fmi2String)
