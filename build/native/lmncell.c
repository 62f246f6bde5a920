/*
 * LMNCell native FMU: FMI 2.0 co-simulation in plain C (no Python needed on the importing side).
 *
 * The model's numbers come from lmncell_model.h, generated from the model file. The code follows
 * the Python runtime step by step, so that both give the same numbers:
 *   - exo_update / features / blend / stepper_step  <->  fmu_src/step.py (ExoStepper, CellStepper)
 *   - cell_temperature / thermal_update              <->  fmu_src/step.py (CellThermal), thermal.py
 *   - cosim_advance / model_step / check_range       <->  fmu_src/cosim.py (CellCosim)
 *   - observer_step and friends                      <->  fmu_src/observers.py (SocObserver)
 * Conventions: SI units, current > 0 charges the cell, SoC as a fraction.
 */
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "lmncell_model.h"

/* A linux64 binary that loads on older Linux hosts too: glibc 2.29 (2019) gave exp, exp2, log,
   log2 and pow a new symbol version (the same results; only the SVID error-handling wrapper
   dropped), which a binary built on a newer system requires by default, so that it would not
   load where glibc is older (RHEL 8: 2.28, CentOS 7: 2.17). Bind the x86-64 baseline ones
   where LMNCell's build asks for it (-DLMNCELL_GLIBC_BASELINE, linking libm: a versioned
   symbol must be found at link time; a rebuild on the host itself, fmpy compile, needs none). */
#if defined(LMNCELL_GLIBC_BASELINE) && defined(__linux__) && defined(__x86_64__) && \
    defined(__GLIBC__)
__asm__(".symver exp,exp@GLIBC_2.2.5");
__asm__(".symver exp2,exp2@GLIBC_2.2.5");
__asm__(".symver log,log@GLIBC_2.2.5");
__asm__(".symver log2,log2@GLIBC_2.2.5");
__asm__(".symver pow,pow@GLIBC_2.2.5");
#endif

/* value references: the same as the pythonfmu FMU */
enum { VR_CURRENT = 0, VR_VOLTAGE_MEASURED, VR_TEMPERATURE, VR_VOLTAGE, VR_SOC, VR_SOC_STD,
       VR_OUT_OF_RANGE, VR_SOC0, VR_CAPACITY, VR_OBSERVER, VR_TEMPERATURE_IS_CELL,
       VR_CELL_TEMPERATURE, VR_CELL_TEMPERATURE_START, VR_USE_CELL_TEMPERATURE_START };

#define CHARGE 1
#define DISCHARGE 2
#define STEP_TOL 1e-9
#define EXTRAPOLATION_K 10.0     /* observers.EXTRAPOLATION_K */
#define GATE_V 0.5
#define NX (1 + NLX + HAS_HYSTERESIS) /* EKF state: SoC, low-pass states (NLX), h */
#define STATE_MAGIC 0x4C4D4E39u /* "LMN9" (LMN8 before the preview, LMN7 before the
                                      current delay's window, LMN6
                                      before one EKF state per distinct low-pass
                                      time constant, LMN5 before ob_hist, LMN4 before
                                      dep_source, LMN3 before the innovation RMS) */

/* A 'capacity' parameter (Ah) the FMU takes: finite, within CAPACITY_MIN_AH...CAPACITY_MAX_AH
   (the generated header's, model.CAPACITY_RANGE_AH; the pythonfmu FMU's is_cell_capacity). */
static int is_cell_capacity(double ah) {
    return isfinite(ah) && ah >= CAPACITY_MIN_AH && ah <= CAPACITY_MAX_AH;
}

/* A 'soc0' parameter the FMU takes: a fraction within 0...1 (NaN is not). */
static int is_soc_fraction(double soc) { return soc >= 0.0 && soc <= 1.0; }

/* An 'observer' parameter the FMU takes: 0 none, 1 EKF, 2 fuzzy, 3 IMM. */
static int is_observer(int observer) { return observer >= 0 && observer <= 3; }

/* ----- the whole simulation state (copied by get/set FMU state) ----------------------------- */
typedef struct {
    unsigned magic;
    /* inputs and parameters */
    double current, voltage_measured, temperature, soc0, capacity;
    int observer, temperature_is_cell;
    double t_start;                            /* cell_temperature_start (degC) */
    int use_t_start;                           /* use_cell_temperature_start */
    int initialized;
    double time;                               /* the FMU's time: where the next step starts */
    /* thermal state (step.CellThermal): cell temperature at the next step's start */
    double t_cell, t_last_input;
    int t_cell_set;
    /* exogenous state (runtime.ExoState) */
    double soc, lp[2 * NF + 1], h, past[NB + 1];
    double core;                               /* LP_τ(i²) of the core rise (ExoState.core) */
    int direction;
    /* the filter coefficients at the last step's temperature (ExoStepper.coefficients_at) */
    double coef_t, coef[2 * NF + 1];
    /* network state (runtime.CellStepper) */
    double lags[NA + 1], prev_lags[NA + 1], voltage;
    int d;
    /* co-simulation accumulators (cosim.CellCosim) */
    double covered, charge, temp_int, volt_int, volt_time;
    /* the current delay's window, DELAY_S earlier than the model step's (cosim.CellCosim):
       covered time, charge (NAN until the first input fills its start) and the last closed
       window's mean current */
    double d_covered, d_charge, d_current;
    int out_of_range, steps;
    /* the voltage now while a model step is partly covered, without an observer
       (cosim.CellCosim._preview): the step in progress taken on a copy */
    double preview;
    int preview_on;
    /* observer (observers.SocObserver) */
    double q, r, ob_soc, ob_var, ob_floor;
    double ob_innov_ms, ob_innov_w;            /* innovations' weighted mean square (V²), weights */
    double ob_hist[NLX + 1];                   /* fuzzy, IMM: the low-pass states' remaining
                                                  spread from the unknown load history (A) */
    int ob_hist_on;                            /* ob_hist still counted (ObserverState.history) */
    int skipped;
    double ob_p[NX][NX];                       /* EKF covariance of [SoC, lp…, h] */
    double ob_i, ob_t, ob_past[NB + 1];        /* the step's current, temperature, past currents */
    double mode_soc[NM], mode_var[NM], mode_prob[NM];   /* IMM only */
    /* what a step refused after the fact (fmi2DoStep) need not restore (state_kept): the
       fuzzy gains, fixed at initialisation, and the last step's working values, each
       recomputed by stepper_step before any use */
    double fuzzy_gain[NM];
    double x[NEXO + 1], z[ND + 1];
    double phi[NM], local[NM];                 /* the step's validities and local outputs */
    double act[NNODES + 1], ex[NNODES + 1];    /* the step's node activations and e^−act */
    double dep_source[2];                      /* the step's g(T)·LP_τ(i) of d(k), d2(k) */
} State;

/* the leading bytes of a State that a step can change (the IMM's modes with the IMM only) */
static size_t state_kept(const State *s) {
    return s->observer == 3 ? offsetof(State, fuzzy_gain) : offsetof(State, mode_soc);
}

/* FMI 2.0 co-simulation states (the standard's state machine) */
enum { MODE_INSTANTIATED, MODE_INITIALIZATION, MODE_STEP, MODE_TERMINATED };

typedef struct {
    State s;
    const fmi2CallbackFunctions *cb;
    char name[128];
    int logging;
    int mode;
    /* the last out-of-range model step's inputs, for the warning fmi2DoStep logs (its
       voltage is the state's: the warning follows only a doStep whose last step was out) */
    int range_inputs;
    double range_i, range_t, range_soc;
    /* fmi2SetupExperiment's stop time (s) where the host defined one: no step may end past
       it (FMI 2.0 asks fmi2Error there); cleared by fmi2Reset */
    int stop_defined;
    double stop_time;
    /* the FMU states this instance handed out (fmi2GetFMUstate, fmi2DeSerializeFMUstate) and
       not yet freed: only these are taken back, and fmi2FreeInstance frees what is left */
    State **states;
    size_t n_states, cap_states;
} Instance;

static void logf_(Instance *in, fmi2Status st, const char *cat, const char *fmt, ...) {
    char buf[512];
    va_list ap;
    if (!in || !in->cb || !in->cb->logger) return;
    /* warnings and discards only with logging on */
    if ((st == fmi2Warning || st == fmi2Discard) && !in->logging) return;
    va_start(ap, fmt);
    vsnprintf(buf, sizeof buf, fmt, ap);
    va_end(ap);
    in->cb->logger(in->cb->componentEnvironment, in->name, st, cat, "%s", buf);
}

/* ----- model functions ------------------------------------------------------------------------ */
/* the knot interval [OCV_SOC[k], OCV_SOC[k + 1]) that holds soc, OCV_SOC[0] < soc <
   OCV_SOC[NOCV − 1]: a guess as if the knots were even, moved to the first k with
   soc < OCV_SOC[k + 1] (what a scan from the left finds, for any knots; O(1) for even ones) */
static int ocv_interval(double soc) {
    double at = (soc - OCV_SOC[0]) / (OCV_SOC[NOCV - 1] - OCV_SOC[0]) * (NOCV - 1);
    int k = at < 0.0 ? 0 : (at > NOCV - 2 ? NOCV - 2 : (int)at);
    while (k > 0 && soc < OCV_SOC[k]) k--;
    while (k < NOCV - 2 && soc >= OCV_SOC[k + 1]) k++;
    return k;
}

static double ocv(double soc) { /* numpy.interp: linear, held beyond the ends */
    int k;
    if (!(soc > OCV_SOC[0])) return OCV_V[0]; /* NaN too: never index past the table */
    if (soc >= OCV_SOC[NOCV - 1]) return OCV_V[NOCV - 1];
    k = ocv_interval(soc);
    return OCV_V[k] + (OCV_V[k + 1] - OCV_V[k]) * (soc - OCV_SOC[k]) / (OCV_SOC[k + 1] - OCV_SOC[k]);
}

/* exp(E·c·(1/(T − T0) − 1/(T_ref − T0))), c = ((T_ref − T0)/T_ref)², at t (°C): the
   Arrhenius (T0 = 0) or Vogel–Tammann–Fulcher gain with E, the time constants' factor with Eτ
   (step.arrhenius_factor, the same operations in the same order) */
static double arrhenius_factor(double t, double e_k) {
    const double t_ref = REF_TEMPERATURE_C + 273.15 - ACTIVATION_T0_K;
    const double ratio = t_ref / (REF_TEMPERATURE_C + 273.15);
    const double scale = e_k * (ratio * ratio);
    return exp(scale * (1.0 / (t + 273.15 - ACTIVATION_T0_K) - 1.0 / t_ref));
}

static double temperature_gain(double t) {
#if HAS_ARRHENIUS
    return arrhenius_factor(t, ARRHENIUS_K);
#else
    (void)t;
    return 1.0;
#endif
}

static double eta(double i) { return i > 0 ? ETA_CHARGE : ETA_DISCHARGE; }

/* the depletion regressor's SoC factor (soc_scale/max(SoC, soc_min))^power (model.Depletion) */
static double depletion_factor(double soc) {
    double q = DEP_SOC_SCALE / (soc >= DEP_SOC_MIN ? soc : DEP_SOC_MIN);
#if DEP_INTEGER_POWER          /* repeated multiplication, as model.Depletion.factor */
    double out = 1.0;
    int k;
    for (k = 0; k < DEP_INTEGER_POWER; k++) out *= q;
    return out;
#else
    return pow(q, DEP_POWER);
#endif
}

static void exo_init(State *s, double soc0, double h0) {
    int k;
    s->soc = soc0;
    for (k = 0; k < 2 * NF + 1; k++) {
        s->lp[k] = 0.0;
        s->coef[k] = LP_COEF[k];
    }
    s->coef_t = NAN;
    s->h = h0;
    s->core = 0.0;
    s->direction = INITIAL_DIRECTION;
    for (k = 0; k < NB + 1; k++) s->past[k] = 0.0;
}

