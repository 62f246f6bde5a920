/* The FMI logger of the test hosts (host.c, threads.c): one line per message on stdout,
 * "LOG [instance] status category: text", the text formatted from the FMU's format and
 * arguments. */
#ifndef LMNCELL_TEST_LOGGER_H
#define LMNCELL_TEST_LOGGER_H

#include <stdarg.h>
#include <stdio.h>

#include "fmi2Functions.h"

static void logger(fmi2ComponentEnvironment env, fmi2String name, fmi2Status st, fmi2String cat,
                   fmi2String msg, ...) {
    va_list ap;
    (void)env;
    va_start(ap, msg);
    printf("LOG [%s] %d %s: ", name, (int)st, cat);
    vprintf(msg, ap);
    printf("\n");
    va_end(ap);
}

#endif
