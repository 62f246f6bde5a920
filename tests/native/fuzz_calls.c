/*
 * libFuzzer harness for the native FMU (tests/test_native.py::test_fuzzed_call_sequences...):
 * each fuzz input is read as a sequence of FMI 2.0 co-simulation calls on one instance of the
 * FMU, whose shipped sources are compiled in with it:
 *
 *   clang -fsanitize=fuzzer,address,undefined -I<sources> -I<FMI headers>
 *         -DLMNCELL_FUZZ_GUID='"<guid>"' fuzz_calls.c <sources>/lmncell.c -lm
 *
 * The calls: inputs and parameters set to any value (NaN, ±inf, ±1e300 and the bytes' own
 * doubles among them), steps of any size from any communication point, the observer,
 * temperature_is_cell and use_cell_temperature_start switches, set-up, initialisation, reset
 * and terminate in any order,
 * FMU states saved, restored, freed, and serialised with some of their bytes overwritten
 * before they are read back (the magic number kept, so that the state is taken).
 * Invariants, each a crash that libFuzzer reports: no sanitizer finding, and after a doStep
 * that returns fmi2OK or fmi2Warning every Real output is finite. At exit it prints how many
 * steps it made and how many of them were taken (the invariants' reach).
 */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

#ifndef LMNCELL_FUZZ_GUID
#error "give the FMU's GUID: -DLMNCELL_FUZZ_GUID='\"...\"'"
#endif

enum { VR_VOLTAGE = 3, VR_SOC, VR_SOC_STD, VR_OUT_OF_RANGE, VR_OBSERVER = 9,
       VR_TEMPERATURE_IS_CELL, VR_CELL_TEMPERATURE, VR_CELL_TEMPERATURE_START,
       VR_USE_CELL_TEMPERATURE_START, N_VR };
enum { N_SLOTS = 3 };

static long steps_made, steps_taken;

static void report(void) {
    fprintf(stderr, "fuzz_calls: %ld steps, %ld taken\n", steps_made, steps_taken);
}

static void quiet(fmi2ComponentEnvironment env, fmi2String name, fmi2Status status,
                  fmi2String category, fmi2String message, ...) {
    (void)env; (void)name; (void)status; (void)category; (void)message;
}

static const fmi2CallbackFunctions CALLBACKS = {quiet, calloc, free, NULL, NULL};

/* the fuzz input, read front to back; -1 once it is used up */
typedef struct { const uint8_t *p; size_t n; } Bytes;

static int next_byte(Bytes *b) {
    if (!b->n) return -1;
    b->n--;
    return *b->p++;
}

/* a value: one of a table of telling values times a small whole number, or the next 8 bytes
   as a double (any bit pattern: NaN, inf, subnormals) */
static double next_real(Bytes *b) {
    static const double telling[16] = {0.0, 1.0, -1.0, 0.1, 1e-9, 1e300, -1e300, 25.0, -20.0,
                                       2.5, 0.5, 3600.0, 1e-300, 60.0, -60.0, 100.0};
    int k = next_byte(b);
    double v;
    if (k < 0) return 0.0;
    if (k < 200) return telling[k % 16] * (k < 16 ? 1.0 : (double)(k / 16));
    if (b->n < sizeof v) return NAN;
    memcpy(&v, b->p, sizeof v);
    b->p += sizeof v;
    b->n -= sizeof v;
    return v;
}

/* abort (a finding) where a taken step left a non-finite Real output */
static void check_outputs(fmi2Component c) {
    static const fmi2ValueReference vr[] = {VR_VOLTAGE, VR_SOC, VR_SOC_STD, VR_CELL_TEMPERATURE};
    fmi2Real v[4];
    size_t k;
    if (fmi2GetReal(c, vr, 4, v) > fmi2Warning) {
        fprintf(stderr, "fmi2GetReal of the outputs failed after a taken step\n");
        abort();
    }
    for (k = 0; k < 4; k++)
        if (!isfinite(v[k])) {
            fprintf(stderr, "output %u is %g after a taken step\n", vr[k], v[k]);
            abort();
        }
}

