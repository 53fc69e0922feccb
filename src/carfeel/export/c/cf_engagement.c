/* carfeel: the 1-DOF gear engagement, a port of models/gearshift/engagement.py,
 * models/mechanics.py and models/rng.py (see cf_engagement.h). Each function names the Python
 * function it ports; comments on the physics are in the Python source. Keep the order of every
 * operation as in Python: that is what makes the results equal bit for bit. */
#include "cf_engagement.h"

#include <math.h>

/* _DONE: progress counts as complete within rounding. */
static const double DONE = 1.0 - 1e-9;

/* Python's x ** 2.0 on floats is libm's pow(x, 2.0) (CPython's float_pow); compiled with
 * -fno-builtin this stays the same call rather than x * x. */
static double square(double x) { return pow(x, 2.0); }

/* rng.seed_state */
uint64_t cf_seed_state(int64_t seed) { return (uint64_t)seed; }

/* rng.next_uniform: Python's ints are unbounded, masked to 64 bits; uint64_t wraps the same. */
uint64_t cf_next_uniform(uint64_t state, double *u) {
    state = state + 0x9E3779B97F4A7C15ULL;
    uint64_t z = state;
    z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ULL;
    z = (z ^ (z >> 27)) * 0x94D049BB133111EBULL;
    z ^= z >> 31;
    *u = (double)(z >> 11) * (1.0 / 9007199254740992.0); /* 1.0 / (1 << 53) */
    return state;
}

/* mechanics.stick_slip_step */
static void stick_slip_step(double position_m, double velocity_m_s, double force_N, double mass_kg,
                            double damping_N_s_m, double stiffness_N_m, double rest_position_m,
                            double static_friction_N, double sliding_friction_N,
                            double stick_velocity_m_s, double dt_s, double *x1, double *v1) {
    double h = dt_s;
    double m_h = mass_kg / h;
    double impedance = m_h + damping_N_s_m + h * stiffness_N_m;
    double applied = force_N - stiffness_N_m * (position_m - rest_position_m);
    int in_band = -stick_velocity_m_s < velocity_m_s && velocity_m_s < stick_velocity_m_s;
    if (in_band && -static_friction_N <= applied && applied <= static_friction_N) {
        *x1 = position_m;
        *v1 = 0.0;
        return;
    }
    double drive = m_h * velocity_m_s + applied;
    if (-sliding_friction_N <= drive && drive <= sliding_friction_N) {
        *x1 = position_m;
        *v1 = 0.0;
        return;
    }
    double friction = drive > 0.0 ? sliding_friction_N : -sliding_friction_N;
    double velocity = (drive - friction) / impedance;
    *x1 = position_m + h * velocity;
    *v1 = velocity;
}

/* mechanics.stick_slip_midpoint_step */
static void stick_slip_midpoint_step(double position_m, double velocity_m_s, double force_N,
                                     double mass_kg, double damping_N_s_m, double stiffness_N_m,
                                     double rest_position_m, double static_friction_N,
                                     double sliding_friction_N, double stick_velocity_m_s,
                                     double dt_s, double *x1, double *v1) {
    double h = dt_s;
    double applied = force_N - stiffness_N_m * (position_m - rest_position_m);
    if (-stick_velocity_m_s < velocity_m_s && velocity_m_s < stick_velocity_m_s &&
        (-static_friction_N <= applied && applied <= static_friction_N)) {
        *x1 = position_m;
        *v1 = 0.0;
        return;
    }
    double v0 = velocity_m_s;
    double stop = mass_kg * v0 / h + applied - (0.5 * damping_N_s_m + 0.25 * h * stiffness_N_m) * v0;
    if (-sliding_friction_N <= stop && stop <= sliding_friction_N && stop * v0 >= 0.0) {
        *x1 = position_m + 0.5 * h * v0;
        *v1 = 0.0;
        return;
    }
    double drive = 2.0 * mass_kg * v0 / h + applied;
    if (-sliding_friction_N <= drive && drive <= sliding_friction_N) {
        *x1 = position_m;
        *v1 = 0.0;
        return;
    }
    double friction = drive > 0.0 ? sliding_friction_N : -sliding_friction_N;
    double mid = (drive - friction) / (2.0 * mass_kg / h + damping_N_s_m + 0.5 * h * stiffness_N_m);
    *x1 = position_m + h * mid;
    *v1 = 2.0 * mid - v0;
}

