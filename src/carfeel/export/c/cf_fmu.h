/* carfeel FMU: what the FMI 2 and FMI 3 wrappers share (cf_fmu.c), and what each model provides
 * (cf_model_shift.c, cf_model_steering.c) and the export generates (cf_generated.c).
 *
 * No globals hold state: everything an instance has lives in its cf_instance, so any number of
 * instances of any number of carfeel FMUs run in one process. Written for carfeel; the FMI
 * headers beside it are the standard's (Modelica Association, 2-clause BSD).
 */
#ifndef CF_FMU_H
#define CF_FMU_H

#include <stddef.h>
#include <stdint.h>

/* Status codes: the numbers of fmi2Status and fmi3Status alike. */
enum { CF_OK = 0, CF_WARNING = 1, CF_DISCARD = 2, CF_ERROR = 3, CF_FATAL = 4 };

enum { CF_REAL = 0, CF_INTEGER = 1 };                  /* storage: double, int64_t */
enum { CF_PARAMETER = 0, CF_INPUT = 1, CF_OUTPUT = 2 }; /* causality */
enum { CF_FIXED = 0, CF_TUNABLE = 1, CF_CONTINUOUS = 2, CF_DISCRETE = 3 }; /* variability */

typedef struct {
    unsigned int value_reference;
    int kind;
    int causality;
    int variability;
    size_t offset; /* into struct cf_model */
    double min, max;
    int min_inclusive, max_inclusive;
    const char *name;
    const char *unit;
} cf_variable;

typedef struct cf_model cf_model;

/* Provided by the model. */
void cf_model_clear(cf_model *model); /* what is not a variable: internal defaults */
int cf_model_check(const cf_model *model, char *message, size_t size); /* 0: consistent */
void cf_model_start(cf_model *model);                 /* initial state and outputs */
void cf_model_step(cf_model *model, double dt_s);     /* one model step, inputs held */
double cf_model_step_size(const cf_model *model);     /* its model_step_s */

/* Generated at export: the variables (value references 1..n, in order), the preset's values. */
extern const cf_variable cf_variables[];
extern const size_t cf_variable_count;
extern const size_t cf_model_size;
extern const char cf_token[];
void cf_model_defaults(cf_model *model); /* cf_model_clear, then every start value */

/* An instance, as the wrappers see it. */
enum { CF_MODE_INSTANTIATED, CF_MODE_INITIALIZATION, CF_MODE_STEP, CF_MODE_TERMINATED,
       CF_MODE_ERROR };

typedef void (*cf_logger)(void *instance, int status, const char *category, const char *message);

typedef struct {
    cf_model *model;
    cf_model *backup; /* the model before a set in step mode, restored if that set is refused */
    int mode;
    double time_s;
    double start_time_s;
    int logging_on;
    cf_logger logger;
    void *environment; /* the wrapper's: the importer's environment and callbacks */
    char *name;
} cf_instance;

cf_instance *cf_instantiate(const char *name, const char *token, int logging_on, cf_logger logger,
                            void *environment);
void cf_free(cf_instance *instance);
void cf_log(cf_instance *instance, int status, const char *category, const char *format, ...)
#if defined(__GNUC__)
    __attribute__((format(printf, 4, 5)))
#endif
    ;
int cf_reset(cf_instance *instance);
int cf_enter_initialization(cf_instance *instance, double start_time_s);
int cf_exit_initialization(cf_instance *instance);
int cf_terminate(cf_instance *instance);
int cf_do_step(cf_instance *instance, double current_s, double step_s);

/* Get and set by value reference; `kind` is what the importer's function reads or writes. */
int cf_get_real(cf_instance *instance, const unsigned int vr[], size_t n, double value[]);
int cf_set_real(cf_instance *instance, const unsigned int vr[], size_t n, const double value[]);
int cf_get_integer(cf_instance *instance, const unsigned int vr[], size_t n, int64_t value[]);
int cf_set_integer(cf_instance *instance, const unsigned int vr[], size_t n,
                   const int64_t value[]);
int cf_no_such_variables(cf_instance *instance, const char *function, size_t n);

/* FMU state: a copy of the model and the time. */
typedef struct cf_saved cf_saved;
int cf_get_state(cf_instance *instance, void **state);
int cf_set_state(cf_instance *instance, const void *state);
int cf_free_state(cf_instance *instance, void **state);
size_t cf_serialized_size(void);
int cf_serialize(cf_instance *instance, const void *state, unsigned char *bytes, size_t size);
int cf_deserialize(cf_instance *instance, const unsigned char *bytes, size_t size, void **state);

int cf_unsupported(cf_instance *instance, const char *function);

#endif
