/* carfeel: the steering torque law and the single-track car, a port of
 * models/steering/torque.py and models/vehicle/single_track.py (see cf_steering.h). */
#include "cf_steering.h"

#include <math.h>
#include <stdio.h>

/* torque.torque_terms; Python's abs(ay) ** k3 is libm's pow(fabs(ay), k3). */
void cf_torque_terms(double speed_m_s, double steering_rate_rad_s, double lateral_accel_m_s2,
                     const cf_torque_params *p, double terms[5]) {
    double ay = lateral_accel_m_s2;
    double rate = steering_rate_rad_s;
    double aligning = p->k1_Nm_s2_m * ay / (1.0 + p->k2 * pow(fabs(ay), p->k3));
    double tire_spin = atan(rate / p->k6_rad_s) / (p->k4_1_Nm + p->k5_s_m_Nm * fabs(speed_m_s));
    double friction = p->k7_Nm * atan(rate / p->k8_rad_s);
    double damping = p->k9_Nm_s_rad * rate;
    terms[0] = aligning + tire_spin + friction + damping;
    terms[1] = aligning;
    terms[2] = tire_spin;
    terms[3] = friction;
    terms[4] = damping;
}

double cf_friction_memory_step(double z, double steering_rate_rad_s, double dt_s,
                               const cf_torque_params *p) {
    double turned = fabs(steering_rate_rad_s) * dt_s;
    if (turned == 0.0) {
        return z;
    }
    double target = steering_rate_rad_s > 0.0 ? 1.0 : -1.0;
    return target + (z - target) * exp(-turned / p->k11_rad);
}

/* VehicleParams.cg_to_rear_axle_m */
static double rear(const cf_vehicle_params *p) { return p->wheelbase_m - p->cg_to_front_axle_m; }

double cf_understeer_gradient(const cf_vehicle_params *p) {
    return p->mass_kg / p->wheelbase_m *
           (rear(p) / p->front_cornering_stiffness_N_rad -
            p->cg_to_front_axle_m / p->rear_cornering_stiffness_N_rad);
}

double cf_steady_state_lateral_accel(double speed_m_s, double steering_wheel_angle_rad,
                                     const cf_vehicle_params *p) {
    double delta = steering_wheel_angle_rad / p->steering_ratio;
    double stability = cf_understeer_gradient(p) / p->wheelbase_m;
    double v2 = speed_m_s * speed_m_s;
    return v2 * delta / (p->wheelbase_m * (1.0 + stability * v2));
}

void cf_vehicle_initial_state(cf_vehicle_state *s, double x_m, double y_m, double yaw_rad) {
    s->sideslip_rad = 0.0;
    s->yaw_rate_rad_s = 0.0;
    s->x_m = x_m;
    s->y_m = y_m;
    s->yaw_rad = yaw_rad;
    s->lateral_accel_m_s2 = 0.0;
    s->front_wheel_angle_rad = 0.0;
}

/* single_track.front_axle_force_N */
static double front_axle_force_N(const cf_vehicle_state *s, double speed_m_s,
                                 const cf_vehicle_params *p) {
    if (speed_m_s < p->kinematic_speed_m_s) {
        return p->mass_kg * s->lateral_accel_m_s2 * rear(p) / p->wheelbase_m;
    }
    return p->front_cornering_stiffness_N_rad *
           (s->front_wheel_angle_rad - s->sideslip_rad -
            p->cg_to_front_axle_m * s->yaw_rate_rad_s / speed_m_s);
}

double cf_aligning_lateral_accel(const cf_vehicle_state *s, double speed_m_s,
                                 const cf_vehicle_params *p) {
    return front_axle_force_N(s, speed_m_s, p) * p->wheelbase_m / (p->mass_kg * rear(p));
}

/* single_track._derivatives, its Ay only. */
static double derivative_ay(double beta, double r, double delta, double v,
                            const cf_vehicle_params *p) {
    double a = p->cg_to_front_axle_m;
    double b = rear(p);
    double front = p->front_cornering_stiffness_N_rad * (delta - beta - a * r / v);
    double back = p->rear_cornering_stiffness_N_rad * (-beta + b * r / v);
    return (front + back) / p->mass_kg;
}

void cf_vehicle_step(cf_vehicle_state *s, double speed_m_s, double steering_angle_rad,
                     const cf_vehicle_params *p, double dt_s) {
    double v = speed_m_s;
    double delta = steering_angle_rad / p->steering_ratio;
    double beta, r, ay;
    if (v < p->kinematic_speed_m_s) {
        double tan_delta = tan(delta);
        beta = atan(rear(p) * tan_delta / p->wheelbase_m);
        r = v * cos(beta) * tan_delta / p->wheelbase_m;
        ay = v * r;
    } else {
        double a = p->cg_to_front_axle_m;
        double b = rear(p);
        double cf = p->front_cornering_stiffness_N_rad;
        double cr = p->rear_cornering_stiffness_N_rad;
        double m_v = p->mass_kg * v;
        double a11 = -(cf + cr) / m_v;
        double a12 = -1.0 - (a * cf - b * cr) / (m_v * v);
        double a21 = -(a * cf - b * cr) / p->yaw_inertia_kg_m2;
        double a22 = -(a * a * cf + b * b * cr) / (p->yaw_inertia_kg_m2 * v);
        double b1 = cf / m_v;
        double b2 = a * cf / p->yaw_inertia_kg_m2;
        double h2 = 0.5 * dt_s;
        double beta0 = s->sideslip_rad, r0 = s->yaw_rate_rad_s;
        double delta_mean = 0.5 * (s->front_wheel_angle_rad + delta);
        double rhs1 = beta0 + h2 * (a11 * beta0 + a12 * r0) + dt_s * b1 * delta_mean;
        double rhs2 = r0 + h2 * (a21 * beta0 + a22 * r0) + dt_s * b2 * delta_mean;
        double m11 = 1.0 - h2 * a11, m12 = -h2 * a12;
        double m21 = -h2 * a21, m22 = 1.0 - h2 * a22;
        double det = m11 * m22 - m12 * m21;
        beta = (rhs1 * m22 - m12 * rhs2) / det;
        r = (m11 * rhs2 - m21 * rhs1) / det;
        ay = derivative_ay(beta, r, delta, v, p);
    }
    double yaw = s->yaw_rad + 0.5 * dt_s * (s->yaw_rate_rad_s + r);
    double course = 0.5 * (s->yaw_rad + yaw) + 0.5 * (s->sideslip_rad + beta);
    double x = s->x_m + dt_s * v * cos(course);
    double y = s->y_m + dt_s * v * sin(course);
    s->sideslip_rad = beta;
    s->yaw_rate_rad_s = r;
    s->x_m = x;
    s->y_m = y;
    s->yaw_rad = yaw;
    s->lateral_accel_m_s2 = ay;
    s->front_wheel_angle_rad = delta;
}

/* The checks of carfeel.io.presets.check_steering on the car; 0 when it passes, else the
 * problem in `message`. */
int cf_vehicle_check(const cf_vehicle_params *v, char *message, size_t size) {
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

