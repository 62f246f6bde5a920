/* An FMI 2.0 co-simulation FMU through the FMI Library (FMIL: the model-description parser and
   C API loader that PyFMI and the FMI Compliance Checker are built on), for
   tests/test_conformance.py: its modelDescription.xml parsed with every warning and error FMIL
   reports, its variables listed, then a run through FMIL's C API: instantiate, setup,
   initialise, 600 s of a current of -6 / 0 / +2 A for 20 s each at 25 degC ambient, in steps of
   the default experiment's step size, terminate, free. The last line: the outputs at 600 s
   (voltage V, soc, cell temperature degC, %.17g). Exit code 1 where FMIL warned or erred about
   the XML or a call did not return fmi2OK.
   Build: gcc -std=c99 -I$FMIL/include fmil_check.c -L$FMIL/lib -lfmilib_shared
          -Wl,-rpath,$FMIL/lib */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <fmilib.h>

static int parsing = 1, xml_problems = 0;   /* FMIL's warnings and errors while it parses */

static void importlogger(jm_callbacks *c, jm_string module, jm_log_level_enu_t level,
                         jm_string message) {
    (void)c;
    if (parsing && level <= jm_log_level_warning) xml_problems++;
    if (level <= jm_log_level_info)
        printf("[FMIL %s %s] %s\n", module, jm_log_level_to_string(level), message);
}

static fmi2_value_reference_t vr_of(fmi2_import_t *fmu, const char *name) {
    fmi2_import_variable_t *v = fmi2_import_get_variable_by_name(fmu, name);
    if (!v) { printf("no variable %s\n", name); exit(1); }
    return fmi2_import_get_variable_vr(v);
}

int main(int argc, char *argv[]) {
    jm_callbacks cb;
    fmi_import_context_t *ctx;
    fmi2_import_t *fmu;
    fmi2_callback_functions_t fcb;
    fmi2_import_variable_list_t *vars;
    const char *tmp;
    size_t k, n;
    int bad_calls = 0;
    double t = 0.0, h, v[3];
    fmi2_value_reference_t in[2], out[3];
    if (argc < 2) return 2;
    cb.malloc = malloc; cb.calloc = calloc; cb.realloc = realloc; cb.free = free;
    cb.logger = importlogger; cb.log_level = jm_log_level_info; cb.context = 0;
    tmp = fmi_import_mk_temp_dir(&cb, "/tmp", "fmilcheck");
    ctx = fmi_import_allocate_context(&cb);
    if (fmi_import_get_fmi_version(ctx, argv[1], tmp) != fmi_version_2_0_enu) {
        printf("not FMI 2.0\n");
        return 1;
    }
    fmu = fmi2_import_parse_xml(ctx, tmp, 0);
    parsing = 0;
    if (!fmu) { printf("XML not parsed\n"); return 1; }
    printf("XML: %d warning(s)/error(s); model %s, GUID %s, kind %d, step %g s\n", xml_problems,
           fmi2_import_get_model_name(fmu), fmi2_import_get_GUID(fmu),
           (int)fmi2_import_get_fmu_kind(fmu), fmi2_import_get_default_experiment_step(fmu));
    vars = fmi2_import_get_variable_list(fmu, 0);
    n = fmi2_import_get_variable_list_size(vars);
    for (k = 0; k < n; k++) {
        fmi2_import_variable_t *var = fmi2_import_get_variable(vars, k);
        printf("  %-28s vr %2u %-10s %-10s %-12s initial %s\n", fmi2_import_get_variable_name(var),
               fmi2_import_get_variable_vr(var),
               fmi2_causality_to_string(fmi2_import_get_causality(var)),
               fmi2_variability_to_string(fmi2_import_get_variability(var)),
               fmi2_base_type_to_string(fmi2_import_get_variable_base_type(var)),
               fmi2_initial_to_string(fmi2_import_get_initial(var)));
    }
    fmi2_import_free_variable_list(vars);
    fcb.logger = fmi2_log_forwarding; fcb.allocateMemory = calloc; fcb.freeMemory = free;
    fcb.stepFinished = NULL; fcb.componentEnvironment = fmu;
    if (fmi2_import_create_dllfmu(fmu, fmi2_fmu_kind_cs, &fcb) == jm_status_error) {
        printf("DLL not loaded: %s\n", fmi2_import_get_last_error(fmu));
        return 1;
    }
    if (fmi2_import_instantiate(fmu, "fmilcheck", fmi2_cosimulation, NULL, fmi2_false)
        == jm_status_error) { printf("instantiate failed\n"); return 1; }
    fmi2_import_set_debug_logging(fmu, fmi2_true, 0, NULL);
    in[0] = vr_of(fmu, "current"); in[1] = vr_of(fmu, "temperature");
    out[0] = vr_of(fmu, "voltage"); out[1] = vr_of(fmu, "soc");
    out[2] = vr_of(fmu, "cell_temperature");
    bad_calls += fmi2_import_setup_experiment(fmu, fmi2_false, 0.0, 0.0, fmi2_true, 600.0) != 0;
    bad_calls += fmi2_import_enter_initialization_mode(fmu) != 0;
    bad_calls += fmi2_import_exit_initialization_mode(fmu) != 0;
    h = fmi2_import_get_default_experiment_step(fmu);
    while (t < 600.0 - 1e-9) {
        double u[2];
        u[0] = ((int)(t / 20.0)) % 3 == 0 ? -6.0 : (((int)(t / 20.0)) % 3 == 1 ? 0.0 : 2.0);
        u[1] = 25.0;
        bad_calls += fmi2_import_set_real(fmu, in, 2, u) != 0;
        bad_calls += fmi2_import_do_step(fmu, t, h, fmi2_true) != 0;
        t += h;
    }
    bad_calls += fmi2_import_get_real(fmu, out, 3, v) != 0;
    bad_calls += fmi2_import_terminate(fmu) != 0;
    fmi2_import_free_instance(fmu);
    fmi2_import_destroy_dllfmu(fmu);
    fmi2_import_free(fmu);
    fmi_import_free_context(ctx);
    fmi_import_rmdir(&cb, tmp);
    cb.free((void *)tmp);
    printf("XML problems %d, calls not OK %d\n", xml_problems, bad_calls);
    printf("outputs %.17g %.17g %.17g\n", v[0], v[1], v[2]);
    return xml_problems || bad_calls;
}
