/* carfeel: runs of the C ports over recorded inputs, for comparing them with the Python models
 * and timing them (tests/test_fmu_port.py, benchmarks/bench_fmu.py). Not part of an FMU. */
#include <stddef.h>
#include <stdint.h>

#include "cf_engagement.h"
#include "cf_physical.h"
#include "cf_steering.h"

#if defined(__GNUC__)
#define CF_EXPORT __attribute__((visibility("default")))
#else
#define CF_EXPORT
#endif

/* n engagement steps from *state, inputs[k] for step k; states[k] and outputs[k] after it
 * (either may be NULL). *state ends as the last state. */
CF_EXPORT void cf_engagement_run(cf_engagement_state *state, const cf_engagement_inputs *inputs,
                                 size_t n, const cf_engagement_params *params, double dt_s,
                                 cf_engagement_state *states, cf_engagement_outputs *outputs) {
    cf_engagement_outputs out;
    for (size_t k = 0; k < n; ++k) {
        cf_engagement_step(state, &inputs[k], params, dt_s, &out);
        if (states != NULL) {
            states[k] = *state;
        }
        if (outputs != NULL) {
            outputs[k] = out;
        }
    }
}

/* The steering law over n samples: terms[5k..5k+4] of (speed, rate, ay)[k]. */
CF_EXPORT void cf_torque_run(const double *speed_m_s, const double *rate_rad_s,
                             const double *ay_m_s2, size_t n, const cf_torque_params *params,
                             double *terms) {
    for (size_t k = 0; k < n; ++k) {
        cf_torque_terms(speed_m_s[k], rate_rad_s[k], ay_m_s2[k], params, &terms[5 * k]);
    }
}

/* The law's friction memory over n steps from z = 0: z[k] after step k (rate[k] held over
 * dt[k]). */
CF_EXPORT void cf_friction_memory_run(const double *rate_rad_s, const double *dt_s, size_t n,
                                      const cf_torque_params *params, double *z) {
    double state = 0.0;
    for (size_t k = 0; k < n; ++k) {
        state = cf_friction_memory_step(state, rate_rad_s[k], dt_s[k], params);
        z[k] = state;
    }
}

/* The single-track car over n steps from *state: states[k] after step k, and the front axle's
 * Ay (single_track.aligning_lateral_accel) after it in aligning[k] (may be NULL). */
CF_EXPORT void cf_vehicle_run(cf_vehicle_state *state, const double *speed_m_s,
                              const double *angle_rad, size_t n, const cf_vehicle_params *params,
                              double dt_s, cf_vehicle_state *states, double *aligning) {
    for (size_t k = 0; k < n; ++k) {
        cf_vehicle_step(state, speed_m_s[k], angle_rad[k], params, dt_s);
        states[k] = *state;
        if (aligning != NULL) {
            aligning[k] = cf_aligning_lateral_accel(state, speed_m_s[k], params);
        }
    }
}

/* Steady-state Ay of n (speed, angle) samples. */
CF_EXPORT void cf_steady_state_run(const double *speed_m_s, const double *angle_rad, size_t n,
                                   const cf_vehicle_params *params, double *ay_m_s2) {
    for (size_t k = 0; k < n; ++k) {
        ay_m_s2[k] = cf_steady_state_lateral_accel(speed_m_s[k], angle_rad[k], params);
    }
}

/* SplitMix64's next draw (cf_next_uniform), for comparing with models/rng.py. */
CF_EXPORT uint64_t cf_port_next_uniform(uint64_t state, double *u) {
    return cf_next_uniform(state, u);
}

/* n steps of the physical steering model from *state: states[k] and outputs[k] after step k. */
CF_EXPORT void cf_physical_run(cf_physical_state *state, const cf_physical_inputs *inputs,
                               size_t n, const cf_physical_params *params, double dt_s,
                               cf_physical_state *states, cf_physical_outputs *outputs) {
    for (size_t k = 0; k < n; ++k) {
        cf_physical_step(state, &inputs[k], params, dt_s, &outputs[k]);
        states[k] = *state;
    }
}
