"""Physical steering: brush tyres on a nonlinear single-track car, and an EPS steering system.

    hand wheel J_h --torsion bar k_tb, c_tb-- pinion + rack + motor J_r --/SR-- front wheels
       ^ driver / device                       ^ EPS: boost(T_tb, V), damping, active return
                                               v rack friction, end stops, kingpin torques

Angles of the steering system are in hand-wheel units (rad at the wheel rim): the pinion angle
theta_p turns the road wheels by delta = theta_p / SR. Kingpin torques (at the road wheels) reach
the pinion divided by SR (ideal gear; its losses are the rack friction).

Kingpin torques, each positive when it turns the wheels back toward centre from a positive delta:
- aligning: mechanical trail t_m times the front axle's force plus the tyres' pneumatic moment
  (brush: trail t0 at zero slip, collapsing with slip; `carfeel.models.vehicle.tyres`);
- jacking: the kingpin inclination lifts the car as the wheels turn: Fz_front * d * sin(lambda)
  * cos(lambda) * sin(delta) (d the kingpin offset at the wheel centre; caster's share cancels
  between the two wheels at equal loads and is left out);
- park: dry-park wind-up, the tyres' contact patches twisted at standstill: an elasto-plastic
  spring (stiffness k_w to an anchor that slides at (2/3) * mu * Fz_front * r_patch, the moment of
  a uniformly pressed round patch) whose anchor follows the wheel as the tyre rolls, over the
  relaxation length: at speed it is a small damper falling as 1/V, at standstill a spring.

Car: single track with two tyres per axle (lateral load transfer m*Ay*h/track, shared by the roll
stiffness), slip angles relaxed over the relaxation length sigma (alpha' = V/sigma * (kinematic
slip - alpha), implicit Euler), small angles as in the linear car (so its understeer gradient is
this car's at low Ay), semi-implicit Euler for sideslip and yaw rate. Below the kinematic speed
the kinematic bicycle takes over as in `single_track`.

Hand wheel: imposed (a driver's or a device's angle and rate, `hands_on` = 1; the output is then
the torque into the column, the rim's own inertia left to what moves it) or free with the hand's
torque applied (`hands_on` = 0: hands off with zero torque; the rim's inertia integrated).
Frictions are position-based stick elements (a spring of bounded stiffness to an anchor that
slides at the friction level, and while it sticks a damper beside the spring), dissipative, with
no velocity slope. The EPS damping follows the assist's speed schedule and rises with V^2.

Output: the torque the driver applies at the rim, positive counter-clockwise (each term resists
the driver, as in the paper's law), and its contributions, which sum to it exactly:
aligning + jacking + park + friction + damping + inertia + stop + assist (the assist is negative:
it takes load off the driver).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

from carfeel.models.vehicle.single_track import STANDARD_GRAVITY_M_S2, VehicleParams
from carfeel.models.vehicle.tyres import brush, load_sensitive_mu

SLIDING_GRIP = 0.95
"""An axle using more than this share of its grip is sliding (brush model: 63 % of the contact
length slides there)."""


@dataclass(frozen=True, slots=True)
class TyreParams:
    """Tyres and what sets their loads; both axles share the tyre model."""

    friction_coefficient: float
    """Road-tyre friction mu at the nominal load (dry about 1.0, wet 0.7, snow 0.3)."""
    load_sensitivity: float
    """e in mu_i = mu * (1 - e * (Fz_i / Fz0 - 1)), dimensionless."""
    pneumatic_trail_m: float
    """t0: pneumatic trail at zero slip."""
    relaxation_length_m: float
    """sigma: rolling distance over which the slip angle builds."""
    cg_height_m: float
    """Height h of the centre of gravity, for the lateral load transfer m*Ay*h/track."""
    track_m: float
    """Track width, for the lateral load transfer m*Ay*h/track."""
    front_roll_share: float
    """Share of the lateral load transfer taken by the front axle (its roll stiffness share)."""
    patch_radius_m: float
    """Radius of a round patch of the contact's area, for the dry-park moment."""
    wind_up_stiffness_Nm_rad: float
    """Torsional stiffness of both front contact patches at the kingpins, before they slide."""