static double initial_hysteresis(double soc0) { return soc0 >= 0.95 ? 1.0 : 0.0; }

/* the filter coefficients at temperature t (step.filter_coefficients), kept while t stays */
static const double *filter_coefficients(State *s, double t) {
#if HAS_TAU_ACTIVATION
    int k;
    if (!(t == s->coef_t)) {
        double kf = arrhenius_factor(t, TAU_ACTIVATION_K);
        for (k = 0; k < 2 * NF; k++) s->coef[k] = exp(-TS / (LP_TAU[k] * kf));
        s->coef_t = t;
    }
    return s->coef;
#else
    (void)s;
    (void)t;
    return LP_COEF;
#endif
}

/* the temperature the step's temperature-dependent parts take: the cell temperature t plus
   the core rise (ExoStepper.lmn_temperature) */
static double lmn_temperature(const State *s, double t) {
#if HAS_CORE_RISE
    return t + CORE_RISE_K * s->core;
#else
    (void)s;
    return t;
#endif
}

static void exo_update(State *s, double i, double t, double cap) {
    int k;
    double gain = TS / (3600.0 * cap);
    const double *coef;
#if HAS_CORE_RISE
    s->core = CORE_RISE_A * s->core + (1.0 - CORE_RISE_A) * i * i;
#endif
    coef = filter_coefficients(s, lmn_temperature(s, t));
    s->soc += gain * eta(i) * i;
    for (k = 0; k < 2 * NF; k++) s->lp[k] = coef[k] * s->lp[k] + (1.0 - coef[k]) * i;
#if HAS_HYSTERESIS
    {
        double e = exp(-HYSTERESIS_GAMMA * fabs(i) * gain);
        s->h = e * s->h + (1.0 - e) * (i > 0 ? 1.0 : (i < 0 ? -1.0 : 0.0));
    }
#endif
    if (i > REST_CURRENT_A) s->direction = CHARGE;
    else if (i < -REST_CURRENT_A) s->direction = DISCHARGE;
}

/* LmnModel.activation_step: dA of "arrhenius" hysteresis terms from the gain g = g(t), else
   the step's dT as given */
static double activation_step(double dt, double g) {
#if HYSTERESIS_ARRHENIUS
    double t_ref = REF_TEMPERATURE_C + 273.15;
    (void)dt;
    return (1.0 - g) * (t_ref * t_ref / (ARRHENIUS_K * TEMPERATURE_STEP_K));
#else
    (void)g;
    return dt;
#endif
}

static void features(const State *s, double i, double t_cell, double *x, double *z,
                     double *dep_source) {
    int col = 0, k;
    double t = lmn_temperature(s, t_cell);
    double g = temperature_gain(t);
    x[col++] = g * i;
    for (k = 0; k < NB - 1; k++) x[col++] = g * s->past[k];
    for (k = 0; k < NF; k++) x[col++] = g * (s->lp[2 * k] - s->lp[2 * k + 1]);
#if HAS_HYSTERESIS
    x[col++] = s->h;
#endif
#if HAS_DEPLETION
    {   /* what ExoStepper.features returns: g·LP_τ of d(k) (and of d2(k)) */
        double factor = depletion_factor(s->soc);
        double source = g * s->lp[DEP_STATE];
        if (dep_source) dep_source[0] = source;
        x[col++] = source * factor;
#if HAS_DEPLETION2
        source = g * s->lp[DEP2_STATE];
        if (dep_source) dep_source[1] = source;
        x[col++] = source * factor;
#endif
    }
#else
    (void)dep_source;
#endif
#if OCV_INPUT
    x[col++] = ocv(s->soc);
#endif
#if SOC_INPUT
    x[col++] = s->soc;
#endif
#if OFFSET
    x[col++] = 1.0;
#endif
#if TEMPERATURE_TERMS > 0
    {
        double dt = (t - REF_TEMPERATURE_C) / TEMPERATURE_STEP_K, power = 1.0;
        double da = activation_step(dt, g), power_a = 1.0;
        int n, c;
        for (n = 0; n < TEMPERATURE_TERMS; n++) {
            power *= dt;
            power_a *= da;
            for (c = 0; c < NTSRC; c++)
                x[col++] = (TSRC_IN_DA[c] ? power_a : power) * x[TSRC_COL[c]];
        }
    }
#endif
    (void)col;
    for (k = 0; k < ND; k++) {
        switch (PART_VAR[k]) {
        case 0: z[k] = s->soc; break;
        case 1: z[k] = i; break;
        case 2: z[k] = NF > 0 ? s->lp[1] : i; break;
        default: z[k] = t; break;
        }
    }
}

static void shift_past(State *s, double i) {
    int k;
    for (k = NB - 2; k > 0; k--) s->past[k] = s->past[k - 1];
    if (NB > 1) s->past[0] = i;
}

/* the nodes' activations act, e^−act and sigmoids q = 1/(1 + e^−act) (by node index) for raw
   partition inputs z */
static void node_activations(const double *z_raw, double *act, double *ex, double *q) {
    double zn[ND + 1];
    int k, n;
    for (k = 0; k < ND; k++) zn[k] = (z_raw[k] - PART_CENTER[k]) / PART_SCALE[k];
    for (n = 0; n < NNODES; n++) {
        double a = NODE_W[n][0];
        for (k = 0; k < ND; k++) a += zn[k] * NODE_W[n][k + 1];
        act[n] = a;
        ex[n] = exp(-a);
        q[n] = 1.0 / (1.0 + ex[n]);
    }
}

/* the tree's slots (runtime.step._OneSample.combine) from the nodes' sigmoids q: slot 0 holds
   a root's validity, 1; node n, parents first, writes its sides v·q_n and v − v·q_n into
   slots 1 + 2n and 2 + 2n, v being the value in its parent's slot */
static void tree_slots(const double *q, double *v) {
    int k;
    v[0] = 1.0;
    for (k = 0; k < NNODES; k++) {
        int n = TREE_NODE[k];
        double parent = v[TREE_INTO[k]], side = parent * q[n];
        v[1 + 2 * n] = side;
        v[2 + 2 * n] = parent - side;
    }
}

/* each leaf's validity: its slot, 0 where a current-sign gate does not match the direction d */
static void leaf_validities(const double *v, int d, double *phi) {
    int j;
    for (j = 0; j < NM; j++) {
#if GATING_CURRENT_SIGN
        phi[j] = LEAF_GATE[j] != 0 && LEAF_GATE[j] != d ? 0.0 : v[LEAF_SLOT[j]];
#else
        (void)d;
        phi[j] = v[LEAF_SLOT[j]];
#endif
    }
}

/* validities Φ (runtime: LmnModel.validities) for raw partition inputs z and direction d */
static void validities(const double *z_raw, int d, double *phi) {
    double act[NNODES + 1], ex[NNODES + 1], v[NSLOTS], q[NNODES + 1];
    node_activations(z_raw, act, ex, q);
    tree_slots(q, v);
    leaf_validities(v, d, phi);
}

/* per-local-model outputs (exogenous and lag parts) for given features and lags */
static void local_outputs(const double *x, const double *lags, double *local) {
    int j, c;
    for (j = 0; j < NM; j++) {
        double acc = 0.0;
        for (c = 0; c < NEXO; c++) acc += x[c] * THETA[j][NA + c];
        for (c = 0; c < NA; c++) acc += THETA[j][c] * lags[c];
        local[j] = acc;
    }
}

/* per-local-model outputs and blended network output for given features and lags */
static double network(const double *x, const double *z, int d, const double *lags,
                      double *phi, double *local) {
    double out = 0.0;
    int j;
    validities(z, d, phi);
    local_outputs(x, lags, local);
    for (j = 0; j < NM; j++) out += phi[j] * local[j];
    return out;
}

static double fixed_point(double soc0, double t, double h0) {
    State tmp;
    double phi[NM], a = 0.0, b;
    int j, c;
    exo_init(&tmp, soc0, h0);
    features(&tmp, 0.0, t, tmp.x, tmp.z, NULL);
    validities(tmp.z, tmp.direction, phi);
    b = 0.0;
    for (j = 0; j < NM; j++) {
        double acc = 0.0;
        for (c = 0; c < NEXO; c++) acc += tmp.x[c] * THETA[j][NA + c];
        b += phi[j] * acc;
        for (c = 0; c < NA; c++) a += phi[j] * THETA[j][c];
    }
    return fabs(1.0 - a) > 1e-9 ? b / (1.0 - a) : 0.0;
}

static void stepper_init(State *s, double soc0, double t) {
    int k;
    double h0 = initial_hysteresis(soc0), y0;
    exo_init(s, soc0, h0);
    y0 = fixed_point(soc0, t, h0);
    for (k = 0; k < NA + 1; k++) s->lags[k] = s->prev_lags[k] = y0;
    s->voltage = RELATIVE_OCV ? ocv(soc0) + y0 : y0;
    for (k = 0; k < NEXO + 1; k++) s->x[k] = 0.0;
    for (k = 0; k < ND + 1; k++) s->z[k] = 0.0;
    s->d = s->direction;
}

static void stepper_step(State *s, double i, double t) {
    double y, slots[NSLOTS], q[NNODES + 1];    /* the tree's slots and the nodes' sigmoids */
    int k;
    exo_update(s, i, t, s->capacity);
    features(s, i, t, s->x, s->z, s->dep_source);
    shift_past(s, i);
    s->d = s->direction;
    for (k = 0; k < NA; k++) s->prev_lags[k] = s->lags[k];
    node_activations(s->z, s->act, s->ex, q);
    tree_slots(q, slots);
    leaf_validities(slots, s->d, s->phi);
    local_outputs(s->x, s->prev_lags, s->local);
    for (y = 0.0, k = 0; k < NM; k++) y += s->phi[k] * s->local[k];
    for (k = NA - 1; k > 0; k--) s->lags[k] = s->lags[k - 1];
    if (NA > 0) s->lags[0] = y;
    s->voltage = RELATIVE_OCV ? y + ocv(s->soc) : y;
}

/* ----- observers ------------------------------------------------------------------------------ */
static double clip01(double v) { return v < 0.0 ? 0.0 : (v > 1.0 ? 1.0 : v); }

/* network voltage and per-local-model voltages for the step just predicted, with
   xi = [SoC, lp…, h] (its first nxi entries) replacing the stepper's states
   (observers.SocObserver._outputs_for) */
static double outputs_for(const State *s, const double *xi, int nxi, double *phi, double *uj) {
    State tmp;
    double x[NEXO + 1], z[ND + 1], local[NM], base, u;
    int k;
    tmp.soc = xi[0];
    for (k = 0; k < 2 * NF + 1; k++)
        tmp.lp[k] = (nxi > 1 && k < 2 * NF) ? xi[1 + SLOT_LX[k]] : s->lp[k];
    tmp.h = nxi > 1 + NLX ? xi[1 + NLX] : s->h;
    tmp.core = s->core;
    for (k = 0; k < NB + 1; k++) tmp.past[k] = s->ob_past[k];
    features(&tmp, s->ob_i, s->ob_t, x, z, NULL);
    u = network(x, z, s->d, s->prev_lags, phi, local);
    base = RELATIVE_OCV ? ocv(xi[0]) : 0.0;
    for (k = 0; k < NM; k++) uj[k] = base + local[k];
    return base + u;
}

/* each local model's output (exogenous and lag parts) at another SoC: the step's own unless
   SoC is among the regressors (runtime.CellStepper.local_voltages_at_socs) */
