/* carfeel FMU "steering", physical model: brush tyres on a nonlinear single-track car and an
 * EPS steering system (cf_physical.h) as an FMU's model. */
#ifndef CF_MODEL_PHYSICAL_H
#define CF_MODEL_PHYSICAL_H

#include "cf_fmu.h"
#include "cf_physical.h"

struct cf_model {
    cf_physical_params params;   /* parameters vehicle.*, tyres.*, steering_system.* (tunable) */
    double model_step_s;         /* parameter (fixed) */
    cf_physical_inputs inputs;   /* inputs speed_m_s ... hands_on */
    cf_physical_state state;
    cf_physical_outputs outputs; /* outputs */
};

#endif
