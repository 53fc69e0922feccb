/* carfeel FMU "steering", physical model: the step with the inputs of the communication step;
 * the checks of carfeel.io.presets.check_steering (the car, and the steering system's modes at
 * the 1 ms step). */
#include "cf_model_physical.h"

#include <math.h>
#include <stdio.h>
#include <string.h>

void cf_model_clear(cf_model *m) { memset(m, 0, sizeof *m); }

double cf_model_step_size(const cf_model *m) { return m->model_step_s; }

/* preset_checks._check_steering_system: semi-implicit Euler must resolve the stiffest and most
 * damped modes at 1 ms (w*h and c*h/J under 0.5). */
static int check_system(const cf_system_params *s, char *message, size_t size) {
    const double h = 1e-3;
    double rack_stiff =
        s->stop_stiffness_Nm_rad + s->torsion_bar_stiffness_Nm_rad + s->friction_stiffness_Nm_rad;
    double eps = s->eps_damping_Nm_s_rad > s->eps_damping_high_speed_Nm_s_rad
                     ? s->eps_damping_Nm_s_rad
                     : s->eps_damping_high_speed_Nm_s_rad;
    double rack_damp = s->compensation_damping_Nm_s_rad + s->rack_damping_Nm_s_rad +
                       s->stop_damping_Nm_s_rad + eps + s->eps_damping_rise_Nm_s3_rad_m2 * 1e4 +
                       s->presliding_damping_Nm_s_rad;
    const char *names[2] = {"rack_inertia_kg_m2", "hand_wheel_inertia_kg_m2"};
    double inertia[2] = {s->rack_inertia_kg_m2, s->hand_wheel_inertia_kg_m2};
    double stiffness[2] = {rack_stiff,
                           s->torsion_bar_stiffness_Nm_rad + s->friction_stiffness_Nm_rad};
    double damping[2] = {rack_damp,
                         s->compensation_damping_Nm_s_rad + s->presliding_damping_Nm_s_rad};
    for (int i = 0; i < 2; ++i) {
        if (sqrt(stiffness[i] / inertia[i]) * h > 0.5 || damping[i] * h / inertia[i] > 0.5) {
            snprintf(message, size,
                     "steering_system.%s = %g kg*m^2 is too light for its springs (%g Nm/rad) "
                     "and dampers (%g Nm*s/rad) at 1 ms steps: w*h and c*h/J must stay under "
                     "0.5; raise the inertia or soften the springs",
                     names[i], inertia[i], stiffness[i], damping[i]);
            return 1;
        }
    }
    return 0;
}

int cf_model_check(const cf_model *m, char *message, size_t size) {
    if (cf_vehicle_check(&m->params.vehicle, message, size) != 0) {
        return 1;
    }
    return check_system(&m->params.system, message, size);
}

void cf_model_start(cf_model *m) {
    cf_physical_initial_state(&m->state, &m->params, 0.0, 0.0, 0.0, m->inputs.steering_angle_rad);
    memset(&m->outputs, 0, sizeof m->outputs); /* at rest, frictions relaxed: no torque yet */
    m->outputs.steering_angle_rad = m->state.hand_angle_rad;
    m->outputs.front_wheel_angle_rad = m->state.pinion_angle_rad / m->params.vehicle.steering_ratio;
}

void cf_model_step(cf_model *m, double dt_s) {
    cf_physical_step(&m->state, &m->inputs, &m->params, dt_s, &m->outputs);
}
