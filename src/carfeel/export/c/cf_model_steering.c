/* carfeel FMU "steering": the torque law with the inputs of the communication step; the checks
 * across parameters of carfeel.io.presets.check_steering. */
#include "cf_model_steering.h"

#include <stdio.h>
#include <string.h>

void cf_model_clear(cf_model *m) { memset(m, 0, sizeof *m); }

double cf_model_step_size(const cf_model *m) { return m->model_step_s; }

int cf_model_check(const cf_model *m, char *message, size_t size) {
    const cf_vehicle_params *v = &m->vehicle;
    if (!(v->cg_to_front_axle_m < v->wheelbase_m)) {
        snprintf(message, size,
                 "vehicle.cg_to_front_axle_m = %g m must be shorter than vehicle.wheelbase_m = "
                 "%g m (the centre of gravity lies between the axles)",
                 v->cg_to_front_axle_m, v->wheelbase_m);
        return 1;
    }
    if (cf_understeer_gradient(v) < 0.0) {
        snprintf(message, size,
                 "the vehicle oversteers: a linear oversteering car is unstable above its critical "
                 "speed; raise vehicle.rear_cornering_stiffness_N_rad or move the centre of "
                 "gravity forward");
        return 1;
    }
    double b = v->wheelbase_m - v->cg_to_front_axle_m;
    double lateral = v->mass_kg * v->kinematic_speed_m_s /
                     (v->front_cornering_stiffness_N_rad + v->rear_cornering_stiffness_N_rad);
    double yaw = v->yaw_inertia_kg_m2 * v->kinematic_speed_m_s /
                 (v->cg_to_front_axle_m * v->cg_to_front_axle_m *
                      v->front_cornering_stiffness_N_rad +
                  b * b * v->rear_cornering_stiffness_N_rad);
    double shortest = lateral < yaw ? lateral : yaw;
    if (shortest < 1e-3) {
        snprintf(message, size,
                 "at vehicle.kinematic_speed_m_s = %g m/s the tyres' time constant is %.3g ms, "
                 "under the 1 ms the model steps with; raise kinematic_speed_m_s or check the "
                 "mass, inertia and cornering stiffnesses",
                 v->kinematic_speed_m_s, shortest * 1e3);
        return 1;
    }
    return 0;
}

static void evaluate(cf_model *m) {
    double ay;
    switch (m->ay_source) {
    case CF_AY_VEHICLE:
        ay = m->car.lateral_accel_m_s2;
        break;
    case CF_AY_FRONT_AXLE:
        ay = cf_aligning_lateral_accel(&m->car, m->speed_m_s, &m->vehicle);
        break;
    case CF_AY_STEADY_STATE:
        ay = cf_steady_state_lateral_accel(m->speed_m_s, m->steering_angle_rad, &m->vehicle);
        break;
    default:
        ay = m->lateral_accel_m_s2;
        break;
    }
    double terms[5];
    cf_torque_terms(m->speed_m_s, m->steering_rate_rad_s, ay, &m->torque, terms);
    m->torque_Nm = terms[0];
    m->torque_aligning_Nm = terms[1];
    m->torque_tire_spin_Nm = terms[2];
    m->torque_friction_Nm = terms[3];
    m->torque_damping_Nm = terms[4];
    m->model_lateral_accel_m_s2 = ay;
    m->yaw_rate_rad_s = m->car.yaw_rate_rad_s;
    m->sideslip_rad = m->car.sideslip_rad;
}

void cf_model_start(cf_model *m) {
    cf_vehicle_initial_state(&m->car, 0.0, 0.0, 0.0);
    evaluate(m);
}

void cf_model_step(cf_model *m, double dt_s) {
    if (m->ay_source == CF_AY_VEHICLE || m->ay_source == CF_AY_FRONT_AXLE) {
        cf_vehicle_step(&m->car, m->speed_m_s, m->steering_angle_rad, &m->vehicle, dt_s);
    }
    evaluate(m);
}