static const double *locals_at(const State *s, double soc, double *local) {
#if HAS_DEPLETION && !OCV_INPUT && !SOC_INPUT
    /* only d(k) (and d2(k)) depend on SoC: the step's local outputs moved along them */
    double factor = depletion_factor(soc);
    double dx = s->dep_source[0] * factor - s->x[DEP_COL];
    double dx2 = HAS_DEPLETION2 ? s->dep_source[1] * factor - s->x[DEP2_COL] : 0.0;
    int j;
    (void)dx2;
    for (j = 0; j < NM; j++) {
        local[j] = s->local[j] + THETA[j][NA + DEP_COL] * dx;
#if HAS_DEPLETION2
        local[j] += THETA[j][NA + DEP2_COL] * dx2;
#endif
    }
    return local;
#elif OCV_INPUT || SOC_INPUT || HAS_DEPLETION
    double x[NEXO + 1];
    memcpy(x, s->x, sizeof x);
#if OCV_INPUT
    x[OCV_COL] = ocv(soc);
#endif
#if SOC_INPUT
    x[SOC_COL] = soc;
#endif
#if HAS_DEPLETION
    x[DEP_COL] = s->dep_source[0] * depletion_factor(soc);
#endif
#if HAS_DEPLETION2
    x[DEP2_COL] = s->dep_source[1] * depletion_factor(soc);
#endif
    local_outputs(x, s->prev_lags, local);
    return local;
#else
    (void)soc;
    (void)local;
    return s->local;
#endif
}

/* the validities of the step's partition inputs with the SoC replaced */
static void validities_at(const State *s, double soc, double *phi) {
    double z[ND + 1];
    int k;
    memcpy(z, s->z, sizeof z);
    for (k = 0; k < ND; k++)
        if (PART_VAR[k] == 0) z[k] = soc;
    validities(z, s->d, phi);
}

/* the same at another SoC alone, from the step's own regressors and partition inputs with only
   the SoC entries replaced (runtime.CellStepper.outputs_at_socs); no features recomputed */
static double outputs_at(const State *s, double soc, double *phi, double *uj) {
    double buf[NM], base = RELATIVE_OCV ? ocv(soc) : 0.0, u = 0.0;
    const double *local = locals_at(s, soc, buf);
    int k;
    validities_at(s, soc, phi);
    for (k = 0; k < NM; k++) {
        u += phi[k] * local[k];
        uj[k] = base + local[k];
    }
    return base + u;
}

/* each local model's voltage at another SoC (the uj of outputs_at without the validities) */
static void local_voltages_at(const State *s, double soc, double *uj) {
    double buf[NM], base = RELATIVE_OCV ? ocv(soc) : 0.0;
    const double *local = locals_at(s, soc, buf);
    int k;
    for (k = 0; k < NM; k++) uj[k] = base + local[k];
}

/* EKF (observers.SocObserver._ekf_predict / _ekf_update) */
/* the step's voltage at SoC hi = SoC + dh and lo = SoC − dl (its own SoC ± the EKF's spread,
   dh, dl ≥ 0, as computed by the caller) as outputs_at gives them, the validities from the
   step's own nodes: e^−act moved by e^∓∂act/∂SoC·d, one exp per node for both sides when
   dh = dl, φ_lo = m/(m + e^−act) with m = e^−∂act/∂SoC·d; recomputed where a product is not a
   number (an infinite e^−act times 0) */
static void outputs_beside(const State *s, double hi, double lo, double dh, double dl,
                           double *uh, double *ul) {
    double qh[NNODES + 1], ql[NNODES + 1], vh[NSLOTS], vl[NSLOTS], phi_h[NM], phi_l[NM];
    double bh[NM], bl[NM], sum_h = 0.0, sum_l = 0.0;
    const double *loc_h = locals_at(s, hi, bh), *loc_l = locals_at(s, lo, bl);
    int j, n;
    for (n = 0; n < NNODES; n++) {
        double w = NODE_SOC_W[n], ex = s->ex[n];
        double move = w != 0.0 ? exp(-w * dh) : 1.0;   /* a node without SoC: e^0 = 1 */
        qh[n] = 1.0 / (1.0 + ex * move);
        if (qh[n] != qh[n]) qh[n] = 1.0 / (1.0 + exp(-(s->act[n] + w * dh)));
        ql[n] = dl == dh || w == 0.0 ? move / (move + ex) : 1.0 / (1.0 + ex * exp(w * dl));
        if (ql[n] != ql[n]) ql[n] = 1.0 / (1.0 + exp(-(s->act[n] - w * dl)));
    }
    tree_slots(qh, vh);
    tree_slots(ql, vl);
    leaf_validities(vh, s->d, phi_h);
    leaf_validities(vl, s->d, phi_l);
    for (j = 0; j < NM; j++) {
        sum_h += phi_h[j] * loc_h[j];
        sum_l += phi_l[j] * loc_l[j];
    }
    *uh = RELATIVE_OCV ? ocv(hi) + sum_h : sum_h;
    *ul = RELATIVE_OCV ? ocv(lo) + sum_l : sum_l;
}

static void ekf_init(State *s) {
    int a, b;
    for (a = 0; a < NX; a++)
        for (b = 0; b < NX; b++)
            s->ob_p[a][b] = (a >= 1 && a < 1 + NLX && b >= 1 && b < 1 + NLX)
                                ? HISTORY_CURRENT_SIGMA_A * HISTORY_CURRENT_SIGMA_A : 0.0;
    s->ob_p[0][0] = SOC0_SIGMA * SOC0_SIGMA;
#if HAS_HYSTERESIS
    s->ob_p[NX - 1][NX - 1] = s->h == 0.0 ? HYST_PRIOR_UNKNOWN : HYST_PRIOR_ASSUMED;
#endif
}

static void ekf_predict(State *s, double i) {
    double f[NX], g[NX], gain = TS / (3600.0 * s->capacity);
    int a, b;
    f[0] = 1.0;
    g[0] = gain * eta(i);
    for (a = 0; a < NLX; a++) {
        f[1 + a] = LP_COEF[LX_SLOT[a]];
        g[1 + a] = 1.0 - LP_COEF[LX_SLOT[a]];
    }
#if HAS_HYSTERESIS
    f[NX - 1] = exp(-HYSTERESIS_GAMMA * fabs(i) * gain);
    g[NX - 1] = 0.0;
#endif
    for (a = 0; a < NX; a++)   /* (f_a·f_b)·P_ab + σ²·g_a·g_b, F diagonal: P stays symmetric */
        for (b = a; b < NX; b++) {
            double p = (f[a] * f[b]) * s->ob_p[a][b]
                       + CURRENT_SIGMA_A * CURRENT_SIGMA_A * (g[a] * g[b]);
            s->ob_p[a][b] = p;
            s->ob_p[b][a] = p;
        }
    s->ob_p[0][0] += EKF_DRIFT_PER_SQRT_H * EKF_DRIFT_PER_SQRT_H * TS / 3600.0;
#if HAS_HYSTERESIS
    s->ob_p[NX - 1][NX - 1] += HYST_DRIFT_PER_SQRT_H * HYST_DRIFT_PER_SQRT_H * TS / 3600.0;
#endif
    s->ob_var = s->ob_p[0][0];
}

/* network voltage with xi[a] moved by delta (SoC kept in [0, 1]); *at: the moved value */
static double output_moved(const State *s, const double *xi, int a, double delta, double *at) {
    double row[NX], phi[NM], uj[NM];
    memcpy(row, xi, sizeof row);
    row[0] = clip01(xi[0]);         /* around the clipped SoC: beyond 0 or 1 both sides clip */
    row[a] += delta;
    row[0] = clip01(row[0]);
    *at = row[a];
    return outputs_for(s, row, NX, phi, uj);
}

/* SocObserver._regressor_gradient: ∂u/∂state for the states after SoC (hv[1 … NX − 1]) through
   the regressors they enter, at the validities phi and SoC soc and the step's temperature */
static void regressor_gradient(const State *s, const double *phi, double soc, double *hv) {
    double t = lmn_temperature(s, s->ob_t);
    double blended[NEXO + 1], g = temperature_gain(t);
    double dt = (t - REF_TEMPERATURE_C) / TEMPERATURE_STEP_K;
    double da = activation_step(dt, g);   /* the unscaled columns are h's */
    int a, c, j, m, p;
    for (m = 0; m < NGRADCOL; m++) {       /* only the columns read below */
        c = GRAD_COL[m];
        blended[c] = 0.0;
        for (j = 0; j < NM; j++) blended[c] += phi[j] * THETA[j][NA + c];
    }
    for (a = 1; a < NX; a++) {
        double acc = 0.0;
        for (m = 0; m < STATE_NCOL[a]; m++) {
            double power = 1.0;
            for (p = 0; p < STATE_POW[a][m]; p++) power *= STATE_SCALED[a][m] ? dt : da;
            acc += STATE_SIGN[a][m] * (STATE_SCALED[a][m] ? g : 1.0) * power
                   * blended[STATE_COL[a][m]];
        }
        hv[a] = acc;
    }
#if HAS_DEPLETION   /* d = g·LP_τ·factor(SoC): ∂d/∂LP_τ = g·factor */
    hv[1 + DEP_LX] += blended[DEP_COL] * g * depletion_factor(soc);
#if HAS_DEPLETION2
    hv[1 + DEP2_LX] += blended[DEP2_COL] * g * depletion_factor(soc);
#endif
#else
    (void)soc;
#endif
}

/* ObserverSettings.model_error_at: σ_m (V) at a SoC, numpy.interp of the training error */
static double model_error_at(double soc) {
    int k;
    if (!(soc > MERR_SOC[0])) return MERR_V[0];
    if (soc >= MERR_SOC[NMERR - 1]) return MERR_V[NMERR - 1];
    for (k = 0; k < NMERR - 1; k++)
        if (soc < MERR_SOC[k + 1]) break;
    return MERR_V[k] + (MERR_V[k + 1] - MERR_V[k]) * (soc - MERR_SOC[k]) / (MERR_SOC[k + 1] - MERR_SOC[k]);
}

/* runtime.step.interp_one: numpy.interp for one value (xs increasing), held beyond the ends */
static double interp_one(double x, const double *xs, const double *ys, int n) {
    int k;
    if (!(x > xs[0])) return x == x ? ys[0] : x;
    if (x >= xs[n - 1]) return ys[n - 1];
    for (k = 0; k < n - 2; k++)
        if (x < xs[k + 1]) break;
    return (ys[k + 1] - ys[k]) / (xs[k + 1] - xs[k]) * (x - xs[k]) + ys[k];
}

/* ObserverSettings.measurement_variance: r (V²) of the EKF or of an IMM mode filter at a SoC */
static double measurement_variance(const State *s, double soc) {
#if HAS_VSIG
    double sig = interp_one(soc, VSIG_SOC, VSIG_V, NVSIG);
    return pow((s->observer == 1 ? EKF_ERROR_SCALE_BY_SOC : IMM_ERROR_SCALE) * sig, 2);
#else
    (void)soc;
    return s->r;
#endif
}

/* SocObserver._model_error: the training error at a SoC (times SocObserver._extrapolation
   beyond the trained temperatures), or the recent innovations' RMS; for
   the fuzzy observer and the IMM in quadrature with the voltage of the load history's spread */
static double model_error(const State *s, double soc) {
    double beyond = T_MIN - s->ob_t > s->ob_t - T_MAX ? T_MIN - s->ob_t : s->ob_t - T_MAX;
    double trained = model_error_at(soc) * (1.0 + (beyond > 0.0 ? beyond : 0.0) / EXTRAPOLATION_K);
    double recent = sqrt(s->ob_innov_ms);
    double err = recent > trained ? recent : trained;
    if (s->ob_hist_on) {
        double hv[NX + 1], uh = 0.0;
        int a;
        regressor_gradient(s, s->phi, soc, hv);
        for (a = 0; a < NLX; a++) uh += hv[1 + a] * s->ob_hist[a];
        err = sqrt(err * err + uh * uh);
    }
    return err;
}

/* SocObserver._track_innovation: exponentially weighted mean square, normalised by the weights */
static void track_innovation(State *s, double innovation) {
#if INNOVATION_ON
    s->ob_innov_w = INNOVATION_DECAY * s->ob_innov_w + 1.0;
    s->ob_innov_ms += (innovation * innovation - s->ob_innov_ms) / s->ob_innov_w;
#else
    (void)s;
    (void)innovation;
#endif
}

