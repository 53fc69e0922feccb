/* carfeel FMU: instances, modes, get and set by value reference, the communication step as whole
 * model steps, and FMU state (see cf_fmu.h). */
#include "cf_fmu.h"

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* A communication step counts as n model steps when it is within this share of a model step of
 * n of them (the importer's time points carry rounding: 0.01 s is 10.000000000000002 x 1 ms). */
#define CF_STEP_TOLERANCE 1e-6

struct cf_saved {
    uint64_t magic;
    double time_s;
    double start_time_s;
    int mode;
    /* the model follows */
};

#define CF_MAGIC 0x63617266656c3031ULL /* "carfel01" */

static const char *mode_name(int mode) {
    switch (mode) {
    case CF_MODE_INSTANTIATED:
        return "instantiated";
    case CF_MODE_INITIALIZATION:
        return "initialization";
    case CF_MODE_STEP:
        return "step";
    case CF_MODE_TERMINATED:
        return "terminated";
    default:
        return "error";
    }
}

void cf_log(cf_instance *inst, int status, const char *category, const char *format, ...) {
    char message[1024];
    va_list args;
    if (inst == NULL || inst->logger == NULL) {
        return;
    }
    if (status == CF_OK && !inst->logging_on) {
        return;
    }
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    /* The FMI 2 logger takes a printf format: no '%' may reach it unescaped. */
    for (char *c = message; *c; ++c) {
        if (*c == '%') {
            *c = '#';
        }
    }
    inst->logger(inst, status, category, message);
}

static int fail(cf_instance *inst, int status, const char *format, const char *detail) {
    cf_log(inst, status, status >= CF_ERROR ? "logStatusError" : "logStatusWarning", format,
           detail);
    return status;
}

cf_instance *cf_instantiate(const char *name, const char *token, int logging_on, cf_logger logger,
                            void *environment) {
    cf_instance probe = {0};
    probe.logger = logger;
    probe.environment = environment;
    probe.name = (char *)(name ? name : "carfeel");
    if (token == NULL || strcmp(token, cf_token) != 0) {
        cf_log(&probe, CF_ERROR, "logStatusError",
               "instantiation token %s does not match this FMU's %s: the model description and "
               "the binary come from different exports",
               token ? token : "(none)", cf_token);
        return NULL;
    }
    cf_instance *inst = calloc(1, sizeof *inst);
    if (inst == NULL) {
        return NULL;
    }
    size_t length = strlen(probe.name) + 1;
    inst->name = malloc(length);
    inst->model = calloc(1, cf_model_size);
    inst->backup = calloc(1, cf_model_size);
    if (inst->name == NULL || inst->model == NULL || inst->backup == NULL) {
        cf_free(inst);
        return NULL;
    }
    memcpy(inst->name, probe.name, length);
    inst->logging_on = logging_on;
    inst->logger = logger;
    inst->environment = environment;
    cf_reset(inst);
    return inst;
}

void cf_free(cf_instance *inst) {
    if (inst == NULL) {
        return;
    }
    free(inst->model);
    free(inst->backup);
    free(inst->name);
    free(inst);
}

int cf_reset(cf_instance *inst) {
    cf_model_defaults(inst->model);
    inst->mode = CF_MODE_INSTANTIATED;
    inst->time_s = 0.0;
    inst->start_time_s = 0.0;
    return CF_OK;
}

static int in_mode(cf_instance *inst, const char *function, int allowed_mask) {
    if (inst == NULL) {
        return 0;
    }
    if (allowed_mask & (1 << inst->mode)) {
        return 1;
    }
    cf_log(inst, CF_ERROR, "logStatusError", "%s is not allowed in %s mode", function,
           mode_name(inst->mode));
    return 0;
}

#define M(mode) (1 << (mode))

int cf_enter_initialization(cf_instance *inst, double start_time_s) {
    if (!in_mode(inst, "EnterInitializationMode", M(CF_MODE_INSTANTIATED))) {
        return CF_ERROR;
    }
    inst->start_time_s = start_time_s;
    inst->time_s = start_time_s;
    inst->mode = CF_MODE_INITIALIZATION;
    return CF_OK;
}

int cf_exit_initialization(cf_instance *inst) {
    char message[512];
    if (!in_mode(inst, "ExitInitializationMode", M(CF_MODE_INITIALIZATION))) {
        return CF_ERROR;
    }
    if (cf_model_check(inst->model, message, sizeof message) != 0) {
        return fail(inst, CF_ERROR, "the parameters are not consistent: %s", message);
    }
    cf_model_start(inst->model);
    inst->mode = CF_MODE_STEP;
    return CF_OK;
}

int cf_terminate(cf_instance *inst) {
    if (!in_mode(inst, "Terminate", M(CF_MODE_STEP) | M(CF_MODE_INITIALIZATION))) {
        return CF_ERROR;
    }
    inst->mode = CF_MODE_TERMINATED;
    return CF_OK;
}

int cf_do_step(cf_instance *inst, double current_s, double step_s) {
    if (!in_mode(inst, "DoStep", M(CF_MODE_STEP))) {
        return CF_ERROR;
    }
    double h = cf_model_step_size(inst->model);
    if (!(step_s > 0.0) || !isfinite(step_s)) {
        cf_log(inst, CF_ERROR, "logStatusError",
               "communication step %.17g s: it must be a positive multiple of the model step "
               "model_step_s = %g s",
               step_s, h);
        return CF_ERROR;
    }
    double steps = floor(step_s / h + 0.5);
    if (steps < 1.0 || fabs(steps * h - step_s) > CF_STEP_TOLERANCE * h) {
        cf_log(inst, CF_ERROR, "logStatusError",
               "communication step %.17g s is not a whole multiple of the model step "
               "model_step_s = %g s: use a multiple of it (the model steps with its inputs held "
               "over the communication step), or set model_step_s before initialization",
               step_s, h);
        return CF_ERROR;
    }
    for (long k = 0; k < (long)steps; ++k) {
        cf_model_step(inst->model, h);
    }
    inst->time_s = current_s + step_s;
    return CF_OK;
}

static const cf_variable *find(cf_instance *inst, unsigned int vr, const char *function) {
    if (vr >= 1 && vr <= cf_variable_count) {
        const cf_variable *v = &cf_variables[vr - 1];
        if (v->value_reference == vr) {
            return v;
        }
    }
    cf_log(inst, CF_ERROR, "logStatusError", "%s: no variable has value reference %u", function,
           vr);
    return NULL;
}

static double *real_at(cf_model *model, const cf_variable *v) {
    return (double *)(void *)((char *)model + v->offset);
}

static int64_t *integer_at(cf_model *model, const cf_variable *v) {
    return (int64_t *)(void *)((char *)model + v->offset);
}

/* Whether `value` may be written into `v` now; logs why not. */
static int settable(cf_instance *inst, const cf_variable *v, double value) {
    if (v->causality == CF_OUTPUT) {
        cf_log(inst, CF_ERROR, "logStatusError",
               "%s is an output: the model computes it, it cannot be set", v->name);
        return 0;
    }
    if (v->causality == CF_PARAMETER && v->variability == CF_FIXED &&
        inst->mode != CF_MODE_INSTANTIATED && inst->mode != CF_MODE_INITIALIZATION) {
        cf_log(inst, CF_ERROR, "logStatusError",
               "%s is a fixed parameter: set it before initialization ends (now in %s mode)",
               v->name, mode_name(inst->mode));
        return 0;
    }
    if (!isfinite(value)) {
        cf_log(inst, CF_ERROR, "logStatusError", "%s = %g %s is not finite; give a number",
               v->name, value, v->unit);
        return 0;
    }
    int above = v->min_inclusive ? value >= v->min : value > v->min;
    int below = v->max_inclusive ? value <= v->max : value < v->max;
    if (!above || !below) {
        cf_log(inst, CF_ERROR, "logStatusError",
               "%s = %g %s is out of range: allowed %g %s value %s %g %s", v->name, value,
               v->unit, v->min, v->min_inclusive ? "<=" : "<", v->max_inclusive ? "<=" : "<",
               v->max, v->unit);
        return 0;
    }
    return 1;
}

static int can_set(cf_instance *inst, const char *function) {
    return in_mode(inst, function,
                   M(CF_MODE_INSTANTIATED) | M(CF_MODE_INITIALIZATION) | M(CF_MODE_STEP));
}

static int can_get(cf_instance *inst, const char *function) {
    return in_mode(inst, function,
                   M(CF_MODE_INSTANTIATED) | M(CF_MODE_INITIALIZATION) | M(CF_MODE_STEP) |
                       M(CF_MODE_TERMINATED) | M(CF_MODE_ERROR));
}

/* In step mode a set of tunable parameters must leave the model consistent, or it is undone. */
static int begin_set(cf_instance *inst) {
    if (inst->mode == CF_MODE_STEP) {
        memcpy(inst->backup, inst->model, cf_model_size);
    }
    return CF_OK;
}

static int end_set(cf_instance *inst, int status, int changed_parameter) {
    char message[512];
    if (inst->mode != CF_MODE_STEP) {
        return status;
    }
    if (status == CF_OK && changed_parameter &&
        cf_model_check(inst->model, message, sizeof message) != 0) {
        cf_log(inst, CF_ERROR, "logStatusError",
               "the parameters would not be consistent (%s): the values were not set", message);
        status = CF_ERROR;
    }
    if (status != CF_OK) {
        memcpy(inst->model, inst->backup, cf_model_size);
    }
    return status;
}

int cf_get_real(cf_instance *inst, const unsigned int vr[], size_t n, double value[]) {
    if (!can_get(inst, "GetReal")) {
        return CF_ERROR;
    }
    for (size_t i = 0; i < n; ++i) {
        const cf_variable *v = find(inst, vr[i], "GetReal");
        if (v == NULL) {
            return CF_ERROR;
        }
        if (v->kind != CF_REAL) {
            return fail(inst, CF_ERROR, "%s is not a real variable", v->name);
        }
        value[i] = *real_at(inst->model, v);
    }
    return CF_OK;
}

int cf_set_real(cf_instance *inst, const unsigned int vr[], size_t n, const double value[]) {
    int status = CF_OK, parameter = 0;
    if (!can_set(inst, "SetReal")) {
        return CF_ERROR;
    }
    begin_set(inst);
    for (size_t i = 0; i < n && status == CF_OK; ++i) {
        const cf_variable *v = find(inst, vr[i], "SetReal");
        if (v == NULL) {
            status = CF_ERROR;
        } else if (v->kind != CF_REAL) {
            status = fail(inst, CF_ERROR, "%s is not a real variable", v->name);
        } else if (!settable(inst, v, value[i])) {
            status = CF_ERROR;
        } else {
            *real_at(inst->model, v) = value[i];
            parameter |= v->causality == CF_PARAMETER;
        }
    }
    return end_set(inst, status, parameter);
}

int cf_get_integer(cf_instance *inst, const unsigned int vr[], size_t n, int64_t value[]) {
    if (!can_get(inst, "GetInteger")) {
        return CF_ERROR;
    }
    for (size_t i = 0; i < n; ++i) {
        const cf_variable *v = find(inst, vr[i], "GetInteger");
        if (v == NULL) {
            return CF_ERROR;
        }
        if (v->kind != CF_INTEGER) {
            return fail(inst, CF_ERROR, "%s is not an integer variable", v->name);
        }
        value[i] = *integer_at(inst->model, v);
    }
    return CF_OK;
}

int cf_set_integer(cf_instance *inst, const unsigned int vr[], size_t n, const int64_t value[]) {
    int status = CF_OK, parameter = 0;
    if (!can_set(inst, "SetInteger")) {
        return CF_ERROR;
    }
    begin_set(inst);
    for (size_t i = 0; i < n && status == CF_OK; ++i) {
        const cf_variable *v = find(inst, vr[i], "SetInteger");
        if (v == NULL) {
            status = CF_ERROR;
        } else if (v->kind != CF_INTEGER) {
            status = fail(inst, CF_ERROR, "%s is not an integer variable", v->name);
        } else if (!settable(inst, v, (double)value[i])) {
            status = CF_ERROR;
        } else {
            *integer_at(inst->model, v) = value[i];
            parameter |= v->causality == CF_PARAMETER;
        }
    }
    return end_set(inst, status, parameter);
}

int cf_no_such_variables(cf_instance *inst, const char *function, size_t n) {
    if (n == 0) {
        return CF_OK;
    }
    return fail(inst, CF_ERROR, "%s: this FMU has no variables of that type", function);
}

int cf_unsupported(cf_instance *inst, const char *function) {
    return fail(inst, CF_ERROR, "%s is not supported by this co-simulation FMU", function);
}

/* FMU state */

int cf_get_state(cf_instance *inst, void **state) {
    if (!can_get(inst, "GetFMUState")) {
        return CF_ERROR;
    }
    cf_saved *saved = *state;
    if (saved == NULL) {
        saved = calloc(1, cf_serialized_size());
        if (saved == NULL) {
            return fail(inst, CF_ERROR, "%s: out of memory", "GetFMUState");
        }
    }
    saved->magic = CF_MAGIC;
    saved->time_s = inst->time_s;
    saved->start_time_s = inst->start_time_s;
    saved->mode = inst->mode;
    memcpy((char *)saved + sizeof *saved, inst->model, cf_model_size);
    *state = saved;
    return CF_OK;
}

int cf_set_state(cf_instance *inst, const void *state) {
    const cf_saved *saved = state;
    if (!can_set(inst, "SetFMUState")) {
        return CF_ERROR;
    }
    if (saved == NULL || saved->magic != CF_MAGIC) {
        return fail(inst, CF_ERROR, "%s: not a state of this FMU", "SetFMUState");
    }
    inst->time_s = saved->time_s;
    inst->start_time_s = saved->start_time_s;
    inst->mode = saved->mode;
    memcpy(inst->model, (const char *)saved + sizeof *saved, cf_model_size);
    return CF_OK;
}

int cf_free_state(cf_instance *inst, void **state) {
    (void)inst;
    if (state != NULL) {
        free(*state);
        *state = NULL;
    }
    return CF_OK;
}

size_t cf_serialized_size(void) { return sizeof(cf_saved) + cf_model_size; }

int cf_serialize(cf_instance *inst, const void *state, unsigned char *bytes, size_t size) {
    if (state == NULL || size < cf_serialized_size()) {
        return fail(inst, CF_ERROR, "%s: no state, or a buffer too small", "SerializeFMUState");
    }
    memcpy(bytes, state, cf_serialized_size());
    return CF_OK;
}

int cf_deserialize(cf_instance *inst, const unsigned char *bytes, size_t size, void **state) {
    cf_saved header;
    if (size != cf_serialized_size()) {
        return fail(inst, CF_ERROR, "%s: the bytes are not a state of this FMU",
                    "DeserializeFMUState");
    }
    memcpy(&header, bytes, sizeof header);
    if (header.magic != CF_MAGIC) {
        return fail(inst, CF_ERROR, "%s: the bytes are not a state of this FMU",
                    "DeserializeFMUState");
    }
    void *copy = *state != NULL ? *state : malloc(size);
    if (copy == NULL) {
        return fail(inst, CF_ERROR, "%s: out of memory", "DeserializeFMUState");
    }
    memcpy(copy, bytes, size);
    *state = copy;
    return CF_OK;
}