@dataclass(frozen=True, slots=True)
class SystemParams:
    """The steering system in hand-wheel units (torques at the pinion, angles at the rim)."""

    hand_wheel_inertia_kg_m2: float
    """Inertia J_h of the rim and the column above the torsion bar (integrated hands off)."""
    rack_inertia_kg_m2: float
    """Pinion, rack, EPS motor and road wheels, referred to the pinion."""
    torsion_bar_stiffness_Nm_rad: float
    """Stiffness k_tb of the torsion bar between the column and the pinion (the EPS senses its
    torque)."""
    compensation_damping_Nm_s_rad: float
    """Damper across the torsion bar: the EPS controller's torque-derivative compensation."""
    mechanical_trail_m: float
    """Caster trail at the ground."""
    kingpin_inclination_rad: float
    """Kingpin inclination lambda; with kingpin_offset_m it sets the jacking torque."""
    kingpin_offset_m: float
    """Lateral distance from the kingpin axis to the wheel plane at the wheel centre."""
    column_friction_Nm: float
    """Friction of the column at the rim (a stick element of friction_stiffness_Nm_rad)."""
    rack_friction_Nm: float
    """Rack, pinion and joint friction referred to the pinion."""
    friction_stiffness_Nm_rad: float
    """Stiffness of the stick elements (before the friction slides)."""
    presliding_damping_Nm_s_rad: float
    """Damper of the column's and the rack's stick elements while they stick (LuGre's sigma_1:
    the micro-slip of real contacts dissipates before they slide); with the spring, bounded by
    the friction level."""
    rack_damping_Nm_s_rad: float
    """Viscous damping of the rack on the pinion's rate, besides the EPS's."""
    assist_deadband_Nm: float
    """Torsion-bar torque below which the motor does not boost."""
    assist_gain_standstill_1_Nm: float
    """Assist gain at standstill: boost = gain * (|T_tb| - deadband)^2, at most max_assist_Nm."""
    assist_gain_high_speed_1_Nm: float
    """Assist gain at high speed: the gain falls from the standstill one to this with speed."""
    assist_fade_speed_m_s: float
    """Speed at which the gain is halfway between its two values."""
    max_assist_Nm: float
    """Motor torque limit at the pinion."""
    eps_damping_Nm_s_rad: float
    """Motor damping on the pinion's rate at standstill (felt through the driver's torque)."""
    eps_damping_high_speed_Nm_s_rad: float
    """Motor damping on the pinion's rate at high speed, reached on the assist's speed schedule:
    it damps the released wheel."""
    eps_damping_rise_Nm_s3_rad_m2: float
    """Motor damping added as V^2 times this, on top of the schedule (the released wheel's weave
    with the car at 200-250 km/h needs more damping than the release at 100 km/h wants)."""
    active_return_Nm_rad: float
    """Stiffness of the EPS's active return toward centre, on the pinion angle (0: off)."""
    active_return_max_Nm: float
    """Largest torque of the active return, at the pinion."""
    active_return_fade_speed_m_s: float
    """Active return is full from 2 m/s and gone above about twice this speed."""
    stop_stiffness_Nm_rad: float
    """Stiffness of the end stops beyond the car's steering lock, on the pinion angle."""
    stop_damping_Nm_s_rad: float
    """Damping of the end stops while the rack is beyond the lock (they only push back)."""


