/* carfeel FMU "steering": the paper's torque law (cf_steering.h) as an FMU's model, its Ay from
 * the importer or from the single-track car; its friction's memory (k10, k11) steps with it. */
#ifndef CF_MODEL_STEERING_H
#define CF_MODEL_STEERING_H

#include <stdint.h>

#include "cf_fmu.h"
#include "cf_steering.h"

/* parameter ay_source: where tau0's lateral acceleration comes from */
enum {
    CF_AY_INPUT = 0,        /* the input lateral_accel_m_s2 (the importer's car) */
    CF_AY_VEHICLE = 1,      /* the FMU's single-track car (carfeel simulate steering) */
    CF_AY_FRONT_AXLE = 2,   /* its front axle's force as an Ay (the 1 kHz loop's default) */
    CF_AY_STEADY_STATE = 3  /* the steady-state Ay of the angle and speed (the paper's) */
};

struct cf_model {
    cf_torque_params torque;   /* parameters torque.* (tunable) */
    cf_vehicle_params vehicle; /* parameters vehicle.* (tunable; width and lock unused) */
    int64_t ay_source;         /* parameter (fixed) */
    double model_step_s;       /* parameter (fixed) */
    double speed_m_s;          /* inputs */
    double lateral_accel_m_s2;
    double steering_angle_rad;
    double steering_rate_rad_s;
    cf_vehicle_state car;
    double friction_memory;    /* the law's state: z of its friction with memory */
    double torque_Nm;          /* outputs */
    double torque_aligning_Nm;
    double torque_tire_spin_Nm;
    double torque_friction_Nm;
    double torque_damping_Nm;
    double model_lateral_accel_m_s2;
    double yaw_rate_rad_s;
    double sideslip_rad;
};

#endif
