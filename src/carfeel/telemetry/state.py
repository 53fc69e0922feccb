"""The vehicle state every format decodes to (SI units; NaN where a format does not carry it).

Signs (ISO 8855, as the single-track model): lateral acceleration, yaw rate and steering angle are
positive to the left. Gear: -1 reverse, 0 neutral, 1.. forward.
"""

from __future__ import annotations

import math
from typing import NamedTuple

NAN = math.nan
REVERSE, NEUTRAL = -1, 0


class VehicleState(NamedTuple):
    speed_m_s: float = NAN
    lateral_accel_m_s2: float = NAN
    yaw_rate_rad_s: float = NAN
    engine_speed_rpm: float = NAN
    gear: int = NEUTRAL
    clutch_pedal: float = NAN
    """0 released .. 1 pressed to the floor."""
    throttle: float = NAN
    """0 .. 1."""
    brake: float = NAN
    """0 .. 1."""
    steering_angle_rad: float = NAN
    """The steering wheel's angle (NaN where a format gives only a normalized input)."""
    engine_max_rpm: float = NAN
    """Where the format gives it: the rev limiter's speed."""
    car: str = ""
    """The car, where the format names it (Forza's ordinal, AC's name, LFS's short name)."""
    cylinders: int = 0
    """Where the format gives it (Forza): for the firing frequency."""
    lateral_derived: bool = False
    """True where Ay was derived (speed x yaw rate, or world acceleration rotated by heading)."""
    time_s: float = NAN
    """The packet's own time stamp, s, as the game counts it (its session or race clock; NaN
    where the format has none: Assetto Corsa, BeamNG's MotionSim, OutSim without OSO_TIME)."""
    # What the shared-memory games add (issue 29); defaults where a format does not say.
    wheel_torque_Nm: float = NAN
    """The game's own force-feedback torque at the wheel, N*m, positive to the left (as the
    steering angle: it is negative while the wheel is turned left and the tyres pull it back);
    iRacing's SteeringWheelTorque."""
    wheel_torque_samples_Nm: tuple[float, ...] = ()
    """The same torque at the game's higher rate within this frame, oldest first (iRacing's
    SteeringWheelTorque_ST: 6 samples at 360 Hz); empty where the game has none."""
    wheel_torque_max_Nm: float = NAN
    """The game's torque scale: the torque its force feedback maps to the wheel's full force
    (iRacing's SteeringWheelMaxForceNm), for normalizing per car."""
    shift_grind_rpm: float = NAN
    """Where the game says a shift grinds (iRacing's ShiftGrindRPM: the speed difference)."""
    engine_idle_rpm: float = NAN
    forward_gears: int = 0
    """The gearbox's forward gears, where the game says (0: not said)."""
    gearbox: str = ""
    """"h", "sequential" or "truck" where the game says; "" where not."""
    truck_slot: int = -1
    """ETS2/ATS: the H-shifter slot the game has selected (-1: not a truck or not said)."""
    range_high: bool = False
    """A truck's range selector (high), where the game says."""
    splitter_high: bool = False
    """A truck's splitter (high), where the game says."""
    slots: tuple[tuple[int, int, int], ...] = ()
    """ETS2/ATS: the game's H-shifter slot table, (handle position, selector bitmask, gear) for
    each slot (bit 0 of the bitmask the range, bit 1 the splitter; gear -n reverse, 0 none)."""
    replay: bool = False
    """The game is playing a replay (the cues are off: nobody is driving)."""
    paused: bool = False
    """The game says it is paused or the player is not in the car."""


FIELDS = (
    "speed_m_s", "lateral_accel_m_s2", "yaw_rate_rad_s", "engine_speed_rpm", "gear",
    "clutch_pedal", "throttle", "brake", "steering_angle_rad",
)  # fmt: skip
"""The fields recorded and printed (the common state of issue 14)."""


def gear_name(gear: int) -> str:
    return "R" if gear < 0 else "N" if gear == 0 else str(gear)


MAX_GEAR = 24
"""Trucks have up to 18 forward gears (ETS2's gearboxes to 16+2); a little more."""

MAX_WHEEL_TORQUE_NM = 200.0
"""A steering column's torque: a truck's unassisted wheel is some tens of N*m."""

BAD = VehicleState(speed_m_s=math.inf)
"""What a decoder returns for a datagram of the right size that is not a packet of its format
(garbage, a field out of the game's own range): it fails `plausible`, so it is counted bad."""


def plausible(state: VehicleState) -> bool:
    """The check every decoded packet passes once, at the boundary: finite where present and within
    what a car can do (speed < 150 m/s, |Ay| < 60 m/s^2, rpm < 30000, gear -1..24, pedals 0..1
    with a little slack for float noise, the wheel's torque within 200 N*m). The decoders check
    their format's own fields first (car ids, flags, ranges the game keeps) and return `BAD`
    where one is off."""
    s = state
    for value, bound in (
        (s.speed_m_s, 150.0),
        (s.lateral_accel_m_s2, 60.0),
        (s.yaw_rate_rad_s, 20.0),
        (s.engine_speed_rpm, 30_000.0),
        (s.steering_angle_rad, 30.0),
    ):
        if not (abs(value) <= bound or math.isnan(value)):
            return False  # inf, or out of range
    for pedal in (s.clutch_pedal, s.throttle, s.brake):
        if not (-0.01 <= pedal <= 1.01 or math.isnan(pedal)):
            return False
    if not (abs(s.time_s) < 1e10 or math.isnan(s.time_s)):
        return False  # 300 years: no game's clock
    for torque in (s.wheel_torque_Nm, *s.wheel_torque_samples_Nm):
        if not (abs(torque) <= MAX_WHEEL_TORQUE_NM or math.isnan(torque)):
            return False
    return -1 <= s.gear <= MAX_GEAR and (
        s.engine_speed_rpm >= 0.0 or math.isnan(s.engine_speed_rpm)
    )