/* observers.soc_variance_floor: (σ_m/|∂u/∂SoC|)², at most 1 */
static double soc_variance_floor(double err, double slope) {
    double m = fabs(slope) > 1e-6 ? fabs(slope) : 1e-6, f;
    if (err <= 0.0) return 0.0;
    f = (err / m) * (err / m);
    return f < 1.0 ? f : 1.0;
}

/* observers.first_crossing: walking from (x0, y0) through the OCV knots k = from, from + step,
   …, the first SoC where the curve reaches target; end if it never does */
static double first_crossing(double x0, double y0, double target, int from, int step,
                             double end) {
    int rising = target > y0, k;
    for (k = from; k >= 0 && k < NOCV; k += step) {
        double x1 = OCV_SOC[k], y1 = OCV_V[k];
        if (rising ? y1 >= target : y1 <= target)
            return x0 + (x1 - x0) * (target - y0) / (y1 - y0);
        x0 = x1;
        y0 = y1;
    }
    return end;
}

/* observers.ocv_interval_sigma: half the SoC interval over which the OCV moves by ±err */
static double ocv_interval_sigma(double soc, double err) {
    int right, left, k;
    double u0;
    if (!(err > 0.0)) return 0.0;
    u0 = ocv(soc);
    for (k = 0; k < NOCV && OCV_SOC[k] < soc; k++) {}   /* the knots ascend: bisect_left */
    left = k;
    for (; k < NOCV && OCV_SOC[k] <= soc; k++) {}       /* bisect_right */
    right = k;
    return 0.5 * (first_crossing(soc, u0, u0 + err, right, 1, 1.0) -
                  first_crossing(soc, u0, u0 - err, left - 1, -1, 0.0));
}

/* SocObserver._variance_floor: σ_m over the slope, at least the OCV interval's spread */
static double variance_floor(const State *s, double soc, double slope) {
    double err = model_error(s, soc);
    double by_slope = soc_variance_floor(err, slope), spread = ocv_interval_sigma(soc, err);
    spread *= spread;
    return spread > by_slope ? spread : by_slope;
}

static double ekf_update(State *s, double v) {
    double xi[NX], hv[NX], ph[NX], k[NX];
    double phi[NM], uj[NM], u, hph = 0.0, innov, spread, curvature = 0.0, r, soc_prior;
    double inv_s;
    int a, b;
    xi[0] = s->soc;
    for (a = 0; a < NLX; a++) xi[1 + a] = s->lp[LX_SLOT[a]];
#if HAS_HYSTERESIS
    xi[NX - 1] = s->h;
#endif
    soc_prior = clip01(xi[0]);
    /* the base point at the clipped SoC (observers.SocObserver._jacobian): the step's own */
    if (soc_prior == s->soc) {
        u = s->voltage;
        memcpy(phi, s->phi, sizeof phi);
    } else {
        u = outputs_at(s, soc_prior, phi, uj);
    }
    /* SoC column: the secant over ±σ, δ² added to r; it also sets the variance floor */
    spread = sqrt(s->ob_p[0][0] > 0.0 ? s->ob_p[0][0] : 0.0);
    if (spread > SPREAD_MAX) spread = SPREAD_MAX;
    if (spread < FD_SOC) spread = FD_SOC;
    {
        double phi2[NM], uj2[NM], uh, ul;
        double hi = soc_prior + spread < 1.0 ? soc_prior + spread : 1.0;
        double lo = soc_prior - spread > 0.0 ? soc_prior - spread : 0.0;
        if (soc_prior == s->soc) {    /* the step's own nodes moved along SoC */
            outputs_beside(s, hi, lo, hi < 1.0 ? spread : 1.0 - soc_prior,
                           lo > 0.0 ? spread : soc_prior, &uh, &ul);
        } else {
            uh = outputs_at(s, hi, phi2, uj2);
            ul = outputs_at(s, lo, phi2, uj2);
        }
        hv[0] = (uh - ul) / (hi - lo);
        curvature = 0.5 * (uh + ul) - u;
    }
    /* the other states: through the regressors only (the validities do not depend on them),
       so their columns are ∂x/∂state times the blended coefficients at ξ (state_gradient) */
    {
#if LINEAR_STATES
        regressor_gradient(s, phi, soc_prior, hv);
#else
        for (a = 1; a < NX; a++) {
            double step = (HAS_HYSTERESIS && a == NX - 1) ? FD_HYSTERESIS : FD_CURRENT_A;
            double hi, lo, uh = output_moved(s, xi, a, step, &hi), ul;
            ul = output_moved(s, xi, a, -step, &lo);
            hv[a] = (uh - ul) / (2.0 * step);
        }
#endif
    }
    r = measurement_variance(s, soc_prior) + curvature * curvature;
    for (a = 0; a < NX; a++) {
        ph[a] = 0.0;
        for (b = 0; b < NX; b++) ph[a] += s->ob_p[a][b] * hv[b];
    }
    for (a = 0; a < NX; a++) hph += hv[a] * ph[a];
    innov = v - u;
    inv_s = 1.0 / (hph + r);
    for (a = 0; a < NX; a++) {
        k[a] = ph[a] * inv_s;
        xi[a] += k[a] * innov;
    }
    /* P − P·h·hᵀ·P/(hᵀPh + r): the Joseph form's value for this optimal gain, in O(n²);
       (Ph_a·Ph_b)·(1/s) keeps the symmetric P of the prediction symmetric, each pair once */
    for (a = 0; a < NX; a++)
        for (b = a; b < NX; b++) {
            double sym = s->ob_p[a][b] - (ph[a] * ph[b]) * inv_s;
            s->ob_p[a][b] = sym;
            s->ob_p[b][a] = sym;
        }
    s->ob_floor = variance_floor(s, soc_prior, hv[0]);
    s->ob_var = s->ob_p[0][0] > 1e-12 ? s->ob_p[0][0] : 1e-12;
    for (a = 0; a < 2 * NF; a++) s->lp[a] = xi[1 + SLOT_LX[a]];
#if HAS_HYSTERESIS
    s->h = xi[NX - 1] < -1.0 ? -1.0 : (xi[NX - 1] > 1.0 ? 1.0 : xi[NX - 1]);
#endif
    return xi[0];
}

static void fuzzy_design(State *s) {
    int j;
    for (j = 0; j < NM; j++) {
        double c = fabs(LOCAL_SLOPE[j]) > 1e-6 ? LOCAL_SLOPE[j] : 1e-6;
        double p = 0.5 * (s->q + sqrt(s->q * s->q + 4.0 * s->q * s->r / (c * c)));
        double k = p * c / (c * c * p + s->r);
        s->fuzzy_gain[j] = k;
    }
}

static void observer_init(State *s, double soc0) {
    int j;
    double var0 = SOC0_SIGMA * SOC0_SIGMA;
    double drift = s->observer == 1 ? EKF_DRIFT_PER_SQRT_H : SOC_ONLY_DRIFT_PER_SQRT_H;
    s->q = pow(CURRENT_SIGMA_A * TS / (3600.0 * s->capacity), 2) + drift * drift * TS / 3600.0;
    s->r = s->observer == 1   ? pow(VOLTAGE_SIGMA_V * EKF_ERROR_SCALE, 2)
           : s->observer == 3 ? pow(VOLTAGE_SIGMA_V * IMM_ERROR_SCALE, 2)
                              : VOLTAGE_SIGMA_V * VOLTAGE_SIGMA_V;
    s->ob_soc = soc0;
    s->ob_var = var0;
    s->ob_floor = 0.0;
    s->ob_innov_ms = 0.0;
    s->ob_innov_w = 0.0;
    s->ob_hist_on = s->observer != 1 && HISTORY_CURRENT_SIGMA_A > 0.0;
    for (j = 0; j < NLX; j++) s->ob_hist[j] = s->ob_hist_on ? HISTORY_CURRENT_SIGMA_A : 0.0;
    s->skipped = 0;
    for (j = 0; j < NM; j++) {
        s->mode_soc[j] = soc0;
        s->mode_var[j] = var0;
        s->mode_prob[j] = 1.0 / NM;
    }
    fuzzy_design(s);
    ekf_init(s);
}

static void imm_predict(State *s, double dsoc) {
    double trans[NM][NM], c[NM], x0[NM], p0[NM];
    int i, j;
    double p = IMM_STAY;
    for (i = 0; i < NM; i++)
        for (j = 0; j < NM; j++)
            trans[i][j] = (i == j) ? (NM > 1 ? p : 1.0) : (1.0 - p) / (NM > 1 ? NM - 1 : 1);
    for (j = 0; j < NM; j++) {
        c[j] = 0.0;
        for (i = 0; i < NM; i++) c[j] += trans[i][j] * s->mode_prob[i];
        if (c[j] < 1e-300) c[j] = 1e-300;
    }
    for (j = 0; j < NM; j++) {
        x0[j] = 0.0;
        for (i = 0; i < NM; i++) x0[j] += trans[i][j] * s->mode_prob[i] / c[j] * s->mode_soc[i];
    }
    for (j = 0; j < NM; j++) {
        p0[j] = 0.0;
        for (i = 0; i < NM; i++) {
            double dx = s->mode_soc[i] - x0[j];
            p0[j] += trans[i][j] * s->mode_prob[i] / c[j] * (s->mode_var[i] + dx * dx);
        }
    }
    for (j = 0; j < NM; j++) {
        s->mode_soc[j] = x0[j] + dsoc;
        s->mode_var[j] = p0[j] + s->q;
        s->mode_prob[j] = c[j];
    }
}

static double imm_update(State *s, double v) {
    double phi[NM], uj[NM], ujh[NM], ujl[NM], lik[NM], slopes[NM], sum = 0.0, x = 0.0;
    double var = 0.0, slope = 0.0;
    int j;
    for (j = 0; j < NM; j++) {
        double xs = clip01(s->mode_soc[j]);
        double hi = xs + FD_SOC < 1.0 ? xs + FD_SOC : 1.0, lo = xs - FD_SOC > 0.0 ? xs - FD_SOC : 0.0;
        double hj, sj, k, innov;
        double unet = outputs_at(s, xs, phi, uj);
        local_voltages_at(s, hi, ujh);
        local_voltages_at(s, lo, ujl);
        hj = (ujh[j] - ujl[j]) / (hi - lo);
        /* the local model's disagreement with the network counts as its measurement error */
        sj = hj * hj * s->mode_var[j] + measurement_variance(s, xs)
             + (unet - uj[j]) * (unet - uj[j]);
        k = s->mode_var[j] * hj / sj;
        innov = v - uj[j];
        s->mode_soc[j] = clip01(s->mode_soc[j] + k * innov);
        s->mode_var[j] = (1.0 - k * hj) * s->mode_var[j];
        if (s->mode_var[j] < 1e-12) s->mode_var[j] = 1e-12;
        slopes[j] = hj;
        lik[j] = exp(-0.5 * innov * innov / sj) / sqrt(2.0 * M_PI * sj);
    }
    for (j = 0; j < NM; j++) sum += s->mode_prob[j] * lik[j];
    for (j = 0; j < NM; j++) s->mode_prob[j] = sum > 0 ? s->mode_prob[j] * lik[j] / sum : 1.0 / NM;
    for (j = 0; j < NM; j++) x += s->mode_prob[j] * s->mode_soc[j];
    for (j = 0; j < NM; j++) {
        double dx = s->mode_soc[j] - x;
        var += s->mode_prob[j] * (s->mode_var[j] + dx * dx);
        slope += s->mode_prob[j] * slopes[j];
    }
    s->ob_var = var;
    s->ob_floor = variance_floor(s, x, slope);
    return x;
}

