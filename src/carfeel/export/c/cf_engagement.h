/* carfeel: the 1-DOF gear engagement (models/gearshift/engagement.py), ported to C.
 *
 * A line-by-line port of the Python step, with models/mechanics.py (stick-slip, implicit Euler and
 * midpoint) and models/rng.py (SplitMix64). The Python model is the reference: the same
 * operations in the same order, so compiled without FMA contraction (-ffp-contract=off) and
 * without builtin maths (-fno-builtin: pow(x, 2.0) stays a libm call as Python's x ** 2 is) it
 * gives the Python step's results bit for bit (tests/test_fmu_port.py).
 *
 * Axis: x along the slot, 0 = neutral, positive toward the gear; forces positive toward the gear.
 * SI units; every struct holds 8-byte fields only, in the order of the Python dataclasses' fields,
 * so the parameters are a flat array of doubles in that order.
 */
#ifndef CF_ENGAGEMENT_H
#define CF_ENGAGEMENT_H

#include <stdint.h>

/* Stage, in the order of carfeel.models.gearshift.engagement.Stage. */
enum {
    CF_NEUTRAL = 0,
    CF_SYNCHRONIZATION = 1,
    CF_GATE_OPEN = 2,
    CF_ENGAGEMENT = 3,
    CF_FREE_TRAVEL = 4,
    CF_STOP = 5,
    CF_IN_GEAR = 6,
    CF_RETURNING = 7
};

typedef struct {
    double mass_kg;
    double stiffness_N_m;
    double damping_N_s_m;
    double static_friction_N;
    double sliding_friction_N;
} cf_stage_mechanics;

typedef struct {
    double width_m;
    double seat_force_N;
    double far_force_N;
    double far_width_m;
} cf_detent_params;

typedef struct {
    double gear_inertia_kg_m2;
    double drag_torque_Nm;
    double angle_rad;
    double radius_m;
    double lever_ratio;
    double linkage_efficiency;
    double travel_m;
    double no_contact_fraction;
} cf_chamfer_params;

typedef struct {
    double synchronization_position_m;
    double teeth_position_m;
    double teeth_end_position_m;
    double in_gear_position_m;
    double detent_release_m;
    double synchronization_duration_s;
    double tooth_force_spread_N;
    double stick_velocity_m_s;
    double settle_velocity_m_s;
    double settle_distance_m;
    cf_stage_mechanics neutral;
    cf_stage_mechanics gate_open;
    cf_stage_mechanics engagement;
    cf_stage_mechanics free_travel;
    cf_stage_mechanics stop;
    cf_stage_mechanics in_gear;
    cf_stage_mechanics returning;
    double ring_release_force_N;
    double desynchronization_time_s;
    double reversal_force_N;
    double reversal_time_s;
    cf_detent_params neutral_detent;
    cf_detent_params gear_detent;
    cf_chamfer_params chamfer;
    double linkage_stiffness_N_m;
    double linkage_damping_N_s_m;
    double stop_travel_m;
    double synchronization_force_N;
} cf_engagement_params;

typedef struct {
    int64_t stage;
    double position_m;
    double velocity_m_s;
    double stage_time_s;
    double synchronization_progress;
    double tooth_force_N;
    uint64_t rng_state;
    double index_end_m;
    double reversal_s;
    double contact_m; /* where the chamfers meet (engagement.EngagementState.contact_m) */
} cf_engagement_state;

typedef struct {
    double driver_force_N;
    double wall_stiffness_N_m;
    double wall_damping_N_s_m;
    double wall_position_m;
    int64_t gate_open; /* -1: the model's own timer (Python None); 0: closed; 1: open */
    double extra_friction_N;
    double gear_inertia_kg_m2; /* NaN: the chamfer parameters' (Python None) */
    double gear_drag_Nm;       /* NaN: the chamfer parameters' (Python None) */
} cf_engagement_inputs;

typedef struct {
    double position_m;
    double velocity_m_s;
    double force_N;
    double reaction_N;
    int64_t stage;
} cf_engagement_outputs;

/* SplitMix64: the generator state for a seed (Python's seed & (2**64 - 1)). */
uint64_t cf_seed_state(int64_t seed);
/* The next state; *u is uniform in [0, 1). */
uint64_t cf_next_uniform(uint64_t state, double *u);

/* The lever at rest in neutral at `position_m`. */
void cf_engagement_initial_state(cf_engagement_state *state, int64_t seed, double position_m);

/* Advance one engagement by dt_s: `state` is replaced by the new state. */
void cf_engagement_step(cf_engagement_state *state, const cf_engagement_inputs *inputs,
                        const cf_engagement_params *params, double dt_s,
                        cf_engagement_outputs *outputs);

/* Push (N) below which the blocked ring lets go (EngagementParams.hold_force_N). */
double cf_hold_force_N(const cf_engagement_params *params);

/* The stage's name as in carfeel's CSV files ("neutral", ...), or "?" . */
const char *cf_stage_name(int64_t stage);

#endif