@dataclass(frozen=True, slots=True)
class PhysicalParams:
    vehicle: VehicleParams
    tyres: TyreParams
    system: SystemParams

    @property
    def front_load_N(self) -> float:
        v = self.vehicle
        return v.mass_kg * STANDARD_GRAVITY_M_S2 * v.cg_to_rear_axle_m / v.wheelbase_m

    @property
    def rear_load_N(self) -> float:
        return self.vehicle.mass_kg * STANDARD_GRAVITY_M_S2 - self.front_load_N

    @property
    def park_moment_Nm(self) -> float:
        """The front patches' sliding moment at standstill, at the kingpins, Nm."""
        return (
            2.0
            / 3.0
            * self.tyres.friction_coefficient
            * self.front_load_N
            * (self.tyres.patch_radius_m)
        )

    @property
    def on_centre_stiffness_Nm_rad(self) -> float:
        """What a device holding the rim meets first: torsion bar and column stick spring."""
        return self.system.torsion_bar_stiffness_Nm_rad + self.system.friction_stiffness_Nm_rad


class PhysicalState(NamedTuple):
    hand_angle_rad: float
    hand_rate_rad_s: float
    pinion_angle_rad: float
    pinion_rate_rad_s: float
    column_anchor_rad: float
    rack_anchor_rad: float
    park_anchor_rad: float
    """Road-wheel angle at which the patches are untwisted."""
    front_slip_rad: float
    rear_slip_rad: float
    sideslip_rad: float
    yaw_rate_rad_s: float
    x_m: float
    y_m: float
    yaw_rad: float
    lateral_accel_m_s2: float


class PhysicalInputs(NamedTuple):
    speed_m_s: float
    steering_angle_rad: float
    """Imposed rim angle (hands on), positive to the left."""
    steering_rate_rad_s: float
    hand_torque_Nm: float
    """Driver's torque on a free wheel (hands off: 0), positive counter-clockwise."""
    hands_on: float
    """1.0: the angle is imposed; 0.0: the wheel is free under `hand_torque_Nm`."""


class PhysicalOutputs(NamedTuple):
    steering_angle_rad: float
    steering_rate_rad_s: float
    lateral_accel_m_s2: float
    torque_Nm: float
    torque_aligning_Nm: float
    torque_jacking_Nm: float
    torque_park_Nm: float
    torque_friction_Nm: float
    torque_damping_Nm: float
    torque_inertia_Nm: float
    torque_stop_Nm: float
    torque_assist_Nm: float
    torsion_bar_torque_Nm: float
    front_wheel_angle_rad: float
    front_grip_used: float
    rear_grip_used: float
    yaw_rate_rad_s: float
    sideslip_rad: float
    x_m: float
    y_m: float
    yaw_rad: float


def initial_state(
    params: PhysicalParams,
    x_m: float = 0.0,
    y_m: float = 0.0,
    yaw_rad: float = 0.0,
    steering_angle_rad: float = 0.0,
) -> PhysicalState:
    """Still, the rim at `steering_angle_rad`, frictions relaxed, the patches not wound up."""
    a = steering_angle_rad
    wheels = a / params.vehicle.steering_ratio
    return PhysicalState(a, 0.0, a, 0.0, a, a, wheels, 0.0, 0.0, 0.0, 0.0, x_m, y_m, yaw_rad, 0.0)


def _stick(
    position: float, anchor: float, level: float, stiffness: float, rate: float = 0.0,
    damping: float = 0.0,
) -> tuple[float, float]:  # fmt: skip
    """(torque, anchor) of a stick element: a spring to an anchor that slides at +-level; while
    it sticks, a damper on `rate` beside the spring, their sum bounded by +-level (passive: the
    bounded sum does at least the spring's work)."""
    torque = stiffness * (position - anchor)
    if torque > level:
        return level, position - level / stiffness
    if torque < -level:
        return -level, position + level / stiffness
    torque += damping * rate
    return max(-level, min(level, torque)), anchor


