/* carfeel FMU: the FMI 2.0 co-simulation interface over cf_fmu.c. Every function of
 * fmi2Functions.h is exported; those of model exchange and the ones this FMU has no use for
 * return fmi2Error with a message. Written for carfeel against the standard's headers. */
#include <stdlib.h>
#include <string.h>

#include "cf_fmu.h"
#include "fmi2Functions.h"

typedef struct {
    cf_instance *instance;
    fmi2CallbackFunctions callbacks;
} wrapper;

/* cf_instance.environment points at the wrapper, which holds the importer's callbacks. */
static void log_fmi2(void *instance, int status, const char *category, const char *message) {
    cf_instance *inst = instance;
    wrapper *w = inst->environment;
    if (w->callbacks.logger != NULL) {
        w->callbacks.logger(w->callbacks.componentEnvironment, inst->name, (fmi2Status)status,
                            category, message);
    }
}

#define INSTANCE(c) (((wrapper *)(c))->instance)
#define CHECK(c)                                                                                  \
    do {                                                                                          \
        if ((c) == NULL) {                                                                        \
            return fmi2Error;                                                                     \
        }                                                                                         \
    } while (0)

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    (void)nCategories;
    (void)categories;
    CHECK(c);
    INSTANCE(c)->logging_on = loggingOn != fmi2False;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    (void)fmuResourceLocation;
    (void)visible;
    wrapper *w = calloc(1, sizeof *w);
    if (w == NULL) {
        return NULL;
    }
    if (functions != NULL) {
        w->callbacks = *functions;
    }
    if (fmuType != fmi2CoSimulation) {
        if (w->callbacks.logger != NULL) {
            w->callbacks.logger(w->callbacks.componentEnvironment, instanceName, fmi2Error,
                                "logStatusError",
                                "this FMU supports co-simulation only, not model exchange");
        }
        free(w);
        return NULL;
    }
    /* cf_instantiate logs through a probe whose environment must already be this wrapper. */
    w->instance = cf_instantiate(instanceName, fmuGUID, loggingOn != fmi2False, log_fmi2, w);
    if (w->instance == NULL) {
        free(w);
        return NULL;
    }
    return w;
}

void fmi2FreeInstance(fmi2Component c) {
    if (c == NULL) {
        return;
    }
    cf_free(INSTANCE(c));
    free(c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined,
                               fmi2Real stopTime) {
    (void)toleranceDefined;
    (void)tolerance;
    (void)stopTimeDefined;
    (void)stopTime;
    CHECK(c);
    INSTANCE(c)->start_time_s = startTime;
    INSTANCE(c)->time_s = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_enter_initialization(INSTANCE(c), INSTANCE(c)->start_time_s);
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_exit_initialization(INSTANCE(c));
}

fmi2Status fmi2Terminate(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_terminate(INSTANCE(c));
}

fmi2Status fmi2Reset(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_reset(INSTANCE(c));
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    CHECK(c);
    return (fmi2Status)cf_get_real(INSTANCE(c), vr, nvr, value);
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    CHECK(c);
    return (fmi2Status)cf_set_real(INSTANCE(c), vr, nvr, value);
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    CHECK(c);
    for (size_t i = 0; i < nvr; ++i) {
        int64_t wide;
        int status = cf_get_integer(INSTANCE(c), &vr[i], 1, &wide);
        if (status != CF_OK) {
            return (fmi2Status)status;
        }
        value[i] = (fmi2Integer)wide;
    }
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    CHECK(c);
    int64_t stack[64] = {0};
    int64_t *wide = nvr <= 64 ? stack : malloc(nvr * sizeof *wide);
    if (wide == NULL) {
        return fmi2Error;
    }
    for (size_t i = 0; i < nvr; ++i) {
        wide[i] = value[i];
    }
    int status = cf_set_integer(INSTANCE(c), vr, nvr, wide);
    if (wide != stack) {
        free(wide);
    }
    return (fmi2Status)status;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_no_such_variables(INSTANCE(c), "fmi2GetBoolean", nvr);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_no_such_variables(INSTANCE(c), "fmi2SetBoolean", nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_no_such_variables(INSTANCE(c), "fmi2GetString", nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_no_such_variables(INSTANCE(c), "fmi2SetString", nvr);
}

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK(c);
    return (fmi2Status)cf_get_state(INSTANCE(c), FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    CHECK(c);
    return (fmi2Status)cf_set_state(INSTANCE(c), FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    CHECK(c);
    return (fmi2Status)cf_free_state(INSTANCE(c), FMUstate);
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    (void)FMUstate;
    CHECK(c);
    *size = cf_serialized_size();
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serialized[],
                                 size_t size) {
    CHECK(c);
    return (fmi2Status)cf_serialize(INSTANCE(c), FMUstate, (unsigned char *)serialized, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serialized[], size_t size,
                                   fmi2FMUstate *FMUstate) {
    CHECK(c);
    return (fmi2Status)cf_deserialize(INSTANCE(c), (const unsigned char *)serialized, size,
                                      FMUstate);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetDirectionalDerivative");
}

/* Model exchange: not offered. */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2EnterEventMode");
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    (void)eventInfo;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2NewDiscreteStates");
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2EnterContinuousTimeMode");
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c,
                                       fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode,
                                       fmi2Boolean *terminateSimulation) {
    (void)noSetFMUStatePriorToCurrentPoint;
    (void)enterEventMode;
    (void)terminateSimulation;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2CompletedIntegratorStep");
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    (void)time;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2SetTime");
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    (void)x;
    (void)nx;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    (void)derivatives;
    (void)nx;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    (void)eventIndicators;
    (void)ni;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    (void)x;
    (void)nx;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    (void)x_nominal;
    (void)nx;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetNominalsOfContinuousStates");
}

/* Co-simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                       size_t nvr, const fmi2Integer order[],
                                       const fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2SetRealInputDerivatives (inputs are held "
                                                   "over a communication step)");
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[],
                                        size_t nvr, const fmi2Integer order[],
                                        fmi2Real value[]) {
    (void)vr;
    (void)nvr;
    (void)order;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetRealOutputDerivatives");
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(c);
    return (fmi2Status)cf_do_step(INSTANCE(c), currentCommunicationPoint, communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2CancelStep (steps are never pending)");
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetStatus (steps are never pending)");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    CHECK(c);
    if (s == fmi2LastSuccessfulTime) {
        *value = INSTANCE(c)->time_s;
        return fmi2OK;
    }
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetRealStatus of this kind");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    CHECK(c);
    if (s == fmi2Terminated) {
        *value = fmi2False;
        return fmi2OK;
    }
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetBooleanStatus of this kind");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s;
    (void)value;
    CHECK(c);
    return (fmi2Status)cf_unsupported(INSTANCE(c), "fmi2GetStringStatus");
}