static void observer_step(State *s, double i, double v, double t) {
    double soc;
    int valid;
    double before = s->ob_soc;
    int k;
    s->ob_i = i;
    s->ob_t = t;
    for (k = 0; k < NB + 1; k++) s->ob_past[k] = s->past[k];
    stepper_step(s, i, t);
    if (s->ob_hist_on) {   /* SocObserver.step: decay, emptied below HISTORY_FORGOTTEN_A */
        double most = 0.0;
        for (k = 0; k < NLX; k++) {
            s->ob_hist[k] *= LP_COEF[LX_SLOT[k]];
            if (s->ob_hist[k] > most) most = s->ob_hist[k];
        }
        if (most < HISTORY_FORGOTTEN_A) s->ob_hist_on = 0;
    }
    if (s->observer == 1) ekf_predict(s, i);
    else s->ob_var += s->q;
    if (s->observer == 3) imm_predict(s, s->soc - before);
    valid = isfinite(v) && v >= V_MIN - GATE_V && v <= V_MAX + GATE_V;
    if (!valid) {
        s->skipped++;
        s->ob_soc = clip01(s->soc);
        s->soc = s->ob_soc;
        return;
    }
    soc = s->soc;
    track_innovation(s, v - s->voltage);
    if (s->observer == 1) {
        soc = ekf_update(s, v);
    } else if (s->observer == 2) {
        /* at the step's own SoC: its voltage and validities; fixed-gain variance,
           observers.fixed_gain_variance */
        double u = s->voltage, kk = 0.0, slope = 0.0, c;
        int j;
        for (j = 0; j < NM; j++) {
            kk += s->phi[j] * s->fuzzy_gain[j];
            slope += s->phi[j] * LOCAL_SLOPE[j];
        }
        c = fabs(slope) > 1e-6 ? slope : 1e-6;
        soc += kk * (v - u);
        s->ob_var = (1.0 - kk * c) * (1.0 - kk * c) * s->ob_var + kk * kk * s->r;
        s->ob_floor = variance_floor(s, s->soc, slope);
    } else {
        soc = imm_update(s, v);
    }
    s->ob_soc = clip01(soc);
    s->soc = s->ob_soc;
}

/* ----- co-simulation engine (cosim.CellCosim) --------------------------------------------------- */
/* CellCosim.check_range: which of the step's current, SoC and temperature lie outside the
   trained region (with its margins: cosim.trained_bounds), as OUT_* bits; 0 inside */
enum { OUT_CURRENT = 1, OUT_SOC = 2, OUT_TEMPERATURE = 4 };

static int inputs_out_of_range(double i, double t, double soc) {
    int out = 0;
    if (i < I_MIN - CURRENT_MARGIN * fabs(I_MIN) - CURRENT_MARGIN_A
        || i > I_MAX + CURRENT_MARGIN * fabs(I_MAX) + CURRENT_MARGIN_A) out |= OUT_CURRENT;
    if (soc < SOC_MIN - SOC_MARGIN || soc > SOC_MAX + SOC_MARGIN) out |= OUT_SOC;
#if HAS_TEMPERATURE_RANGE
    if (t < T_MIN - T_MARGIN || t > T_MAX + T_MARGIN) out |= OUT_TEMPERATURE;
#else
    (void)t;
#endif
    return out;
}

/* CellCosim.check_voltage: 1 when the model's voltage leaves the trained voltage range by
   more than V_MARGIN (not within it: NaN too) */
static int voltage_out_of_range(double v) {
    return !(v >= V_MIN - V_MARGIN && v <= V_MAX + V_MARGIN);
}

/* buf (size bytes, n of them used) with "; " and a formatted part appended (the parts of an
   out-of-range message); returns the bytes used, at most size - 1 (a long one is cut) */
static size_t append_part(char *buf, size_t n, size_t size, const char *fmt, ...) {
    va_list ap;
    int k;
    if (n > 0 && n + 2 < size) {
        memcpy(buf + n, "; ", 3);
        n += 2;
    }
    if (n + 1 >= size) return size - 1;
    va_start(ap, fmt);
    k = vsnprintf(buf + n, size - n, fmt, ap);
    va_end(ap);
    n += k > 0 ? (size_t)k : 0;
    return n < size ? n : size - 1;
}

/* out_of_range after a model step; where it is set, the step's inputs are kept for the
   warning (log_range) */
static void check_range(Instance *in, int inputs_out, double i, double t, double soc) {
    State *s = &in->s;
    s->out_of_range = inputs_out || voltage_out_of_range(s->voltage);
    if (s->out_of_range) {
        in->range_inputs = inputs_out;
        in->range_i = i;
        in->range_t = t;
        in->range_soc = soc;
    }
}

/* the FMI warning at the start of an out-of-range excursion (a doStep after which out_of_range
   is set and before which it was not): what left the trained region in the last model step,
   as CellCosim.range_message and the Python FMU write it; t0 the step's communication point */
static void log_range(Instance *in, double t0) {
    char msg[400] = "";
    size_t n = 0;
    if (in->range_inputs & OUT_CURRENT)
        n = append_part(msg, n, sizeof msg, "current %.3f A outside the trained %.3f..%.3f A",
                        in->range_i, I_MIN, I_MAX);
    if (in->range_inputs & OUT_SOC)
        n = append_part(msg, n, sizeof msg, "SoC %.3f outside the trained %.3f..%.3f",
                        in->range_soc, SOC_MIN, SOC_MAX);
#if HAS_TEMPERATURE_RANGE
    if (in->range_inputs & OUT_TEMPERATURE)
        n = append_part(msg, n, sizeof msg, "temperature %.1f degC outside the trained "
                        "%.1f..%.1f degC", in->range_t, T_MIN, T_MAX);
#endif
    if (voltage_out_of_range(in->s.voltage))
        n = append_part(msg, n, sizeof msg, "model voltage %.3f V outside the trained "
                        "%.3f..%.3f V", in->s.voltage, V_MIN, V_MAX);
    logf_(in, fmi2Warning, "logStatusWarning", "t = %.9g s: %s", t0, msg);
}

/* ----- cell temperature (step.CellThermal, thermal.py) ---------------------------------------- */
static int thermal_active(const State *s) { return HAS_THERMAL && !s->temperature_is_cell; }

/* thermal.cell_start_fault: why use_cell_temperature_start = true cannot be taken (written
   into msg), or 0 where it can */
static int cell_start_fault(const State *s, char *msg, size_t size) {
    if (!thermal_active(s)) {
        snprintf(msg, size, "parameter 'use_cell_temperature_start' = true: %s, so the "
                 "temperature input is the cell temperature, from the first step on",
                 s->temperature_is_cell ? "temperature_is_cell = true"
                                        : "this model has no thermal model");
        return 1;
    }
    if (!(isfinite(s->t_start) && s->t_start >= MIN_TEMPERATURE_C
          && s->t_start <= MAX_TEMPERATURE_C)) {
        snprintf(msg, size, "parameter 'cell_temperature_start' = %g: expected a cell "
                 "temperature within %g...%g degC", s->t_start, MIN_TEMPERATURE_C,
                 MAX_TEMPERATURE_C);
        return 1;
    }
    return 0;
}

/* the cell starts at cell_temperature_start (use_cell_temperature_start, taken) */
static int starts_at_t_start(const State *s) {
    char msg[256];
    return s->use_t_start && !cell_start_fault(s, msg, sizeof msg);
}

static double cell_temperature(State *s, double input) {
    if (!thermal_active(s)) return input;
    if (!s->t_cell_set) {
        s->t_cell = input + THERMAL_OFFSET_K;
        s->t_cell_set = 1;
    }
    return s->t_cell;
}

static void thermal_update(State *s, double input, double i) {
    double a, rest, q, t;
    if (!thermal_active(s)) {
        s->t_cell = input;
        s->t_cell_set = 1;
        return;
    }
    t = cell_temperature(s, input);
    q = i * (s->voltage - ocv(s->soc));
    a = exp(-TS / THERMAL_TAU_S);
    rest = input + THERMAL_OFFSET_K;
    s->t_cell = rest + a * (t - rest) + THERMAL_R_K_PER_W * (1.0 - a) * q;
}

static void model_step(Instance *in) {
    State *s = &in->s;
    double i = DELAY_S > 0 ? s->d_current : s->charge / TS, ta = s->temp_int / TS;
    double t = cell_temperature(s, ta), soc = s->observer ? s->ob_soc : s->soc;
    int inputs_out = inputs_out_of_range(i, t, soc);
    if (s->observer) {
        double v = s->volt_time >= TS * (1 - STEP_TOL) ? s->volt_int / s->volt_time : 0.0;
        observer_step(s, i, v > 0 ? v : NAN, t);
    } else {
        stepper_step(s, i, t);
    }
    check_range(in, inputs_out, i, t, soc);
    thermal_update(s, ta, i);
    s->steps++;
    s->covered = s->charge = s->temp_int = s->volt_int = s->volt_time = 0.0;
}

/* cosim.CellCosim._preview: while a model step is partly covered and no observer runs, the
   voltage now is that step taken on a copy as if the current input had been held over all of it
   (with a current delay longer than the communication step h: the open delayed window's mean,
   cosim.CellCosim._preview_current), at the temperature input's mean over the covered part */
static void preview(State *s, double h) {
    State copy;
    double i;
    s->preview_on = s->covered > 0.0 && !s->observer;
    if (!s->preview_on) return;
    i = DELAY_S <= 0 || h >= DELAY_S ? s->current
        : (s->d_covered > 0.0 ? s->d_charge / s->d_covered : s->d_current);
    copy = *s;           /* cell_temperature may fix the copy's start temperature, not s's */
    stepper_step(&copy, i, cell_temperature(&copy, s->temp_int / s->covered));
    s->preview = copy.voltage;
}

static fmi2Status cosim_advance(Instance *in, double h) {
    State *s = &in->s;
    double remaining = h;
    if (!isfinite(s->current)) {
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: input 'current' = %g: expected a "
              "finite number; the step was not taken", s->time, s->current);
        return fmi2Error;
    }
    if (!isfinite(s->temperature)) {
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: input 'temperature' = %g: expected "
              "a finite number; the step was not taken", s->time, s->temperature);
        return fmi2Error;
    }
    if (!isfinite(s->voltage_measured)) {
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: input 'voltage_measured' = %g: "
              "expected a finite number (0 when not measured); the step was not taken", s->time,
              s->voltage_measured);
        return fmi2Error;
    }
    if (!isfinite(h) || h <= 0) {
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: communication step size %g s: "
              "expected > 0 s; the step was not taken", s->time, h);
        return fmi2Error;
    }
    if (h > MAX_STEPS_PER_CALL * TS) {  /* for ever, once TS no longer changes `remaining` */
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: communication step size %g s: more "
              "than %.0f model steps of %g s; expected at most %g s in one step (split it); the "
              "step was not taken", s->time, h, MAX_STEPS_PER_CALL, TS, MAX_STEPS_PER_CALL * TS);
        return fmi2Error;
    }
    if (fabs(s->current) > MAX_C_RATE * s->capacity) {
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: input 'current' = %g A: beyond %g C "
              "of %g Ah, not a current a cell carries; the step was not taken", s->time,
              s->current, MAX_C_RATE, s->capacity);
        return fmi2Error;
    }
    if (s->temperature < MIN_TEMPERATURE_C || s->temperature > MAX_TEMPERATURE_C) {
        logf_(in, fmi2Error, "logStatusError", "t = %.9g s: input 'temperature' = %g degC: "
              "expected %g..%g degC (degC, not K); the step was not taken", s->time, s->temperature,
              MIN_TEMPERATURE_C, MAX_TEMPERATURE_C);
        return fmi2Error;
    }
    if (DELAY_S > 0 && isnan(s->d_charge)) s->d_charge = s->current * DELAY_S;
    while (remaining > 0.0) {          /* every positive step counts, however short */
        double take = TS - s->covered < remaining ? TS - s->covered : remaining;
        if (DELAY_S > 0) {
            if (TS - s->d_covered < take) take = TS - s->d_covered;
            s->d_covered += take;
            s->d_charge += s->current * take;
        }
        s->covered += take;
        s->charge += s->current * take;
        s->temp_int += s->temperature * take;
        if (s->voltage_measured > 0) {
            s->volt_int += s->voltage_measured * take;
            s->volt_time += take;
        }
        remaining -= take;
        if (DELAY_S > 0 && s->d_covered >= TS * (1.0 - STEP_TOL)) {
            s->d_current = s->d_charge / TS;
            s->d_covered = s->d_charge = 0.0;
        }
        if (s->covered >= TS * (1.0 - STEP_TOL)) {
            model_step(in);
            if (remaining < STEP_TOL * TS) remaining = 0.0;  /* rounding of the step's end */
        }
    }
    preview(s, h);
    s->time += h;
    return fmi2OK;
}

