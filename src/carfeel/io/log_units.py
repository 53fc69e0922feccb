"""carfeel's channels with their SI units, and the unit names a log may give (to SI by a
factor)."""

from __future__ import annotations

import math

CHANNELS = {
    "time_s": "s",
    "speed_m_s": "m/s",
    "steering_angle_rad": "rad",
    "steering_rate_rad_s": "rad/s",
    "lateral_accel_m_s2": "m/s^2",
    "steering_torque_Nm": "N m",
    "position_m": "m",
    "force_N": "N",
}
"""carfeel's channels a map can fill, with their SI units."""
OWN_NAMES = {**CHANNELS, "torque_Nm": "N m"}
"""The columns a file named in carfeel's own way is read for (`carfeel simulate` writes the
torque as torque_Nm)."""

_G = 9.80665
UNITS: dict[str, tuple[str, float]] = {
    "s": ("s", 1.0), "ms": ("s", 1e-3), "us": ("s", 1e-6),
    "m/s": ("m/s", 1.0), "km/h": ("m/s", 1 / 3.6), "kph": ("m/s", 1 / 3.6),
    "kmh": ("m/s", 1 / 3.6), "mph": ("m/s", 0.44704),
    "rad": ("rad", 1.0), "deg": ("rad", math.pi / 180), "°": ("rad", math.pi / 180),
    "rad/s": ("rad/s", 1.0), "deg/s": ("rad/s", math.pi / 180), "°/s": ("rad/s", math.pi / 180),
    "m/s^2": ("m/s^2", 1.0), "m/s2": ("m/s^2", 1.0), "m/s²": ("m/s^2", 1.0), "g": ("m/s^2", _G),
    "nm": ("N m", 1.0), "n m": ("N m", 1.0), "n*m": ("N m", 1.0), "n.m": ("N m", 1.0),
    "ncm": ("N m", 0.01), "nmm": ("N m", 1e-3),
    "m": ("m", 1.0), "mm": ("m", 1e-3), "cm": ("m", 1e-2),
    "n": ("N", 1.0), "kn": ("N", 1e3), "kgf": ("N", _G), "kp": ("N", _G),
    "lbf": ("N", 4.4482216152605),
}  # fmt: skip
"""Unit names (case-insensitive) -> (SI unit, factor)."""


def si_unit(unit: str) -> str | None:
    """The SI unit `unit` converts to ('km/h' -> 'm/s'), None if carfeel does not know it."""
    found = UNITS.get(unit.strip().lower()) or UNITS.get(unit.strip())
    return found[0] if found else None


def si_factor(unit: str) -> float:
    """The factor from `unit` to its SI unit (1.0 for a unit carfeel does not know)."""
    return UNITS.get(unit.strip().lower(), UNITS.get(unit.strip(), ("", 1.0)))[1]
