"""A 1-DOF mass-spring-damper with stick-slip (Karnopp) friction, integrated implicitly.

Equation (8) of the paper, for one stage of a lever::

    F = m*a + c*v + k*(x - x0) + F_fr

The step is implicit (backward) Euler in the spring and damper, so it is unconditionally stable and,
with no applied force, never gains energy (proof in `stick_slip_step`). Friction is resolved inside
the same implicit step. Inside Karnopp's velocity band the lever counts as at rest: it sticks
(velocity exactly 0.0, position unchanged to the last bit) while the applied force stays within the
static friction, and breaks away with the sliding friction once it does not. Outside the band the
friction that would bring the lever to rest within the step is computed first; if the sliding
friction can supply it, the lever stops exactly. So sticking and breakaway happen at the exact
force levels, whatever the step size.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class StageMechanics:
    """Mechanical parameters of a lever during one stage (the paper's m, k, c, Fst, Fsl).

    The rest position x0 belongs to the stage's geometry and is passed separately.
    """

    mass_kg: float
    """Mass m of the lever, reflected at the knob, in this stage."""
    stiffness_N_m: float
    """Stiffness k of this stage's spring toward its rest position x0 (0: no spring)."""
    damping_N_s_m: float
    """Viscous damping c of the lever in this stage."""
    static_friction_N: float
    """Static (break-away) friction F_st in this stage."""
    sliding_friction_N: float
    """Sliding friction F_sl in this stage."""


def stick_slip_step(
    position_m: float,
    velocity_m_s: float,
    force_N: float,
    mass_kg: float,
    damping_N_s_m: float,
    stiffness_N_m: float,
    rest_position_m: float,
    static_friction_N: float,
    sliding_friction_N: float,
    stick_velocity_m_s: float,
    dt_s: float,
) -> tuple[float, float, float]:
    """Advance the lever by one step of `dt_s`; return (position_m, velocity_m_s, friction_N).

    The parameters are plain floats: a caller may add springs (a wall, a coupling) to a stage's
    own, or change a friction per event (the tooth force of an engagement). Several springs
    k_i toward r_i act as one spring sum(k_i) toward sum(k_i*r_i)/sum(k_i), up to a constant.

    Signs: positions, velocities and forces are positive in the same direction; `force_N` is the
    applied (driver) force; the returned friction opposes the motion (or the would-be motion when
    stuck) and is what the lever's mounting carries.

    Energy: with impedance Z = m/h + c + h*k the implicit update is
    Z*v1 = m*v0/h + F - k*(x0-r) - Ff.
    Multiplying by v1 gives E1 - E0 = h*F*v1 - m/2*(v1-v0)^2 - k/2*(x1-x0)^2 - h*c*v1^2 - h*Ff*v1,
    and Ff*v1 >= 0 by construction, so with F = 0 the energy E = m*v^2/2 + k*(x-r)^2/2 never grows
    (inside the velocity band v0 is first set to 0, which only removes energy).
    """
    h = dt_s
    m_h = mass_kg / h
    impedance = m_h + damping_N_s_m + h * stiffness_N_m
    applied = force_N - stiffness_N_m * (position_m - rest_position_m)
    in_band = -stick_velocity_m_s < velocity_m_s < stick_velocity_m_s
    if in_band and -static_friction_N <= applied <= static_friction_N:
        # Karnopp: in the velocity band the lever sticks while the applied force stays within the
        # static friction, whatever the step size (its small momentum is dropped: dissipative).
        return position_m, 0.0, applied
    # Moving, or breaking away: the friction that would bring the lever exactly to rest within
    # this step; if the sliding friction can supply it, the lever stops, else it slides.
    drive = m_h * velocity_m_s + applied
    if -sliding_friction_N <= drive <= sliding_friction_N:
        return position_m, 0.0, drive
    friction = sliding_friction_N if drive > 0.0 else -sliding_friction_N
    velocity = (drive - friction) / impedance
    return position_m + h * velocity, velocity, friction


def stick_slip_midpoint_step(
    position_m: float,
    velocity_m_s: float,
    force_N: float,
    mass_kg: float,
    damping_N_s_m: float,
    stiffness_N_m: float,
    rest_position_m: float,
    static_friction_N: float,
    sliding_friction_N: float,
    stick_velocity_m_s: float,
    dt_s: float,
) -> tuple[float, float, float]:
    """As `stick_slip_step`, second order (the implicit midpoint rule), for stiff springs.

    Backward Euler damps a spring numerically: a 30 kN/m stop on 1.2 kg (158 rad/s) at 1 kHz
    rings with an effective damping ratio of 0.18 where the physical one is 0.105. The midpoint
    rule maps the continuous poles to the unit circle with an error of (w*h)^2/12 (0.2 % there).

    With vm = (v0 + v1)/2 and x1 = x0 + h*vm the update is
    (2m/h + c + h*k/2)*vm = 2m*v0/h + F - k*(x0-r) - Ff, and
    E1 - E0 = h*vm*(F - c*vm - Ff), with Ff*vm >= 0 by construction: passive with F = 0.
    When the friction can stop the lever within the step it ends at rest (a stop at x0 + h*v0/2
    if that friction opposes v0, else at x0): both only remove energy.
    """
    h = dt_s
    applied = force_N - stiffness_N_m * (position_m - rest_position_m)
    if -stick_velocity_m_s < velocity_m_s < stick_velocity_m_s and (
        -static_friction_N <= applied <= static_friction_N
    ):
        return position_m, 0.0, applied
    v0 = velocity_m_s
    # The friction that brings the lever to rest exactly at the end of the step.
    stop = mass_kg * v0 / h + applied - (0.5 * damping_N_s_m + 0.25 * h * stiffness_N_m) * v0
    if -sliding_friction_N <= stop <= sliding_friction_N and stop * v0 >= 0.0:
        return position_m + 0.5 * h * v0, 0.0, stop
    drive = 2.0 * mass_kg * v0 / h + applied
    if -sliding_friction_N <= drive <= sliding_friction_N:
        return position_m, 0.0, drive
    friction = sliding_friction_N if drive > 0.0 else -sliding_friction_N
    mid = (drive - friction) / (2.0 * mass_kg / h + damping_N_s_m + 0.5 * h * stiffness_N_m)
    return position_m + h * mid, 2.0 * mid - v0, friction


def stage_energy_J(
    position_m: float, velocity_m_s: float, mech: StageMechanics, rest_position_m: float
) -> float:
    """Kinetic plus spring energy of the lever in one stage, J."""
    stretch = position_m - rest_position_m
    return 0.5 * mech.mass_kg * velocity_m_s**2 + 0.5 * mech.stiffness_N_m * stretch**2
