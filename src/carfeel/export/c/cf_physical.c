/* carfeel: the physical steering model, a port of models/steering/physical.py and
 * models/vehicle/tyres.py (see cf_physical.h). Python's min(a, b) is b < a ? b : a and
 * max(a, b) is b > a ? b : a (the first argument wins a tie, as in Python). */
#include "cf_physical.h"

#include <math.h>

#define STANDARD_GRAVITY_M_S2 9.80665

static double py_min(double a, double b) { return b < a ? b : a; }
static double py_max(double a, double b) { return b > a ? b : a; }

/* tyres.brush: Fy N, Mz Nm, the share of the grip used. */
static double brush(double slip_rad, double load_N, double stiffness_N_rad, double mu,
                    double trail_m, double *mz, double *used) {
    double grip = mu * load_N;
    if (grip <= 0.0) {
        *mz = 0.0;
        *used = 1.0;
        return 0.0;
    }
    double x = stiffness_N_rad * fabs(slip_rad) / (3.0 * grip);
    double sign = slip_rad >= 0.0 ? 1.0 : -1.0;
    if (x >= 1.0) {
        *mz = 0.0;
        *used = 1.0;
        return sign * grip;
    }
    double rest = 1.0 - x;
    double rest3 = rest * rest * rest;
    double share = 1.0 - rest3;
    *mz = trail_m * stiffness_N_rad * slip_rad * rest3;
    *used = share;
    return sign * grip * share;
}

/* tyres.load_sensitive_mu */
static double load_sensitive_mu(double mu, double load_N, double nominal_load_N,
                                double sensitivity) {
    return py_max(0.1 * mu, mu * (1.0 - sensitivity * (load_N / nominal_load_N - 1.0)));
}

/* PhysicalParams.front_load_N, rear_load_N, park_moment_Nm */
static double front_load_N(const cf_physical_params *p) {
    const cf_vehicle_params *v = &p->vehicle;
    return v->mass_kg * STANDARD_GRAVITY_M_S2 * (v->wheelbase_m - v->cg_to_front_axle_m) /
           v->wheelbase_m;
}

static double rear_load_N(const cf_physical_params *p) {
    return p->vehicle.mass_kg * STANDARD_GRAVITY_M_S2 - front_load_N(p);
}

static double park_moment_Nm(const cf_physical_params *p) {
    return 2.0 / 3.0 * p->tyres.friction_coefficient * front_load_N(p) * (p->tyres.patch_radius_m);
}

/* physical._stick: (torque, anchor) of a stick element, its damper acting while it sticks. */
static double stick(double position, double anchor, double level, double stiffness,
                    double rate, double damping, double *new_anchor) {
    double torque = stiffness * (position - anchor);
    if (torque > level) {
        *new_anchor = position - level / stiffness;
        return level;
    }
    if (torque < -level) {
        *new_anchor = position + level / stiffness;
        return -level;
    }
    *new_anchor = anchor;
    torque += damping * rate;
    return py_max(-level, py_min(level, torque));
}

void cf_physical_initial_state(cf_physical_state *s, const cf_physical_params *params,
                               double x_m, double y_m, double yaw_rad,
                               double steering_angle_rad) {
    double a = steering_angle_rad;
    double wheels = a / params->vehicle.steering_ratio;
    s->hand_angle_rad = a;
    s->hand_rate_rad_s = 0.0;
    s->pinion_angle_rad = a;
    s->pinion_rate_rad_s = 0.0;
    s->column_anchor_rad = a;
    s->rack_anchor_rad = a;
    s->park_anchor_rad = wheels;
    s->front_slip_rad = 0.0;
    s->rear_slip_rad = 0.0;
    s->sideslip_rad = 0.0;
    s->yaw_rate_rad_s = 0.0;
    s->x_m = x_m;
    s->y_m = y_m;
    s->yaw_rad = yaw_rad;
    s->lateral_accel_m_s2 = 0.0;
}