static void step(fmi2Component c, Bytes *b, int op, double *t) {
    double h = next_real(b);
    fmi2Status s;
    if (op & 64) h = fabs(h);
    s = fmi2DoStep(c, *t, h, fmi2True);
    steps_made++;
    if (s == fmi2OK || s == fmi2Warning) {
        steps_taken++;
        check_outputs(c);
        *t += h;
    }
    if (op & 128) *t = next_real(b);    /* the host's next communication point, any */
}

/* a state serialised, some of its bytes overwritten (not the magic number), read back */
static void corrupt_state(fmi2Component c, Bytes *b, fmi2FMUstate from, fmi2FMUstate *to) {
    static fmi2Byte buf[1 << 17];
    size_t n = 0;
    int k, writes = next_byte(b) & 7;
    if (!from || fmi2SerializedFMUstateSize(c, from, &n) != fmi2OK || n > sizeof buf
        || fmi2SerializeFMUstate(c, from, buf, n) != fmi2OK)
        return;
    for (k = 0; k < writes; k++) {
        int hi = next_byte(b), lo = next_byte(b), value = next_byte(b);
        size_t at = (((size_t)(hi < 0 ? 0 : hi) << 8) | (size_t)(lo < 0 ? 0 : lo)) % n;
        if (at >= sizeof(unsigned)) buf[at] = (fmi2Byte)value;
    }
    fmi2DeSerializeFMUstate(c, buf, n, to);
}

int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size) {
    static int registered;
    Bytes b = {data, size};
    fmi2FMUstate states[N_SLOTS] = {NULL, NULL, NULL};
    fmi2Component c = fmi2Instantiate("fuzz", fmi2CoSimulation, LMNCELL_FUZZ_GUID,
                                      "file:///tmp", &CALLBACKS, fmi2False, fmi2True);
    double t = 0.0;
    int op, k;
    if (!c) abort();
    if (!registered) registered = !atexit(report);
    while ((op = next_byte(&b)) >= 0) {
        fmi2ValueReference vr = (fmi2ValueReference)(op >> 4) % N_VR;
        int slot = op % N_SLOTS;
        switch (op % 19) {
        case 0: case 1: case 2: {
            fmi2Real v = next_real(&b);
            fmi2SetReal(c, &vr, 1, &v);
            break;
        }
        case 3: case 4: case 5: case 6: step(c, &b, op, &t); break;
        case 7: fmi2SetupExperiment(c, fmi2False, 0.0, t = next_real(&b), fmi2False, 0.0); break;
        case 8: fmi2EnterInitializationMode(c); break;
        case 9: fmi2ExitInitializationMode(c); break;
        case 10: fmi2GetFMUstate(c, &states[slot]); break;
        case 11: fmi2SetFMUstate(c, states[slot]); break;
        case 12: fmi2FreeFMUstate(c, &states[slot]); break;
        case 13: corrupt_state(c, &b, states[slot], &states[(slot + 1) % N_SLOTS]); break;
        case 14: {
            fmi2ValueReference obs = VR_OBSERVER;
            fmi2Integer v = (fmi2Integer)(next_byte(&b) % 6) - 1;
            fmi2SetInteger(c, &obs, 1, &v);
            break;
        }
        case 15: {       /* temperature_is_cell or use_cell_temperature_start */
            int byte = next_byte(&b);
            fmi2ValueReference which = (byte & 2) ? VR_USE_CELL_TEMPERATURE_START
                                                  : VR_TEMPERATURE_IS_CELL;
            fmi2Boolean v = byte & 1;
            fmi2SetBoolean(c, &which, 1, &v);
            break;
        }
        case 16: {
            fmi2Real r;
            fmi2Integer i;
            fmi2Boolean z;
            fmi2GetReal(c, &vr, 1, &r);
            fmi2GetInteger(c, &vr, 1, &i);
            fmi2GetBoolean(c, &vr, 1, &z);
            fmi2GetRealStatus(c, fmi2LastSuccessfulTime, &r);
            break;
        }
        case 17: fmi2Reset(c); break;
        case 18: fmi2Terminate(c); break;
        }
    }
    for (k = 0; k < N_SLOTS; k++) fmi2FreeFMUstate(c, &states[k]);
    fmi2FreeInstance(c);
    return 0;
}
