/* carfeel FMU "shift": the 1-DOF gear engagement (cf_engagement.h) as an FMU's model. */
#ifndef CF_MODEL_SHIFT_H
#define CF_MODEL_SHIFT_H

#include "cf_engagement.h"
#include "cf_fmu.h"

struct cf_model {
    cf_engagement_params gearbox; /* parameters gearbox.* (tunable) */
    int64_t seed;                 /* parameter seed (fixed): the tooth draws */
    double model_step_s;          /* parameter model_step_s (fixed) */
    cf_engagement_inputs inputs;  /* inputs driver_force_N, gate_open, extra_friction_N, wall_* */
    cf_engagement_state state;
    cf_engagement_outputs outputs;         /* outputs position_m ... stage */
    double synchronization_progress;       /* output */
};

#endif
