"""What two layers agree on without importing each other: the device's reading, shared by the
1 kHz loop (`carfeel.realtime`, which reads it from a device) and the game's side
(`carfeel.telemetry`, whose driver model reads the lever from it). Types only."""

from __future__ import annotations

from typing import NamedTuple

__all__ = ["DeviceSample"]


class DeviceSample(NamedTuple):
    """One reading of a device at `time_s` (s, the loop's clock)."""

    time_s: float
    positions: tuple[float, ...]
    """Per axis, m or rad, positive as the commands."""
    forces: tuple[float, ...] | None
    """The hand's force per axis if the device measures it (N or Nm), else None."""
    buttons: tuple[bool, ...] | None = None
    """Whether each button the run asked the device for is pressed, in the order asked (a
    lever's lift, lock button, brake: `--lever-buttons`); None: none asked."""