static int outputs_finite(const State *s) {
    return isfinite(s->voltage) && isfinite(s->soc) && isfinite(s->ob_soc) &&
           isfinite(s->ob_var) && isfinite(s->t_cell) && (!s->preview_on || isfinite(s->preview));
}

/* the state right after initialisation, from the parameters and the temperature input */
static void init_state(State *s) {
    /* the temperature input where a step takes it, else the default (the first step
       refuses it; the outputs until then stay finite), as the pythonfmu FMU's slave */
    double t_in = isfinite(s->temperature) && s->temperature >= MIN_TEMPERATURE_C &&
                  s->temperature <= MAX_TEMPERATURE_C ? s->temperature : DEFAULT_TEMPERATURE_C;
    double soc0 = is_soc_fraction(s->soc0) ? s->soc0 : (s->soc0 > 1.0 ? 1.0 : 0.0);
    if (starts_at_t_start(s)) {          /* a cell warmer or colder than its ambient */
        s->t_cell = s->t_last_input = s->t_start;
        s->t_cell_set = 1;
    } else {                             /* rested at the first step's input */
        s->t_cell_set = 0;
        s->t_last_input = cell_temperature(s, t_in);
        s->t_cell_set = 0;
    }
    stepper_init(s, soc0, s->t_last_input);
    observer_init(s, soc0);
    s->covered = s->charge = s->temp_int = s->volt_int = s->volt_time = 0.0;
    s->d_covered = DELAY_S;
    s->d_charge = NAN;
    s->d_current = 0.0;
    s->out_of_range = 0;
    s->steps = 0;
    s->initialized = 1;
}

static fmi2Status initialise(Instance *in) {
    State *s = &in->s;
    char msg[256];
    if (!is_soc_fraction(s->soc0)) {
        logf_(in, fmi2Error, "logStatusError", "parameter 'soc0' = %g: expected a fraction "
              "within 0..1; not initialised, every step will be refused", s->soc0);
        return fmi2Error;
    }
    if (!is_cell_capacity(s->capacity)) {
        logf_(in, fmi2Error, "logStatusError", "parameter 'capacity' = %g: expected a cell's "
              "capacity within %g...%g Ah; not initialised, every step will be refused",
              s->capacity, CAPACITY_MIN_AH, CAPACITY_MAX_AH);
        return fmi2Error;
    }
    if (!is_observer(s->observer)) {
        logf_(in, fmi2Error, "logStatusError", "parameter 'observer' = %d: expected 0 none, 1 EKF, "
              "2 fuzzy, 3 IMM; not initialised, every step will be refused", s->observer);
        return fmi2Error;
    }
    if (s->use_t_start && cell_start_fault(s, msg, sizeof msg)) {
        logf_(in, fmi2Error, "logStatusError", "%s; not initialised, every step will be "
              "refused", msg);
        return fmi2Error;
    }
    init_state(s);
    return fmi2OK;
}

static void defaults(State *s) {
    memset(s, 0, sizeof *s);
    s->magic = STATE_MAGIC;
    s->temperature = DEFAULT_TEMPERATURE_C;
    s->soc0 = 1.0;
    s->capacity = CAPACITY_AH;
    s->t_start = DEFAULT_TEMPERATURE_C;
    s->voltage = RELATIVE_OCV ? ocv(1.0) : 0.0;
}

/* ----- FMI 2.0 co-simulation interface ---------------------------------------------------------- */
const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
const char *fmi2GetVersion(void) { return fmi2Version; }

/* The log categories modelDescription.xml declares: those of the pythonfmu FMU */
#define DECLARED_CATEGORIES \
    "logStatusWarning, logStatusDiscard, logStatusError, logStatusFatal, logAll"
static int declared_category(const char *name) {
    static const char *const declared[] = {"logStatusWarning", "logStatusDiscard",
                                           "logStatusError", "logStatusFatal", "logAll"};
    size_t k;
    for (k = 0; k < sizeof declared / sizeof declared[0]; k++)
        if (strcmp(name, declared[k]) == 0) return 1;
    return 0;
}

/* Logging on for the categories named (all with none named, or with logAll), as the pythonfmu
   FMU's logger does: warnings ("logStatusWarning") are logged only where it is on; errors
   always. A NULL array or entry is refused and the logging left as it was; a category that is
   not declared is ignored with fmi2Warning. */
fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cats[]) {
    Instance *in = (Instance *)c;
    int warnings = n == 0;
    fmi2Status status = fmi2OK;
    size_t k;
    if (!in) return fmi2Error;
    if (n > 0 && !cats) {
        logf_(in, fmi2Error, "logStatusError", "fmi2SetDebugLogging: nCategories = %zu but "
              "categories is NULL; logging left as it was", n);
        return fmi2Error;
    }
    for (k = 0; k < n; k++) {
        if (!cats[k]) {
            logf_(in, fmi2Error, "logStatusError", "fmi2SetDebugLogging: nCategories = %zu but "
                  "categories[%zu] is NULL; logging left as it was", n, k);
            return fmi2Error;
        }
    }
    for (k = 0; k < n; k++) {
        if (strcmp(cats[k], "logStatusWarning") == 0 || strcmp(cats[k], "logAll") == 0)
            warnings = 1;
        else if (!declared_category(cats[k])) {
            /* not filtered by the logging switch: the host's own mistake, as it returns */
            if (in->cb && in->cb->logger)
                in->cb->logger(in->cb->componentEnvironment, in->name, fmi2Warning,
                               "logStatusWarning", "fmi2SetDebugLogging: log category '%.40s' "
                               "is not declared, ignored; this FMU declares %s", cats[k],
                               DECLARED_CATEGORIES);
            status = fmi2Warning;
        }
    }
    in->logging = on && warnings;
    return status;
}

fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String res,
                              const fmi2CallbackFunctions *cb, fmi2Boolean vis, fmi2Boolean log) {
    Instance *in;
    (void)res; (void)vis;
    if (!cb || !cb->logger) return NULL;   /* FMI 2.0: the host must give a logger */
    if (!name || !name[0]) {               /* FMI 2.0: not NULL, not empty */
        cb->logger(cb->componentEnvironment, "", fmi2Error, "logStatusError",
                   "fmi2Instantiate: empty instanceName");
        return NULL;
    }
    if (type != fmi2CoSimulation || !guid || strcmp(guid, MODEL_GUID) != 0) {
        cb->logger(cb->componentEnvironment, name, fmi2Error, "logStatusError",
                   "fmi2Instantiate: wrong FMU type or GUID (expected %s)", MODEL_GUID);
        return NULL;
    }
    in = (Instance *)calloc(1, sizeof(Instance));
    if (!in) return NULL;
    in->cb = cb;
    in->logging = log;
    in->mode = MODE_INSTANTIATED;
    snprintf(in->name, sizeof in->name, "%s", name);
    defaults(&in->s);
    return in;
}

void fmi2FreeInstance(fmi2Component c) {
    Instance *in = (Instance *)c;
    size_t k;
    if (!in) return;
    for (k = 0; k < in->n_states; k++) free(in->states[k]);
    free(in->states);
    free(in);
}

/* 1 if the instance's mode is among `allowed` (a mask of M_(MODE_…)), else log and 0 */
#define M_(m) (1 << (m))
static int in_mode(Instance *in, int allowed, const char *call) {
    static const char *names[] = {"instantiated", "initialization mode", "step mode",
                                  "terminated"};
    if (allowed & M_(in->mode)) return 1;
    logf_(in, fmi2Error, "logStatusError", "%s is not allowed in %s", call, names[in->mode]);
    return 0;
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tolDef, fmi2Real tol, fmi2Real t0,
                               fmi2Boolean stopDef, fmi2Real t1) {
    Instance *in = (Instance *)c;
    (void)tolDef; (void)tol;
    if (!in || !in_mode(in, M_(MODE_INSTANTIATED), "fmi2SetupExperiment")) return fmi2Error;
    if (!isfinite(t0)) {
        logf_(in, fmi2Error, "logStatusError", "fmi2SetupExperiment: startTime %g is not finite",
              t0);
        return fmi2Error;
    }
    if (stopDef && !(t1 >= t0 && isfinite(t1))) {
        logf_(in, fmi2Error, "logStatusError", "fmi2SetupExperiment: stopTime %g is not a "
              "finite time at or after startTime %g (stopTimeDefined is true); nothing was set",
              t1, t0);
        return fmi2Error;
    }
    in->s.time = t0;
    in->stop_defined = stopDef ? 1 : 0;
    in->stop_time = t1;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    Instance *in = (Instance *)c;
    if (!in || !in_mode(in, M_(MODE_INSTANTIATED), "fmi2EnterInitializationMode"))
        return fmi2Error;
    in->mode = MODE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    Instance *in = (Instance *)c;
    fmi2Status st;
    if (!in || !in_mode(in, M_(MODE_INITIALIZATION), "fmi2ExitInitializationMode"))
        return fmi2Error;
    st = initialise(in);
    if (st == fmi2OK) in->mode = MODE_STEP;
    return st;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    Instance *in = (Instance *)c;
    if (!in || !in_mode(in, M_(MODE_INITIALIZATION) | M_(MODE_STEP), "fmi2Terminate"))
        return fmi2Error;
    in->mode = MODE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    Instance *in = (Instance *)c;
    if (!in) return fmi2Error;
    defaults(&in->s);
    in->mode = MODE_INSTANTIATED;
    in->stop_defined = 0;
    return fmi2OK;
}

static double output_real(const State *s0, fmi2ValueReference vr, int *ok) {
    State tmp;
    const State *s = s0;
    *ok = 1;
    if (!s0->initialized && (vr == VR_VOLTAGE || vr == VR_SOC || vr == VR_SOC_STD ||
                             vr == VR_CELL_TEMPERATURE)) {
        tmp = *s0;                       /* what exitInitializationMode will give, unchanged */
        if (!is_observer(tmp.observer)) tmp.observer = 0;
        if (!is_cell_capacity(tmp.capacity)) tmp.capacity = CAPACITY_AH;
        init_state(&tmp);
        s = &tmp;
    }
    switch (vr) {
    case VR_CURRENT: return s->current;
    case VR_VOLTAGE_MEASURED: return s->voltage_measured;
    case VR_TEMPERATURE: return s->temperature;
    case VR_VOLTAGE: return s->initialized ? (s->preview_on ? s->preview : s->voltage)
                                           : (RELATIVE_OCV ? ocv(s->soc0) : NAN);
    case VR_SOC: return s->initialized ? (s->observer ? s->ob_soc : s->soc) : s->soc0;
    case VR_SOC_STD: {   /* the reported σ: at least the floor (SocObserver.soc_std) */
        double var = s->ob_var > s->ob_floor ? s->ob_var : s->ob_floor;
        return s->initialized && s->observer ? sqrt(var > 0 ? var : 0) : 0.0;
    }
    case VR_SOC0: return s->soc0;
    case VR_CAPACITY: return s->capacity;
    case VR_CELL_TEMPERATURE_START: return s->t_start;
    case VR_CELL_TEMPERATURE:
        if (s->initialized && s->t_cell_set) return s->t_cell;
        if (s->initialized) return s->t_last_input;
        return s->temperature + (thermal_active(s) ? THERMAL_OFFSET_K : 0.0);
    default: *ok = 0; return 0.0;
    }
}