/* engagement._detent: (force N, potential J, stiffness N/m) of one detent at x. */
static double detent(double x, double seat, double width, const cf_detent_params *d,
                     double *energy, double *stiffness) {
    double span = width > 0.0 ? width : -width;
    double u = (x - seat) / width;
    double sign = width > 0.0 ? 1.0 : -1.0;
    if (u < 0.0) {
        u = -u;
        sign = -sign;
    }
    double peak = d->seat_force_N;
    if (u < 1.0) {
        *energy = peak * span * u * u * (2.0 - u * (4.0 / 3.0));
        *stiffness = 4.0 * peak * (1.0 - 2.0 * u) / span;
        return -sign * 4.0 * peak * u * (1.0 - u);
    }
    double far = d->far_width_m;
    double w = far > 0.0 ? (u - 1.0) * span / far : 1.0;
    double top = peak * span * (2.0 / 3.0);
    if (w < 1.0) {
        double help = d->far_force_N;
        *energy = top - help * far * w * w * (2.0 - w * (4.0 / 3.0));
        *stiffness = -4.0 * help * (1.0 - 2.0 * w) / far;
        return sign * 4.0 * help * w * (1.0 - w);
    }
    *energy = top - d->far_force_N * far * (2.0 / 3.0);
    *stiffness = 0.0;
    return 0.0;
}

static double detent_potential(double x, double seat, double width, const cf_detent_params *d) {
    double energy, stiffness;
    detent(x, seat, width, d, &energy, &stiffness);
    return energy;
}

/* engagement.detent_energy_J: potential (J) of both detents at x (as _detents: e1 + e2). */
static double cf_detents_energy(const cf_engagement_params *p, double x) {
    double e1 = detent_potential(x, 0.0, p->neutral_detent.width_m, &p->neutral_detent);
    double e2 = detent_potential(x, p->in_gear_position_m, -p->gear_detent.width_m, &p->gear_detent);
    return e1 + e2;
}

/* engagement._flat_J */
static double flat_J(double width, const cf_detent_params *d) {
    return (d->seat_force_N * width - d->far_force_N * d->far_width_m) * (2.0 / 3.0);
}

/* EngagementParams.hold_force_N, with detent_force_N(x, params, 0.0). */
double cf_hold_force_N(const cf_engagement_params *p) {
    double x = p->synchronization_position_m;
    double energy, stiffness;
    double force = 0.0;
    force += detent(x, 0.0, p->neutral_detent.width_m, &p->neutral_detent, &energy, &stiffness);
    double back = p->neutral.stiffness_N_m * x - force;
    return back + p->ring_release_force_N;
}

/* engagement.mechanics: the mechanics of a free stage and its rest position. */
static const cf_stage_mechanics *mechanics(const cf_engagement_params *p, int64_t stage,
                                           double *rest) {
    *rest = 0.0;
    switch (stage) {
    case CF_GATE_OPEN:
        return &p->gate_open;
    case CF_ENGAGEMENT:
        return &p->engagement;
    case CF_FREE_TRAVEL:
        return &p->free_travel;
    case CF_STOP:
        *rest = p->in_gear_position_m;
        return &p->stop;
    case CF_IN_GEAR:
        *rest = p->in_gear_position_m;
        return &p->in_gear;
    case CF_RETURNING:
        return &p->returning;
    default: /* neutral (the blocked synchronization stage never integrates) */
        return &p->neutral;
    }
}

