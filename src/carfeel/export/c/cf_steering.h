/* carfeel: the paper's steering wheel torque law (models/steering/torque.py) and the linear
 * single-track car that can feed it (models/vehicle/single_track.py), ported to C.
 *
 * As cf_engagement.h: the same operations in the same order as the Python reference, compiled
 * with -ffp-contract=off -fno-builtin, equal to it bit for bit (tests/test_fmu_port.py).
 * Signs: angle, rate, Ay and torque positive to the left (counter-clockwise). SI units; the
 * parameter structs are the Python dataclasses' fields, in their order, all doubles.
 */
#ifndef CF_STEERING_H
#define CF_STEERING_H

#include <stddef.h>

typedef struct {
    double k1_Nm_s2_m;
    double k2;
    double k3;
    double k4_1_Nm;
    double k5_s_m_Nm;
    double k6_rad_s;
    double k7_Nm;
    double k8_rad_s;
    double k9_Nm_s_rad;
    double k10_Nm;  /* the friction with memory: level (0: off) */
    double k11_rad; /* and the angle it builds over after a reversal */
} cf_torque_params;

typedef struct {
    double mass_kg;
    double yaw_inertia_kg_m2;
    double wheelbase_m;
    double cg_to_front_axle_m;
    double front_cornering_stiffness_N_rad;
    double rear_cornering_stiffness_N_rad;
    double steering_ratio;
    double width_m;
    double steering_lock_rad;
    double kinematic_speed_m_s;
} cf_vehicle_params;

typedef struct {
    double sideslip_rad;
    double yaw_rate_rad_s;
    double x_m;
    double y_m;
    double yaw_rad;
    double lateral_accel_m_s2;
    double front_wheel_angle_rad;
} cf_vehicle_state;

/* torque.torque_terms: terms[0..4] = tau, tau0 (aligning), tau1 (tire spin), tau2 (friction),
 * tau3 (damping), Nm. */
void cf_torque_terms(double speed_m_s, double steering_rate_rad_s, double lateral_accel_m_s2,
                     const cf_torque_params *params, double terms[5]);

/* torque.friction_memory_step: the friction memory z after dt_s with the rate held (the Dahl
 * element, exact); the torque adds k10_Nm * z to tau2 and tau. */
double cf_friction_memory_step(double z, double steering_rate_rad_s, double dt_s,
                               const cf_torque_params *params);

/* single_track.initial_state: driving straight at the pose. */
void cf_vehicle_initial_state(cf_vehicle_state *state, double x_m, double y_m, double yaw_rad);

/* single_track.step: advance the car by dt_s at the speed and steering wheel angle. */
void cf_vehicle_step(cf_vehicle_state *state, double speed_m_s, double steering_angle_rad,
                     const cf_vehicle_params *params, double dt_s);

/* single_track.aligning_lateral_accel: the Ay the front axle's force stands for, m/s^2. */
double cf_aligning_lateral_accel(const cf_vehicle_state *state, double speed_m_s,
                                 const cf_vehicle_params *params);

/* single_track.steady_state_lateral_accel, m/s^2. */
double cf_steady_state_lateral_accel(double speed_m_s, double steering_wheel_angle_rad,
                                     const cf_vehicle_params *params);

/* VehicleParams.understeer_gradient_rad_s2_m */
double cf_understeer_gradient(const cf_vehicle_params *params);

/* carfeel.io.presets.check_steering's checks of the car: 0 if it passes, else 1 and why. */
int cf_vehicle_check(const cf_vehicle_params *params, char *message, size_t size);

#endif