/* the modes in which FMI 2.0 lets a co-simulation host read variables: not before
   fmi2EnterInitializationMode (the Instantiated state) */
#define GETTABLE (M_(MODE_INITIALIZATION) | M_(MODE_STEP) | M_(MODE_TERMINATED))

/* 1 where the arrays of a get or set call are given (or n is 0), else log and 0: a NULL
   array with n > 0 is the host's mistake, refused with nothing read or set */
static int arrays_given(Instance *in, const char *call, size_t n, const void *vr,
                        const void *values, const char *done) {
    if (n == 0 || (vr && values)) return 1;
    logf_(in, fmi2Error, "logStatusError", "%s: nvr = %zu but %s is NULL; nothing was %s", call,
          n, vr ? "value" : "vr", done);
    return 0;
}

/* 1 where pointer p is given, else log that the argument `what` of `call` is NULL and 0 */
static int given(Instance *in, const char *call, const void *p, const char *what) {
    if (p) return 1;
    logf_(in, fmi2Error, "logStatusError", "%s: %s is NULL", call, what);
    return 0;
}

/* ----- variable access ------------------------------------------------------------------------ */
/* the variables by value reference, as the pythonfmu FMU registers them (slave.py) */
typedef enum { T_REAL, T_INTEGER, T_BOOLEAN } VarType;
typedef enum { C_INPUT, C_OUTPUT, C_PARAMETER } VarCausality;
static const char *const TYPE_NAMES[] = {"Real", "Integer", "Boolean"};
static const struct { const char *name; VarType type; VarCausality causality; } VARS[] = {
    {"current", T_REAL, C_INPUT}, {"voltage_measured", T_REAL, C_INPUT},
    {"temperature", T_REAL, C_INPUT}, {"voltage", T_REAL, C_OUTPUT}, {"soc", T_REAL, C_OUTPUT},
    {"soc_std", T_REAL, C_OUTPUT}, {"out_of_range", T_BOOLEAN, C_OUTPUT},
    {"soc0", T_REAL, C_PARAMETER}, {"capacity", T_REAL, C_PARAMETER},
    {"observer", T_INTEGER, C_PARAMETER}, {"temperature_is_cell", T_BOOLEAN, C_PARAMETER},
    {"cell_temperature", T_REAL, C_OUTPUT}, {"cell_temperature_start", T_REAL, C_PARAMETER},
    {"use_cell_temperature_start", T_BOOLEAN, C_PARAMETER}};
#define N_VARS (sizeof VARS / sizeof VARS[0])

/* a Real as the log writes it (slave.value_text): the fewest significant digits that read
   back to it, in %g's form and without an exponent below 1e6; nan, inf or -inf */
static void real_text(char *out, size_t size, double x) {
    int p, exponent, q;
    const char *e;
    if (isnan(x)) { snprintf(out, size, "nan"); return; }
    if (isinf(x)) { snprintf(out, size, x > 0 ? "inf" : "-inf"); return; }
    for (p = 1; p < 17; p++) {
        snprintf(out, size, "%.*e", p - 1, x);
        if (strtod(out, NULL) == x) break;
    }
    snprintf(out, size, "%.*e", p - 1, x);
    e = strchr(out, 'e');
    exponent = e ? atoi(e + 1) : 0;
    q = exponent + 1 < 6 ? exponent + 1 : 6;
    snprintf(out, size, "%.*g", p > q ? p : q, x);
}

/* value k of a get or set call's array of the given type, as the log writes it */
static void value_text(char *out, size_t size, VarType type, const void *values, size_t k) {
    if (type == T_REAL) real_text(out, size, ((const fmi2Real *)values)[k]);
    else if (type == T_INTEGER) snprintf(out, size, "%d", ((const fmi2Integer *)values)[k]);
    else snprintf(out, size, "%s", ((const fmi2Boolean *)values)[k] ? "true" : "false");
}

/* a parameter's value, as the log writes it */
static void parameter_text(char *out, size_t size, const State *s, fmi2ValueReference vr) {
    switch (vr) {
    case VR_SOC0: real_text(out, size, s->soc0); break;
    case VR_CAPACITY: real_text(out, size, s->capacity); break;
    case VR_CELL_TEMPERATURE_START: real_text(out, size, s->t_start); break;
    case VR_OBSERVER: snprintf(out, size, "%d", s->observer); break;
    case VR_TEMPERATURE_IS_CELL: snprintf(out, size, s->temperature_is_cell ? "true" : "false");
        break;
    default: snprintf(out, size, s->use_t_start ? "true" : "false"); break;
    }
}

/* why value reference vr cannot be read (setting 0) or set (setting 1) as the given type now,
   written into out, or 0 where it can (slave._problem's words) */
static int access_problem(char *out, size_t size, const State *s, fmi2ValueReference vr,
                          VarType type, int setting) {
    char kept[32];
    if (vr >= N_VARS) {
        snprintf(out, size, "no variable with value reference %u", vr);
        return 1;
    }
    if (VARS[vr].type != type) {
        snprintf(out, size, "value reference %u ('%s') is not a%s %s", vr, VARS[vr].name,
                 type == T_INTEGER ? "n" : "", TYPE_NAMES[type]);
        return 1;
    }
    if (setting && VARS[vr].causality == C_OUTPUT) {
        snprintf(out, size, "'%s' is an output and cannot be set", VARS[vr].name);
        return 1;
    }
    if (setting && VARS[vr].causality == C_PARAMETER && s->initialized) {
        parameter_text(kept, sizeof kept, s, vr);
        snprintf(out, size, "parameter '%s' is fixed after initialisation (value kept: %s)",
                 VARS[vr].name, kept);
        return 1;
    }
    return 0;
}

/* 1 where every value of a set call can be set, else log the first that cannot (how many more
   cannot) and 0: nothing of the call is then set */
static int all_settable(Instance *in, const char *call, size_t n, const fmi2ValueReference vr[],
                        VarType type, const void *values) {
    char problem[160], given[32], more[48] = "";
    size_t k, first = n, others = 0;
    for (k = 0; k < n; k++) {
        if (access_problem(problem, sizeof problem, &in->s, vr[k], type, 1)) {
            if (first == n) first = k;
            else others++;
        }
    }
    if (first == n) return 1;
    access_problem(problem, sizeof problem, &in->s, vr[first], type, 1);
    value_text(given, sizeof given, type, values, first);
    if (others)
        snprintf(more, sizeof more, "; %zu more value%s refused", others, others > 1 ? "s" : "");
    logf_(in, fmi2Error, "logStatusError", "%s: %s; %s was not set%s (nothing of this call was "
          "set)", call, problem, given, more);
    return 0;
}

