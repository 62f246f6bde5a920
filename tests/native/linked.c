/* dlopen, dlsym and dlclose for host.c linked statically with the FMU's C (lmncell.c) in one
 * executable, where no dynamic loader is at hand (an arm64 build run under qemu-aarch64):
 * "loading" the FMU binary finds the fmi2 functions host.c asks for among those linked in. */
#include <string.h>

#include "fmi2Functions.h"

void *dlopen(const char *path, int flags) {
    (void)path;
    (void)flags;
    return (void *)1;
}

int dlclose(void *lib) {
    (void)lib;
    return 0;
}

#define LINKED(name) {"fmi2" #name, (void *)fmi2##name}
static const struct {
    const char *name;
    void *function;
} linked[] = {LINKED(DoStep), LINKED(EnterInitializationMode), LINKED(ExitInitializationMode),
              LINKED(FreeInstance), LINKED(GetReal), LINKED(Instantiate), LINKED(SetInteger),
              LINKED(SetReal), LINKED(SetupExperiment), LINKED(Terminate)};

void *dlsym(void *lib, const char *name) {
    (void)lib;
    for (size_t k = 0; k < sizeof linked / sizeof *linked; k++)
        if (strcmp(linked[k].name, name) == 0) return linked[k].function;
    return NULL;
}