/* engagement.chamfer_load: (equivalent mass kg, drag N) of the gear at the knob. */
static void chamfer_load(const cf_engagement_params *p, double inertia_kg_m2, double drag_Nm,
                         double *mass, double *drag) {
    const cf_chamfer_params *c = &p->chamfer;
    double j = isnan(inertia_kg_m2) ? c->gear_inertia_kg_m2 : inertia_kg_m2;
    double torque = isnan(drag_Nm) ? c->drag_torque_Nm : drag_Nm;
    double tangent = tan(c->angle_rad);
    double per = tangent / (c->radius_m * c->lever_ratio);
    *mass = j * per * per / c->linkage_efficiency;
    *drag = torque * per / c->linkage_efficiency;
}

/* engagement.hand_over_velocity */
static double hand_over_velocity(double velocity_m_s, double old_mass_kg, double new_mass_kg) {
    if (new_mass_kg > old_mass_kg) {
        return velocity_m_s * (old_mass_kg / new_mass_kg);
    }
    return velocity_m_s;
}

/* engagement._mass_and_spring */
static void mass_and_spring(const cf_engagement_params *p, int64_t stage, double x, double *mass,
                            double *spring) {
    if (stage == CF_SYNCHRONIZATION) {
        *mass = p->neutral.mass_kg;
        *spring = 0.0;
        return;
    }
    double rest;
    const cf_stage_mechanics *mech = mechanics(p, stage, &rest);
    *mass = mech->mass_kg;
    *spring = 0.5 * mech->stiffness_N_m * square(x - rest);
}

/* engagement._hand_over */
static double hand_over(double velocity_m_s, double position_m, int64_t old, int64_t new_stage,
                        const cf_engagement_params *p) {
    double old_mass, old_spring, new_mass, new_spring;
    mass_and_spring(p, old, position_m, &old_mass, &old_spring);
    mass_and_spring(p, new_stage, position_m, &new_mass, &new_spring);
    double v = hand_over_velocity(velocity_m_s, old_mass, new_mass);
    double climb = new_spring - old_spring;
    if (climb > 0.0) {
        double kinetic = 0.5 * new_mass * v * v - climb;
        double speed = kinetic > 0.0 ? sqrt(2.0 * kinetic / new_mass) : 0.0;
        v = v > 0.0 ? speed : -speed;
    }
    return v;
}

void cf_engagement_initial_state(cf_engagement_state *s, int64_t seed, double position_m) {
    s->stage = CF_NEUTRAL;
    s->position_m = position_m;
    s->velocity_m_s = 0.0;
    s->stage_time_s = 0.0;
    s->synchronization_progress = 0.0;
    s->tooth_force_N = 0.0;
    s->rng_state = cf_seed_state(seed);
    s->index_end_m = 0.0;
    s->reversal_s = 0.0;
    s->contact_m = 0.0;
}