def step(
    state: PhysicalState, inputs: PhysicalInputs, params: PhysicalParams, dt_s: float
) -> tuple[PhysicalState, PhysicalOutputs]:
    """Advance car and steering system by `dt_s`; the torque at the rim and its terms, Nm."""
    veh, tyr, sys = params.vehicle, params.tyres, params.system
    v = inputs.speed_m_s
    sr = veh.steering_ratio
    length = veh.wheelbase_m
    a = veh.cg_to_front_axle_m
    b = length - a
    m = veh.mass_kg
    delta = state.pinion_angle_rad / sr

    # Loads: static plus the lateral load transfer of the last step's Ay (left tyre inner in a
    # left turn).
    fz_front = params.front_load_N
    fz_f, fz_r = 0.5 * fz_front, 0.5 * params.rear_load_N
    transfer = m * state.lateral_accel_m_s2 * tyr.cg_height_m / tyr.track_m
    dfz_f = 0.5 * tyr.front_roll_share * transfer
    dfz_r = 0.5 * transfer - dfz_f
    mu = tyr.friction_coefficient
    e = tyr.load_sensitivity

    beta, r = state.sideslip_rad, state.yaw_rate_rad_s
    if v >= veh.kinematic_speed_m_s:
        k = v * dt_s / tyr.relaxation_length_m
        alpha_f = (state.front_slip_rad + k * (delta - beta - a * r / v)) / (1.0 + k)
        alpha_r = (state.rear_slip_rad + k * (b * r / v - beta)) / (1.0 + k)
        cf = 0.5 * veh.front_cornering_stiffness_N_rad
        cr = 0.5 * veh.rear_cornering_stiffness_N_rad
        t0 = tyr.pneumatic_trail_m
        load = fz_f - dfz_f
        fy1, mz1, u1 = brush(alpha_f, load, cf, load_sensitive_mu(mu, load, fz_f, e), t0)
        load = fz_f + dfz_f
        fy2, mz2, u2 = brush(alpha_f, load, cf, load_sensitive_mu(mu, load, fz_f, e), t0)
        load = fz_r - dfz_r
        fy3, _, u3 = brush(alpha_r, load, cr, load_sensitive_mu(mu, load, fz_r, e), t0)
        load = fz_r + dfz_r
        fy4, _, u4 = brush(alpha_r, load, cr, load_sensitive_mu(mu, load, fz_r, e), t0)
        front, rear = fy1 + fy2, fy3 + fy4
        pneumatic = mz1 + mz2
        ay = (front + rear) / m
        beta += dt_s * (ay / v - r)
        r += dt_s * (a * front - b * rear) / veh.yaw_inertia_kg_m2
        front_used, rear_used = max(u1, u2), max(u3, u4)
    else:
        alpha_f = alpha_r = 0.0
        tan_delta = math.tan(delta)
        beta = math.atan(b * tan_delta / length)
        r = v * math.cos(beta) * tan_delta / length
        ay = v * r
        front = m * ay * b / length
        pneumatic = tyr.pneumatic_trail_m * front
        front_used = rear_used = 0.0

    # Kingpin torques, at the pinion.
    aligning = (sys.mechanical_trail_m * front + pneumatic) / sr
    lam = sys.kingpin_inclination_rad
    jacking = fz_front * sys.kingpin_offset_m * math.sin(lam) * math.cos(lam) * math.sin(delta) / sr
    k = v * dt_s / tyr.relaxation_length_m
    park_anchor = (state.park_anchor_rad + k * delta) / (1.0 + k)
    park, park_anchor = _stick(
        delta, park_anchor, params.park_moment_Nm, tyr.wind_up_stiffness_Nm_rad
    )
    park /= sr

    # EPS: boost on the torsion-bar torque, scheduled on speed; damping; active return.
    if inputs.hands_on > 0.5:
        # The rim's own inertia is left to what moves it (a device has its own; a driver's
        # rate, differenced, would be noise): the output is the torque into the column.
        hand = inputs.steering_angle_rad
        hand_rate = inputs.steering_rate_rad_s
        hand_accel = 0.0
    else:
        hand, hand_rate, hand_accel = state.hand_angle_rad, state.hand_rate_rad_s, 0.0
    theta, omega = state.pinion_angle_rad, state.pinion_rate_rad_s
    bar = sys.torsion_bar_stiffness_Nm_rad * (hand - theta)
    bar_total = bar + sys.compensation_damping_Nm_s_rad * (hand_rate - omega)
    fade = v / sys.assist_fade_speed_m_s
    low_speed = 1.0 / (1.0 + fade * fade)
    excess = abs(bar) - sys.assist_deadband_Nm
    boost = 0.0
    if excess > 0.0:
        gain = (
            sys.assist_gain_high_speed_1_Nm
            + (sys.assist_gain_standstill_1_Nm - sys.assist_gain_high_speed_1_Nm) * low_speed
        )
        boost = min(sys.max_assist_Nm, gain * excess * excess)
        boost = boost if bar > 0.0 else -boost
    back = v / sys.active_return_fade_speed_m_s
    window = min(1.0, 0.5 * v) / (1.0 + back * back * back * back)
    ret = sys.active_return_Nm_rad * theta
    ret = max(-sys.active_return_max_Nm, min(sys.active_return_max_Nm, ret)) * window
    rack_friction, rack_anchor = _stick(
        theta, state.rack_anchor_rad, sys.rack_friction_Nm, sys.friction_stiffness_Nm_rad,
        omega, sys.presliding_damping_Nm_s_rad,
    )  # fmt: skip
    eps_damping = sys.eps_damping_high_speed_Nm_s_rad + low_speed * (
        sys.eps_damping_Nm_s_rad - sys.eps_damping_high_speed_Nm_s_rad
    )
    eps_damping += sys.eps_damping_rise_Nm_s3_rad_m2 * v * v
    damping = (sys.rack_damping_Nm_s_rad + eps_damping) * omega
    lock = veh.steering_lock_rad
    stop = 0.0
    if theta > lock:
        stop = max(
            0.0, sys.stop_stiffness_Nm_rad * (theta - lock) + sys.stop_damping_Nm_s_rad * omega
        )
    elif theta < -lock:
        stop = min(
            0.0, sys.stop_stiffness_Nm_rad * (theta + lock) + sys.stop_damping_Nm_s_rad * omega
        )
    load_torque = aligning + jacking + park + rack_friction + damping + stop
    rack_accel = (bar_total + boost - ret - load_torque) / sys.rack_inertia_kg_m2
    omega += dt_s * rack_accel
    theta += dt_s * omega

    # Hand wheel: column friction, and the hand's torque if it is free.
    column, column_anchor = _stick(
        hand, state.column_anchor_rad, sys.column_friction_Nm, sys.friction_stiffness_Nm_rad,
        hand_rate, sys.presliding_damping_Nm_s_rad,
    )  # fmt: skip
    if inputs.hands_on <= 0.5:
        hand_accel = (inputs.hand_torque_Nm - bar_total - column) / sys.hand_wheel_inertia_kg_m2
        hand_rate += dt_s * hand_accel
        hand += dt_s * hand_rate

    # Pose: as in single_track.
    yaw = state.yaw_rad + 0.5 * dt_s * (state.yaw_rate_rad_s + r)
    course = 0.5 * (state.yaw_rad + yaw) + 0.5 * (state.sideslip_rad + beta)
    x = state.x_m + dt_s * v * math.cos(course)
    y = state.y_m + dt_s * v * math.sin(course)

    inertia = sys.hand_wheel_inertia_kg_m2 * hand_accel + sys.rack_inertia_kg_m2 * rack_accel
    assist = -boost + ret
    friction = rack_friction + column
    total = aligning + jacking + park + friction + damping + inertia + stop + assist
    new = PhysicalState(
        hand, hand_rate, theta, omega, column_anchor, rack_anchor, park_anchor,
        alpha_f, alpha_r, beta, r, x, y, yaw, ay,
    )  # fmt: skip
    out = PhysicalOutputs(
        hand, hand_rate, ay, total, aligning, jacking, park, friction, damping, inertia, stop,
        assist, bar_total, theta / sr, front_used, rear_used, r, beta, x, y, yaw,
    )  # fmt: skip
    return new, out
