/* carfeel FMU "shift": the engagement stepped with the inputs of the communication step; the
 * checks across parameters of carfeel.io.presets.check_shift that concern the gearbox. */
#include "cf_model_shift.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

void cf_model_clear(cf_model *m) {
    memset(m, 0, sizeof *m);
    m->inputs.gate_open = -1;
    m->inputs.gear_inertia_kg_m2 = NAN; /* the chamfer parameters' */
    m->inputs.gear_drag_Nm = NAN;
}

double cf_model_step_size(const cf_model *m) { return m->model_step_s; }

int cf_model_check(const cf_model *m, char *message, size_t size) {
    const cf_engagement_params *g = &m->gearbox;
    const double order[4] = {g->synchronization_position_m, g->teeth_position_m,
                             g->teeth_end_position_m, g->in_gear_position_m};
    static const char *names[4] = {"synchronization_position_m", "teeth_position_m",
                                   "teeth_end_position_m", "in_gear_position_m"};
    for (int i = 0; i < 3; ++i) {
        if (!(order[i] < order[i + 1])) {
            snprintf(message, size,
                     "gearbox.%s = %g m must lie before gearbox.%s = %g m: along the slot the "
                     "synchro ring comes first, then the teeth, then the stop",
                     names[i], order[i], names[i + 1], order[i + 1]);
            return 1;
        }
    }
    const cf_stage_mechanics *stages[7] = {&g->neutral, &g->gate_open,  &g->engagement,
                                           &g->free_travel, &g->stop, &g->in_gear,
                                           &g->returning};
    static const char *stage_names[7] = {"neutral", "gate_open", "engagement", "free_travel",
                                         "stop",    "in_gear",   "returning"};
    for (int i = 0; i < 7; ++i) {
        if (stages[i]->sliding_friction_N > stages[i]->static_friction_N) {
            snprintf(message, size,
                     "gearbox.%s.sliding_friction_N = %g N exceeds gearbox.%s.static_friction_N "
                     "= %g N: allowed 0 <= sliding <= static",
                     stage_names[i], stages[i]->sliding_friction_N, stage_names[i],
                     stages[i]->static_friction_N);
            return 1;
        }
    }
    if (!(g->stop.stiffness_N_m > 0.0) || !(g->in_gear.stiffness_N_m > 0.0)) {
        snprintf(message, size,
                 "gearbox.stop.stiffness_N_m and gearbox.in_gear.stiffness_N_m must be > 0 N/m: "
                 "both stages are springs around the in-gear position");
        return 1;
    }
    if (g->in_gear.stiffness_N_m > g->stop.stiffness_N_m) {
        snprintf(message, size,
                 "gearbox.in_gear.stiffness_N_m = %g N/m exceeds gearbox.stop.stiffness_N_m = %g "
                 "N/m: the lever settles from the stop into the detent, which may be softer but "
                 "not stiffer",
                 g->in_gear.stiffness_N_m, g->stop.stiffness_N_m);
        return 1;
    }
    double held = g->stop.static_friction_N / g->stop.stiffness_N_m;
    if (g->settle_distance_m <= held) {
        snprintf(message, size,
                 "gearbox.settle_distance_m = %g m must exceed the distance the stop's static "
                 "friction can hold the lever off x_gear (%.3g m)",
                 g->settle_distance_m, held);
        return 1;
    }
    double room = g->in_gear_position_m - g->teeth_end_position_m;
    if (g->detent_release_m >= room) {
        snprintf(message, size,
                 "gearbox.detent_release_m = %g m must be shorter than the travel from the teeth "
                 "to the gear (%g m)",
                 g->detent_release_m, room);
        return 1;
    }
    return 0;
}

static void publish(cf_model *m) {
    m->synchronization_progress = m->state.synchronization_progress;
}

void cf_model_start(cf_model *m) {
    cf_engagement_initial_state(&m->state, m->seed, 0.0);
    m->outputs.position_m = m->state.position_m;
    m->outputs.velocity_m_s = 0.0;
    m->outputs.force_N = m->inputs.driver_force_N;
    m->outputs.reaction_N = 0.0;
    m->outputs.stage = m->state.stage;
    publish(m);
}

void cf_model_step(cf_model *m, double dt_s) {
    cf_engagement_step(&m->state, &m->inputs, &m->gearbox, dt_s, &m->outputs);
    publish(m);
}