/* engagement.step */
void cf_engagement_step(cf_engagement_state *state, const cf_engagement_inputs *inputs,
                        const cf_engagement_params *params, double dt_s,
                        cf_engagement_outputs *out) {
    const cf_engagement_params *p = params;
    double force = inputs->driver_force_N;
    int64_t stage = state->stage;
    double x = state->position_m;
    double v = state->velocity_m_s;
    double progress = state->synchronization_progress;
    double reversal = 0.0;

    /* Guards on force and time, before the motion of this step. */
    if (stage == CF_SYNCHRONIZATION) {
        double bound = p->neutral.stiffness_N_m * p->synchronization_position_m +
                       (p->neutral_detent.seat_force_N + p->ring_release_force_N);
        if (force < bound && force < cf_hold_force_N(p)) {
            stage = CF_NEUTRAL;
        } else {
            int synchronized;
            if (inputs->gate_open < 0) {
                double rate = dt_s / p->synchronization_duration_s;
                double f_ref = p->synchronization_force_N;
                if (f_ref > 0.0) { /* the cone's torque grows with the axial load */
                    double hold = cf_hold_force_N(p);
                    rate *= (force - hold) / (f_ref - hold);
                }
                progress += rate;
                synchronized = progress >= DONE;
            } else {
                synchronized = inputs->gate_open != 0;
            }
            if (!synchronized) {
                double x1 = x, v1 = 0.0, reaction = force;
                double k_link = p->linkage_stiffness_N_m;
                if (k_link > 0.0) {
                    double x_sync = p->synchronization_position_m;
                    double mass = p->neutral.mass_kg;
                    stick_slip_step(x, v, force, mass, p->linkage_damping_N_s_m, k_link, x_sync,
                                    0.0, 0.0, 0.0, dt_s, &x1, &v1);
                    if (x1 < x_sync) {
                        x1 = x_sync;
                        v1 = 0.0;
                    }
                    reaction = force - mass * (v1 - v) / dt_s;
                }
                state->stage = stage;
                state->position_m = x1;
                state->velocity_m_s = v1;
                state->stage_time_s = state->stage_time_s + dt_s;
                state->synchronization_progress = progress;
                state->reversal_s = 0.0;
                out->position_m = x1;
                out->velocity_m_s = v1;
                out->force_N = force;
                out->reaction_N = reaction;
                out->stage = stage;
                return;
            }
            stage = CF_GATE_OPEN;
        }
    } else if (stage == CF_ENGAGEMENT && force < -p->reversal_force_N) {
        reversal = state->reversal_s + dt_s;
        if (reversal >= p->reversal_time_s && v <= 0.0) {
            stage = CF_RETURNING;
        }
    } else if ((stage == CF_STOP || stage == CF_IN_GEAR) && force < -p->reversal_force_N) {
        reversal = state->reversal_s + dt_s; /* a pull out of gear, held */
    } else if (stage == CF_NEUTRAL && progress > 0.0) {
        double dropped = progress - dt_s / p->desynchronization_time_s;
        progress = dropped > 0.0 ? dropped : 0.0; /* max(0.0, dropped) */
    }
    if (stage != state->stage) {
        v = hand_over(v, x, state->stage, stage, p);
    }

    double rest;
    const cf_stage_mechanics *mech = mechanics(p, stage, &rest);
    double mass = mech->mass_kg;
    double stiffness = mech->stiffness_N_m;
    double damping = mech->damping_N_s_m;
    double k_wall = inputs->wall_stiffness_N_m;
    if (k_wall > 0.0) {
        rest = (stiffness * rest + k_wall * inputs->wall_position_m) / (stiffness + k_wall);
        stiffness += k_wall;
        damping += inputs->wall_damping_N_s_m;
    }
    double extra = inputs->extra_friction_N;
    double contact = state->contact_m;
    int heavy = stage == CF_ENGAGEMENT && contact <= x && x < state->index_end_m;
    if (stage == CF_ENGAGEMENT) {
        extra += state->tooth_force_N;
        if (heavy) {
            double index_mass, index_drag;
            chamfer_load(p, inputs->gear_inertia_kg_m2, inputs->gear_drag_Nm, &index_mass,
                         &index_drag);
            mass += index_mass;
            extra += index_drag;
        }
    }
    const cf_detent_params *nd = &p->neutral_detent, *gd = &p->gear_detent;
    double n_width = nd->width_m, g_width = gd->width_m;
    double n_reach = n_width + nd->far_width_m, g_reach = g_width + gd->far_width_m;
    double x_gear = p->in_gear_position_m;
    int near_n = -n_reach < x && x < n_reach;
    int near_g = -g_reach < x - x_gear && x - x_gear < g_reach;
    double detent_force = 0.0, k_detent = 0.0, u_n = 0.0, u_g = 0.0;
    if (near_n) {
        detent_force = detent(x, 0.0, n_width, nd, &u_n, &k_detent);
    }
    if (near_g) {
        double k;
        double f = detent(x, x_gear, -g_width, gd, &u_g, &k);
        detent_force += f;
        k_detent += k;
    }
    if (k_detent > 0.0) {
        rest = (stiffness * rest + k_detent * x) / (stiffness + k_detent);
        stiffness += k_detent;
    } else {
        k_detent = 0.0;
    }
    double x1, v1;
    if (stage == CF_STOP || stage == CF_IN_GEAR) {
        stick_slip_midpoint_step(x, v, force + detent_force, mass, damping, stiffness, rest,
                                 mech->static_friction_N + extra, mech->sliding_friction_N + extra,
                                 p->stick_velocity_m_s, dt_s, &x1, &v1);
    } else {
        stick_slip_step(x, v, force + detent_force, mass, damping, stiffness, rest,
                        mech->static_friction_N + extra, mech->sliding_friction_N + extra,
                        p->stick_velocity_m_s, dt_s, &x1, &v1);
    }
    if (x1 != x) {
        int near_n1 = -n_reach < x1 && x1 < n_reach;
        int near_g1 = -g_reach < x1 - x_gear && x1 - x_gear < g_reach;
        if (near_n || near_g || near_n1 || near_g1) {
            double dx = x1 - x;
            double excess = (detent_force - 0.5 * k_detent * dx) * dx;
            if (near_n || near_n1) {
                double before = near_n ? u_n : flat_J(n_width, nd);
                double after = near_n1 ? detent_potential(x1, 0.0, n_width, nd) : flat_J(n_width, nd);
                excess += after - before;
            }
            if (near_g || near_g1) {
                double before = near_g ? u_g : flat_J(g_width, gd);
                double after =
                    near_g1 ? detent_potential(x1, x_gear, -g_width, gd) : flat_J(g_width, gd);
                excess += after - before;
            }
            if (excess > 0.0) {
                double kinetic = 0.5 * mass * v1 * v1;
                if (kinetic > excess) {
                    v1 *= sqrt(1.0 - excess / kinetic);
                } else {
                    x1 = x;
                    v1 = 0.0;
                }
            }
        }
    }
    double reaction = force - mech->mass_kg * (v1 - v) / dt_s;

    /* Guards on position, at the end of the motion of this step. */
    int64_t new_stage = stage;
    uint64_t rng_state = state->rng_state;
    double tooth = state->tooth_force_N;
    double index_end = state->index_end_m;
    int meets = 0;
    double x_sync = p->synchronization_position_m;
    if (stage == CF_NEUTRAL) {
        if (x1 >= x_sync && v1 > 0.0) {
            x1 = x_sync;
            v1 = 0.0;
            new_stage = CF_SYNCHRONIZATION;
        } else if (x1 < -p->in_gear_position_m) { /* the rear stop, plastic */
            x1 = -p->in_gear_position_m;
            v1 = 0.0;
        }
    } else if (stage == CF_GATE_OPEN) {
        double x_teeth = p->teeth_position_m;
        if (x1 < x_sync) {
            new_stage = CF_RETURNING;
        } else if (x1 >= x_teeth) {
            double u;
            new_stage = CF_ENGAGEMENT;
            rng_state = cf_next_uniform(rng_state, &u);
            tooth = u * p->tooth_force_spread_N;
            double miss = p->chamfer.no_contact_fraction;
            index_end = contact = 0.0;
            if (u >= miss) { /* engagement.py: where the chamfer faces meet, and their end */
                double travel = p->chamfer.travel_m;
                contact = x_teeth + (u - miss) / (1.0 - miss) * travel;
                index_end = x_teeth + travel;
            }
        }
    } else if (stage == CF_ENGAGEMENT) {
        if (x1 >= index_end) {
            meets = index_end > 0.0 && !heavy && x < contact; /* met and passed in one step */
            index_end = 0.0;
        }
        if (x1 >= p->teeth_end_position_m) {
            new_stage = CF_FREE_TRAVEL;
        } else if (x1 < p->teeth_position_m) {
            new_stage = CF_RETURNING;
        }
    } else if (stage == CF_FREE_TRAVEL) {
        if (x1 >= p->in_gear_position_m) {
            /* engagement.py: cap the kinetic energy at what it was plus the driver's work up
             * to x_gear less the detents' climb (v1 holds the whole step's acceleration). */
            double xg = p->in_gear_position_m;
            double gained = force * (xg - x) - (cf_detents_energy(p, xg) - cf_detents_energy(p, x));
            double cap = 0.5 * mech->mass_kg * v * v + gained;
            double kinetic = 0.5 * mech->mass_kg * v1 * v1;
            if (kinetic > cap) {
                v1 = cap > 0.0 ? sqrt(2.0 * cap / mech->mass_kg) : 0.0;
            }
            x1 = xg;
            new_stage = CF_STOP;
        } else if (x1 < p->teeth_end_position_m) {
            new_stage = CF_RETURNING;
        }
    } else if (stage == CF_STOP || stage == CF_IN_GEAR) {
        double gear = p->in_gear_position_m;
        double end = p->stop_travel_m;
        if (end > 0.0 && x1 > gear + end) { /* the gate's end: plastic */
            x1 = gear + end;
            v1 = 0.0;
        }
        /* only a pull, held, takes it out */
        if (x1 < gear - p->detent_release_m && 0.0 < reversal && reversal >= p->reversal_time_s) {
            new_stage = CF_RETURNING;
        } else if (stage == CF_STOP && -p->settle_velocity_m_s < v1 &&
                   v1 < p->settle_velocity_m_s && -p->settle_distance_m < x1 - gear &&
                   x1 - gear < p->settle_distance_m) {
            new_stage = CF_IN_GEAR;
        }
    } else if (stage == CF_RETURNING) {
        if (x1 <= x_sync) {
            new_stage = CF_NEUTRAL;
            progress = 0.0;
        } else if (v1 > 0.0 && force > 0.0) {
            if (x < p->teeth_position_m) {
                new_stage = CF_GATE_OPEN;
            } else if (x < p->teeth_end_position_m) {
                new_stage = CF_ENGAGEMENT;
            } else {
                new_stage = CF_FREE_TRAVEL;
            }
        }
    }

    if (new_stage != stage) {
        v1 = hand_over(v1, x1, stage, new_stage, p);
    }
    if (new_stage == CF_ENGAGEMENT &&
        (meets || (contact <= x1 && x1 < index_end && !heavy))) {
        double index_mass, index_drag;
        chamfer_load(p, inputs->gear_inertia_kg_m2, inputs->gear_drag_Nm, &index_mass,
                     &index_drag);
        v1 = hand_over_velocity(v1, mech->mass_kg, mech->mass_kg + index_mass);
    }
    double stage_time = new_stage == state->stage ? state->stage_time_s + dt_s : 0.0;
    state->stage = new_stage;
    state->position_m = x1;
    state->velocity_m_s = v1;
    state->stage_time_s = stage_time;
    state->synchronization_progress = progress;
    state->tooth_force_N = tooth;
    state->rng_state = rng_state;
    state->index_end_m = index_end;
    state->reversal_s = reversal;
    state->contact_m = contact;
    out->position_m = x1;
    out->velocity_m_s = v1;
    out->force_N = force;
    out->reaction_N = reaction;
    out->stage = new_stage;
}

const char *cf_stage_name(int64_t stage) {
    static const char *names[] = {"neutral",     "synchronization", "gate_open", "engagement",
                                  "free_travel", "stop",            "in_gear",   "returning"};
    return stage >= 0 && stage < 8 ? names[stage] : "?";
}