void cf_physical_step(cf_physical_state *state, const cf_physical_inputs *inputs,
                      const cf_physical_params *params, double dt_s, cf_physical_outputs *out) {
    const cf_vehicle_params *veh = &params->vehicle;
    const cf_tyre_params *tyr = &params->tyres;
    const cf_system_params *sys = &params->system;
    double v = inputs->speed_m_s;
    double sr = veh->steering_ratio;
    double length = veh->wheelbase_m;
    double a = veh->cg_to_front_axle_m;
    double b = length - a;
    double m = veh->mass_kg;
    double delta = state->pinion_angle_rad / sr;

    double fz_front = front_load_N(params);
    double fz_f = 0.5 * fz_front, fz_r = 0.5 * rear_load_N(params);
    double transfer = m * state->lateral_accel_m_s2 * tyr->cg_height_m / tyr->track_m;
    double dfz_f = 0.5 * tyr->front_roll_share * transfer;
    double dfz_r = 0.5 * transfer - dfz_f;
    double mu = tyr->friction_coefficient;
    double e = tyr->load_sensitivity;

    double beta = state->sideslip_rad, r = state->yaw_rate_rad_s;
    double alpha_f, alpha_r, front, pneumatic, ay, front_used, rear_used;
    if (v >= veh->kinematic_speed_m_s) {
        double k = v * dt_s / tyr->relaxation_length_m;
        alpha_f = (state->front_slip_rad + k * (delta - beta - a * r / v)) / (1.0 + k);
        alpha_r = (state->rear_slip_rad + k * (b * r / v - beta)) / (1.0 + k);
        double cf = 0.5 * veh->front_cornering_stiffness_N_rad;
        double cr = 0.5 * veh->rear_cornering_stiffness_N_rad;
        double t0 = tyr->pneumatic_trail_m;
        double mz1, mz2, mz3, mz4, u1, u2, u3, u4;
        double load = fz_f - dfz_f;
        double fy1 = brush(alpha_f, load, cf, load_sensitive_mu(mu, load, fz_f, e), t0, &mz1, &u1);
        load = fz_f + dfz_f;
        double fy2 = brush(alpha_f, load, cf, load_sensitive_mu(mu, load, fz_f, e), t0, &mz2, &u2);
        load = fz_r - dfz_r;
        double fy3 = brush(alpha_r, load, cr, load_sensitive_mu(mu, load, fz_r, e), t0, &mz3, &u3);
        load = fz_r + dfz_r;
        double fy4 = brush(alpha_r, load, cr, load_sensitive_mu(mu, load, fz_r, e), t0, &mz4, &u4);
        front = fy1 + fy2;
        double rear = fy3 + fy4;
        pneumatic = mz1 + mz2;
        ay = (front + rear) / m;
        beta += dt_s * (ay / v - r);
        r += dt_s * (a * front - b * rear) / veh->yaw_inertia_kg_m2;
        front_used = py_max(u1, u2);
        rear_used = py_max(u3, u4);
    } else {
        alpha_f = alpha_r = 0.0;
        double tan_delta = tan(delta);
        beta = atan(b * tan_delta / length);
        r = v * cos(beta) * tan_delta / length;
        ay = v * r;
        front = m * ay * b / length;
        pneumatic = tyr->pneumatic_trail_m * front;
        front_used = rear_used = 0.0;
    }

    double aligning = (sys->mechanical_trail_m * front + pneumatic) / sr;
    double lam = sys->kingpin_inclination_rad;
    double jacking = fz_front * sys->kingpin_offset_m * sin(lam) * cos(lam) * sin(delta) / sr;
    double k = v * dt_s / tyr->relaxation_length_m;
    double park_anchor = (state->park_anchor_rad + k * delta) / (1.0 + k);
    double park =
        stick(delta, park_anchor, park_moment_Nm(params), tyr->wind_up_stiffness_Nm_rad, 0.0,
              0.0, &park_anchor);
    park /= sr;

    double hand, hand_rate, hand_accel;
    if (inputs->hands_on > 0.5) {
        hand = inputs->steering_angle_rad;
        hand_rate = inputs->steering_rate_rad_s;
        hand_accel = 0.0;
    } else {
        hand = state->hand_angle_rad;
        hand_rate = state->hand_rate_rad_s;
        hand_accel = 0.0;
    }
    double theta = state->pinion_angle_rad, omega = state->pinion_rate_rad_s;
    double bar = sys->torsion_bar_stiffness_Nm_rad * (hand - theta);
    double bar_total = bar + sys->compensation_damping_Nm_s_rad * (hand_rate - omega);
    double fade = v / sys->assist_fade_speed_m_s;
    double low_speed = 1.0 / (1.0 + fade * fade);
    double excess = fabs(bar) - sys->assist_deadband_Nm;
    double boost = 0.0;
    if (excess > 0.0) {
        double gain = sys->assist_gain_high_speed_1_Nm +
                      (sys->assist_gain_standstill_1_Nm - sys->assist_gain_high_speed_1_Nm) *
                          low_speed;
        boost = py_min(sys->max_assist_Nm, gain * excess * excess);
        boost = bar > 0.0 ? boost : -boost;
    }
    double back = v / sys->active_return_fade_speed_m_s;
    double window = py_min(1.0, 0.5 * v) / (1.0 + back * back * back * back);
    double ret = sys->active_return_Nm_rad * theta;
    ret = py_max(-sys->active_return_max_Nm, py_min(sys->active_return_max_Nm, ret)) * window;
    double rack_anchor;
    double rack_friction = stick(theta, state->rack_anchor_rad, sys->rack_friction_Nm,
                                 sys->friction_stiffness_Nm_rad, omega,
                                 sys->presliding_damping_Nm_s_rad, &rack_anchor);
    double eps_damping = sys->eps_damping_high_speed_Nm_s_rad +
                         low_speed * (sys->eps_damping_Nm_s_rad - sys->eps_damping_high_speed_Nm_s_rad);
    eps_damping += sys->eps_damping_rise_Nm_s3_rad_m2 * v * v;
    double damping = (sys->rack_damping_Nm_s_rad + eps_damping) * omega;
    double lock = veh->steering_lock_rad;
    double stop = 0.0;
    if (theta > lock) {
        stop = py_max(0.0, sys->stop_stiffness_Nm_rad * (theta - lock) +
                               sys->stop_damping_Nm_s_rad * omega);
    } else if (theta < -lock) {
        stop = py_min(0.0, sys->stop_stiffness_Nm_rad * (theta + lock) +
                               sys->stop_damping_Nm_s_rad * omega);
    }
    double load_torque = aligning + jacking + park + rack_friction + damping + stop;
    double rack_accel = (bar_total + boost - ret - load_torque) / sys->rack_inertia_kg_m2;
    omega += dt_s * rack_accel;
    theta += dt_s * omega;

    double column_anchor;
    double column = stick(hand, state->column_anchor_rad, sys->column_friction_Nm,
                          sys->friction_stiffness_Nm_rad, hand_rate,
                          sys->presliding_damping_Nm_s_rad, &column_anchor);
    if (inputs->hands_on <= 0.5) {
        hand_accel = (inputs->hand_torque_Nm - bar_total - column) / sys->hand_wheel_inertia_kg_m2;
        hand_rate += dt_s * hand_accel;
        hand += dt_s * hand_rate;
    }

    double yaw = state->yaw_rad + 0.5 * dt_s * (state->yaw_rate_rad_s + r);
    double course = 0.5 * (state->yaw_rad + yaw) + 0.5 * (state->sideslip_rad + beta);
    double x = state->x_m + dt_s * v * cos(course);
    double y = state->y_m + dt_s * v * sin(course);

    double inertia = sys->hand_wheel_inertia_kg_m2 * hand_accel + sys->rack_inertia_kg_m2 * rack_accel;
    double assist = -boost + ret;
    double friction = rack_friction + column;
    double total = aligning + jacking + park + friction + damping + inertia + stop + assist;

    state->hand_angle_rad = hand;
    state->hand_rate_rad_s = hand_rate;
    state->pinion_angle_rad = theta;
    state->pinion_rate_rad_s = omega;
    state->column_anchor_rad = column_anchor;
    state->rack_anchor_rad = rack_anchor;
    state->park_anchor_rad = park_anchor;
    state->front_slip_rad = alpha_f;
    state->rear_slip_rad = alpha_r;
    state->sideslip_rad = beta;
    state->yaw_rate_rad_s = r;
    state->x_m = x;
    state->y_m = y;
    state->yaw_rad = yaw;
    state->lateral_accel_m_s2 = ay;

    out->steering_angle_rad = hand;
    out->steering_rate_rad_s = hand_rate;
    out->lateral_accel_m_s2 = ay;
    out->torque_Nm = total;
    out->torque_aligning_Nm = aligning;
    out->torque_jacking_Nm = jacking;
    out->torque_park_Nm = park;
    out->torque_friction_Nm = friction;
    out->torque_damping_Nm = damping;
    out->torque_inertia_Nm = inertia;
    out->torque_stop_Nm = stop;
    out->torque_assist_Nm = assist;
    out->torsion_bar_torque_Nm = bar_total;
    out->front_wheel_angle_rad = theta / sr;
    out->front_grip_used = front_used;
    out->rear_grip_used = rear_used;
    out->yaw_rate_rad_s = r;
    out->sideslip_rad = beta;
    out->x_m = x;
    out->y_m = y;
    out->yaw_rad = yaw;
}
