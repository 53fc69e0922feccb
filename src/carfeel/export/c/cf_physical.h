/* carfeel: the physical steering model (models/steering/physical.py: brush tyres on a nonlinear
 * single-track car, and an EPS steering system) with models/vehicle/tyres.py, ported to C.
 *
 * As cf_engagement.h: the same operations in the same order as the Python reference, compiled
 * with -ffp-contract=off -fno-builtin, equal to it bit for bit (tests/test_fmu_port.py).
 * Angles of the steering system in hand-wheel units; torques at the rim, positive
 * counter-clockwise. The parameter structs are the Python dataclasses' fields, in order.
 */
#ifndef CF_PHYSICAL_H
#define CF_PHYSICAL_H

#include "cf_steering.h"

typedef struct {
    double friction_coefficient;
    double load_sensitivity;
    double pneumatic_trail_m;
    double relaxation_length_m;
    double cg_height_m;
    double track_m;
    double front_roll_share;
    double patch_radius_m;
    double wind_up_stiffness_Nm_rad;
} cf_tyre_params;

typedef struct {
    double hand_wheel_inertia_kg_m2;
    double rack_inertia_kg_m2;
    double torsion_bar_stiffness_Nm_rad;
    double compensation_damping_Nm_s_rad;
    double mechanical_trail_m;
    double kingpin_inclination_rad;
    double kingpin_offset_m;
    double column_friction_Nm;
    double rack_friction_Nm;
    double friction_stiffness_Nm_rad;
    double presliding_damping_Nm_s_rad;
    double rack_damping_Nm_s_rad;
    double assist_deadband_Nm;
    double assist_gain_standstill_1_Nm;
    double assist_gain_high_speed_1_Nm;
    double assist_fade_speed_m_s;
    double max_assist_Nm;
    double eps_damping_Nm_s_rad;
    double eps_damping_high_speed_Nm_s_rad;
    double eps_damping_rise_Nm_s3_rad_m2;
    double active_return_Nm_rad;
    double active_return_max_Nm;
    double active_return_fade_speed_m_s;
    double stop_stiffness_Nm_rad;
    double stop_damping_Nm_s_rad;
} cf_system_params;

typedef struct {
    cf_vehicle_params vehicle;
    cf_tyre_params tyres;
    cf_system_params system;
} cf_physical_params;

typedef struct {
    double hand_angle_rad;
    double hand_rate_rad_s;
    double pinion_angle_rad;
    double pinion_rate_rad_s;
    double column_anchor_rad;
    double rack_anchor_rad;
    double park_anchor_rad;
    double front_slip_rad;
    double rear_slip_rad;
    double sideslip_rad;
    double yaw_rate_rad_s;
    double x_m;
    double y_m;
    double yaw_rad;
    double lateral_accel_m_s2;
} cf_physical_state;

typedef struct {
    double speed_m_s;
    double steering_angle_rad;
    double steering_rate_rad_s;
    double hand_torque_Nm;
    double hands_on; /* > 0.5: the rim's angle and rate imposed; else free under hand_torque_Nm */
} cf_physical_inputs;

typedef struct {
    double steering_angle_rad;
    double steering_rate_rad_s;
    double lateral_accel_m_s2;
    double torque_Nm;
    double torque_aligning_Nm;
    double torque_jacking_Nm;
    double torque_park_Nm;
    double torque_friction_Nm;
    double torque_damping_Nm;
    double torque_inertia_Nm;
    double torque_stop_Nm;
    double torque_assist_Nm;
    double torsion_bar_torque_Nm;
    double front_wheel_angle_rad;
    double front_grip_used;
    double rear_grip_used;
    double yaw_rate_rad_s;
    double sideslip_rad;
    double x_m;
    double y_m;
    double yaw_rad;
} cf_physical_outputs;

/* physical.initial_state: still, the rim at steering_angle_rad, frictions relaxed. */
void cf_physical_initial_state(cf_physical_state *state, const cf_physical_params *params,
                               double x_m, double y_m, double yaw_rad,
                               double steering_angle_rad);

/* physical.step: `state` is replaced by the new state. */
void cf_physical_step(cf_physical_state *state, const cf_physical_inputs *inputs,
                      const cf_physical_params *params, double dt_s, cf_physical_outputs *out);

#endif