/* 1 where value reference vr can be read as the given type, else log why and 0 */
static int readable(Instance *in, const char *call, fmi2ValueReference vr, VarType type) {
    char problem[160];
    if (!access_problem(problem, sizeof problem, &in->s, vr, type, 0)) return 1;
    logf_(in, fmi2Error, "logStatusError", "%s: %s", call, problem);
    return 0;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real v[]) {
    Instance *in = (Instance *)c;
    size_t k;
    int ok;
    if (!in || !in_mode(in, GETTABLE, "fmi2GetReal")
        || !arrays_given(in, "fmi2GetReal", n, vr, v, "read")) return fmi2Error;
    for (k = 0; k < n; k++) {
        if (!readable(in, "fmi2GetReal", vr[k], T_REAL)) return fmi2Error;
        v[k] = output_real(&in->s, vr[k], &ok);
    }
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer v[]) {
    Instance *in = (Instance *)c;
    size_t k;
    if (!in || !in_mode(in, GETTABLE, "fmi2GetInteger")
        || !arrays_given(in, "fmi2GetInteger", n, vr, v, "read")) return fmi2Error;
    for (k = 0; k < n; k++) {
        if (!readable(in, "fmi2GetInteger", vr[k], T_INTEGER)) return fmi2Error;
        v[k] = in->s.observer;     /* the only Integer */
    }
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[]) {
    Instance *in = (Instance *)c;
    size_t k;
    if (!in || !in_mode(in, GETTABLE, "fmi2GetBoolean")
        || !arrays_given(in, "fmi2GetBoolean", n, vr, v, "read")) return fmi2Error;
    for (k = 0; k < n; k++) {
        if (!readable(in, "fmi2GetBoolean", vr[k], T_BOOLEAN)) return fmi2Error;
        if (vr[k] == VR_OUT_OF_RANGE) v[k] = in->s.out_of_range ? fmi2True : fmi2False;
        else if (vr[k] == VR_TEMPERATURE_IS_CELL)
            v[k] = in->s.temperature_is_cell ? fmi2True : fmi2False;
        else v[k] = in->s.use_t_start ? fmi2True : fmi2False;
    }
    return fmi2OK;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[]) {
    if (!c || !in_mode((Instance *)c, GETTABLE, "fmi2GetString")
        || !arrays_given((Instance *)c, "fmi2GetString", n, vr, v, "read")) return fmi2Error;
    if (n) {
        logf_((Instance *)c, fmi2Error, "logStatusError", "fmi2GetString: value reference %u: "
              "this FMU has no String variables", vr[0]);
        return fmi2Error;
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real v[]) {
    Instance *in = (Instance *)c;
    State *s;
    size_t k;
    if (!in || !in_mode(in, M_(MODE_INSTANTIATED) | M_(MODE_INITIALIZATION) | M_(MODE_STEP),
                        "fmi2SetReal") || !arrays_given(in, "fmi2SetReal", n, vr, v, "set")
        || !all_settable(in, "fmi2SetReal", n, vr, T_REAL, v))
        return fmi2Error;
    s = &in->s;
    for (k = 0; k < n; k++) {
        switch (vr[k]) {       /* all_settable: the settable Reals only */
        case VR_CURRENT: s->current = v[k]; break;
        case VR_VOLTAGE_MEASURED: s->voltage_measured = v[k]; break;
        case VR_TEMPERATURE: s->temperature = v[k]; break;
        case VR_SOC0: s->soc0 = v[k]; break;
        case VR_CAPACITY: s->capacity = v[k]; break;
        default: s->t_start = v[k]; break;
        }
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Integer v[]) {
    Instance *in = (Instance *)c;
    size_t k;
    if (!in || !in_mode(in, M_(MODE_INSTANTIATED) | M_(MODE_INITIALIZATION) | M_(MODE_STEP),
                        "fmi2SetInteger") || !arrays_given(in, "fmi2SetInteger", n, vr, v, "set")
        || !all_settable(in, "fmi2SetInteger", n, vr, T_INTEGER, v))
        return fmi2Error;
    for (k = 0; k < n; k++) in->s.observer = v[k];     /* the only Integer */
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                          const fmi2Boolean v[]) {
    Instance *in = (Instance *)c;
    size_t k;
    if (!in || !in_mode(in, M_(MODE_INSTANTIATED) | M_(MODE_INITIALIZATION) | M_(MODE_STEP),
                        "fmi2SetBoolean") || !arrays_given(in, "fmi2SetBoolean", n, vr, v, "set")
        || !all_settable(in, "fmi2SetBoolean", n, vr, T_BOOLEAN, v))
        return fmi2Error;
    for (k = 0; k < n; k++) {  /* all_settable: the two Boolean parameters only */
        if (vr[k] == VR_TEMPERATURE_IS_CELL) in->s.temperature_is_cell = v[k] ? 1 : 0;
        else in->s.use_t_start = v[k] ? 1 : 0;
    }
    return fmi2OK;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                         const fmi2String v[]) {
    if (!c || !arrays_given((Instance *)c, "fmi2SetString", n, vr, v, "set")) return fmi2Error;
    if (n) {
        logf_((Instance *)c, fmi2Error, "logStatusError", "fmi2SetString: value reference %u: "
              "this FMU has no String variables; nothing was set", vr[0]);
        return fmi2Error;
    }
    return fmi2OK;
}

/* the index of st among the instance's live states, or n_states */
static size_t state_index(const Instance *in, const void *st) {
    size_t k;
    for (k = 0; k < in->n_states && (const void *)in->states[k] != st; k++) {}
    return k;
}

/* 1 where st is a live state of this instance (its fmi2GetFMUstate's or
   fmi2DeSerializeFMUstate's, not freed), else log and 0: a freed or foreign pointer is never
   read */
static int own_state(Instance *in, const char *call, fmi2FMUstate st) {
    if (!given(in, call, st, "the FMU state")) return 0;
    if (state_index(in, st) < in->n_states) return 1;
    logf_(in, fmi2Error, "logStatusError", "%s: the FMU state is not one of this instance's "
          "(freed, or from another instance or FMU?)", call);
    return 0;
}

/* a new state of this instance, holding a copy of s; NULL (logged) when out of memory */
static State *new_state(Instance *in, const char *call, const State *s) {
    State *copy;
    if (in->n_states == in->cap_states) {
        size_t cap = in->cap_states ? 2 * in->cap_states : 8;
        State **grown = (State **)realloc(in->states, cap * sizeof *grown);
        if (!grown) {
            logf_(in, fmi2Error, "logStatusError", "%s: out of memory", call);
            return NULL;
        }
        in->states = grown;
        in->cap_states = cap;
    }
    copy = (State *)malloc(sizeof(State));
    if (!copy) {
        logf_(in, fmi2Error, "logStatusError", "%s: out of memory", call);
        return NULL;
    }
    *copy = *s;
    in->states[in->n_states++] = copy;
    return copy;
}

/* s into the host's *st: a state handed out before is reused, as FMI 2.0 suggests (after
   own_state), else a new one of this instance is made (fmi2GetFMUstate, ...DeSerialize...) */
static fmi2Status store_state(Instance *in, const char *call, fmi2FMUstate *st, const State *s) {
    State *copy;
    if (*st) {
        if (!own_state(in, call, *st)) return fmi2Error;
        *(State *)*st = *s;
        return fmi2OK;
    }
    copy = new_state(in, call, s);
    if (!copy) return fmi2Error;
    *st = copy;
    return fmi2OK;
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Instance *in = (Instance *)c;
    if (!in || !given(in, "fmi2GetFMUstate", st, "the pointer to the FMU state")) return fmi2Error;
    return store_state(in, "fmi2GetFMUstate", st, &in->s);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate st) {
    Instance *in = (Instance *)c;
    if (!in || !own_state(in, "fmi2SetFMUstate", st)) return fmi2Error;
    in->s = *(State *)st;
    in->mode = in->s.initialized ? MODE_STEP : MODE_INSTANTIATED;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *st) {
    Instance *in = (Instance *)c;
    if (!in || !given(in, "fmi2FreeFMUstate", st, "the pointer to the FMU state"))
        return fmi2Error;
    if (!*st) return fmi2OK;   /* nothing to free */
    if (!own_state(in, "fmi2FreeFMUstate", *st)) return fmi2Error;
    in->states[state_index(in, *st)] = in->states[--in->n_states];
    free(*st);
    *st = NULL;
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate st, size_t *size) {
    Instance *in = (Instance *)c;
    if (!in || !own_state(in, "fmi2SerializedFMUstateSize", st)
        || !given(in, "fmi2SerializedFMUstateSize", size, "size")) return fmi2Error;
    *size = sizeof(State);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate st, fmi2Byte b[], size_t size) {
    Instance *in = (Instance *)c;
    if (!in || !own_state(in, "fmi2SerializeFMUstate", st)
        || !given(in, "fmi2SerializeFMUstate", b, "serializedState")) return fmi2Error;
    if (size != sizeof(State)) {
        logf_(in, fmi2Error, "logStatusError", "fmi2SerializeFMUstate: size %lu, expected %lu "
              "(fmi2SerializedFMUstateSize)", (unsigned long)size, (unsigned long)sizeof(State));
        return fmi2Error;
    }
    memcpy(b, st, sizeof(State));
    return fmi2OK;
}

/* whether s is a state this FMU can be in, as far as its switches, time, parameters and
   outputs tell (bytes with the right size and magic number may still be none: another model
   of the same shape, or bytes changed on the way) */
static int state_plausible(const State *s) {
    if (!isfinite(s->time) || (s->temperature_is_cell != 0 && s->temperature_is_cell != 1)
        || (s->initialized != 0 && s->initialized != 1)
        || (s->use_t_start != 0 && s->use_t_start != 1))
        return 0;
    return !s->initialized || (is_observer(s->observer) && is_cell_capacity(s->capacity)
                               && is_soc_fraction(s->soc0) && outputs_finite(s)
                               && (!s->use_t_start || starts_at_t_start(s)));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t size,
                                   fmi2FMUstate *st) {
    Instance *in = (Instance *)c;
    State tmp;
    if (!in || !given(in, "fmi2DeSerializeFMUstate", b, "serializedState")
        || !given(in, "fmi2DeSerializeFMUstate", st, "the pointer to the FMU state"))
        return fmi2Error;
    if (size != sizeof(State)) {
        logf_(in, fmi2Error, "logStatusError", "fmi2DeSerializeFMUstate: %lu bytes, "
              "expected %lu (another model or version?)", (unsigned long)size,
              (unsigned long)sizeof(State));
        return fmi2Error;
    }
    memcpy(&tmp, b, sizeof(State));
    if (tmp.magic != STATE_MAGIC) {
        logf_(in, fmi2Error, "logStatusError", "fmi2DeSerializeFMUstate: the bytes are not a "
              "state of this model (another model or version?)");
        return fmi2Error;
    }
    if (!state_plausible(&tmp)) {
        logf_(in, fmi2Error, "logStatusError", "fmi2DeSerializeFMUstate: the bytes are not a "
              "state this FMU can be in (a non-finite time, a switch out of range, or, once "
              "initialised, a bad parameter or a non-finite output); nothing was read");
        return fmi2Error;
    }
    return store_state(in, "fmi2DeSerializeFMUstate", st, &tmp);
}

/* A function this FMU does not offer: fmi2Error, logged */
static fmi2Status not_supported(fmi2Component c, const char *message) {
    if (c) logf_((Instance *)c, fmi2Error, "logStatusError", "%s", message);
    return fmi2Error;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                        const fmi2ValueReference z[], size_t nz,
                                        const fmi2Real dv[], fmi2Real dz[]) {
    (void)u; (void)nu; (void)z; (void)nz; (void)dv; (void)dz;
    return not_supported(c, "fmi2GetDirectionalDerivative: not supported "
                                "(providesDirectionalDerivative is false)");
}

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                       const fmi2Integer order[], const fmi2Real v[]) {
    (void)vr; (void)n; (void)order; (void)v;
    return not_supported(c, "fmi2SetRealInputDerivatives: not supported "
                                "(canInterpolateInputs is false)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                        const fmi2Integer order[], fmi2Real v[]) {
    (void)vr; (void)n; (void)order; (void)v;
    return not_supported(c, "fmi2GetRealOutputDerivatives: not supported "
                                "(maxOutputDerivativeOrder is 0)");
}

/* the scale (s) of a relative time tolerance at time t: |t|, at least 1 s */
static double time_scale(double t) {
    return fabs(t) > 1.0 ? fabs(t) : 1.0;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean noSetPrior) {
    Instance *in = (Instance *)c;
    (void)t; (void)noSetPrior;
    if (!in) return fmi2Error;
    if (!in_mode(in, M_(MODE_STEP), "fmi2DoStep")) return fmi2Error;
    if (!isfinite(t) || fabs(t - in->s.time) > 1e-9 * time_scale(in->s.time)) {
        logf_(in, fmi2Error, "logStatusError", "fmi2DoStep: currentCommunicationPoint %.17g s "
              "is not the FMU's time %.17g s (steps must follow on from each other)", t,
              in->s.time);
        return fmi2Error;
    }
    if (in->stop_defined && isfinite(h)
        && !(in->s.time + h <= in->stop_time + STOP_TOLERANCE * time_scale(in->stop_time))) {
        logf_(in, fmi2Error, "logStatusError", "fmi2DoStep: a step of %.17g s from %.17g s "
              "ends past the stop time %.17g s given to fmi2SetupExperiment; the step was not "
              "taken", h, in->s.time, in->stop_time);
        return fmi2Error;
    }
#ifdef LMNCELL_TRIVIAL
    /* benchmark floor only: the same FMU with the model step left out */
    in->s.time += h;
    return fmi2OK;
#else
    {
        State before;                   /* its first state_kept bytes: what a refused step
                                           restores */
        size_t kept = state_kept(&in->s);
        int was_out = in->s.out_of_range;
        double t0 = in->s.time;
        fmi2Status st;
        memcpy(&before, &in->s, kept);
        st = cosim_advance(in, h);
        if (st == fmi2OK && !outputs_finite(&in->s)) {
            memcpy(&in->s, &before, kept);
            logf_(in, fmi2Error, "logStatusError", "t = %.9g s: the model produced a "
                  "non-finite output (inputs far outside the trained region?); the step was not "
                  "taken", t0);
            return fmi2Error;
        }
        if (st == fmi2OK && in->s.out_of_range && !was_out) log_range(in, t0);
        return st;
    }
#endif
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    return not_supported(c, "fmi2CancelStep: not supported "
                                "(its steps never return fmi2Pending)");
}

/* The status kinds FMI 2.0 defines, by value (fmi2StatusKind) */
static const char *status_kind(fmi2StatusKind k) {
    static const char *names[] = {"fmi2DoStepStatus", "fmi2PendingStatus",
                                  "fmi2LastSuccessfulTime", "fmi2Terminated"};
    return (unsigned)k < sizeof names / sizeof names[0] ? names[k] : "(unknown kind)";
}

/* A status this FMU cannot give: fmi2Discard, as FMI 2.0 asks, with a message saying why (its
   steps are synchronous and never discarded: only fmi2LastSuccessfulTime and fmi2Terminated
   are answered, by fmi2GetRealStatus and fmi2GetBooleanStatus) */
static fmi2Status no_status(Instance *in, const char *call, fmi2StatusKind k) {
    logf_(in, fmi2Discard, "logStatusDiscard", "%s: no %s status (this FMU answers "
          "fmi2LastSuccessfulTime by fmi2GetRealStatus and fmi2Terminated by "
          "fmi2GetBooleanStatus; its steps never return fmi2Pending)", call, status_kind(k));
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v) {
    (void)v;
    if (!c) return fmi2Error;
    return no_status((Instance *)c, "fmi2GetStatus", k);
}

/* fmi2LastSuccessfulTime: the end of the last completed communication step (the start time
   before the first) */
fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v) {
    Instance *in = (Instance *)c;
    if (!in) return fmi2Error;
    if (k != fmi2LastSuccessfulTime) return no_status(in, "fmi2GetRealStatus", k);
    if (!given(in, "fmi2GetRealStatus", v, "value")) return fmi2Error;
    *v = in->s.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v) {
    (void)v;
    if (!c) return fmi2Error;
    return no_status((Instance *)c, "fmi2GetIntegerStatus", k);
}

/* fmi2Terminated: fmi2False, the FMU never asks to end the simulation */
fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v) {
    Instance *in = (Instance *)c;
    if (!in) return fmi2Error;
    if (k != fmi2Terminated) return no_status(in, "fmi2GetBooleanStatus", k);
    if (!given(in, "fmi2GetBooleanStatus", v, "value")) return fmi2Error;
    *v = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v) {
    (void)v;
    if (!c) return fmi2Error;
    return no_status((Instance *)c, "fmi2GetStringStatus", k);
}
