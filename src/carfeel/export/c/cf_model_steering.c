/* carfeel FMU "steering": the torque law with the inputs of the communication step; the checks
 * across parameters of carfeel.io.presets.check_steering. */
#include "cf_model_steering.h"

#include <string.h>

void cf_model_clear(cf_model *m) { memset(m, 0, sizeof *m); }

double cf_model_step_size(const cf_model *m) { return m->model_step_s; }

int cf_model_check(const cf_model *m, char *message, size_t size) {
    return cf_vehicle_check(&m->vehicle, message, size);
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
    if (m->torque.k10_Nm != 0.0) { /* torque.torque: the friction's memory */
        double memory = m->torque.k10_Nm * m->friction_memory;
        terms[0] = terms[0] + memory;
        terms[3] = terms[3] + memory;
    }
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
    m->friction_memory = 0.0;
    evaluate(m);
}

void cf_model_step(cf_model *m, double dt_s) {
    if (m->ay_source == CF_AY_VEHICLE || m->ay_source == CF_AY_FRONT_AXLE) {
        cf_vehicle_step(&m->car, m->speed_m_s, m->steering_angle_rad, &m->vehicle, dt_s);
    }
    m->friction_memory =
        cf_friction_memory_step(m->friction_memory, m->steering_rate_rad_s, dt_s, &m->torque);
    evaluate(m);
}
