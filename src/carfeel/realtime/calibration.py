"""`carfeel calibrate`: identify a device hands off, through the safety chain, and store its
profile (`realtime.knowledge`)."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.realtime.clock import Clock, SimulatedClock, WallClock
from carfeel.realtime.opening import open_device
from carfeel.realtime.run_options import MAX_RATE_HZ, MIN_RATE_HZ


@dataclass(frozen=True, slots=True)
class Calibration:
    """`carfeel calibrate`: identify a device hands off and store its profile."""

    device: str = "virtual"
    kind: str | None = None
    """joystick or wheel; None: a virtual device's own, else joystick."""
    rate_hz: float = 1000.0
    clock: str = "wall"
    device_max_force: float | None = None
    device_travel: float | None = None
    device_delay_ms: float | None = None
    device_report_hz: float | None = None
    device_profile: Path | None = None
    seed: int = 0
    loop_cpu: int | None = None


def calibrate_device(calibration: Calibration, say: Callable[[str], None] | None = None) -> Any:
    """Identify the device (hands off, through the safety chain) and write its profile; the
    `knowledge.Knowledge` measured (its `profile` is where it was written)."""
    from carfeel.realtime.knowledge import know_device, real_max_force
    from carfeel.realtime.scheduling import claimed

    c = calibration
    kind = c.kind
    if kind is None:
        kind = "joystick"
        name, _, argument = c.device.partition(":")
        if name == "virtual" and argument:
            from carfeel.realtime.devices.virtual import PLANTS

            plant = argument.partition(":")[0]
            if plant in PLANTS:
                kind = PLANTS[plant][2]
        elif name == "virtual":
            kind = "joystick"
    if kind not in ("joystick", "wheel"):
        raise InputError(f"--kind {kind!r}: choose joystick or wheel")
    if c.device.startswith("replay"):
        raise InputError("a replayed device cannot be identified (it plays back a recording)")
    if c.clock == "simulated" and not c.device.startswith("virtual"):
        raise InputError("--clock simulated needs a virtual device; a real one lives in wall time")
    if not (MIN_RATE_HZ <= c.rate_hz <= MAX_RATE_HZ):
        raise InputError(f"--rate-hz {c.rate_hz:g}: allowed {MIN_RATE_HZ:g} .. {MAX_RATE_HZ:g}")
    virtual = c.device.startswith("virtual")
    if virtual and (c.device_max_force is not None or c.device_travel is not None):
        raise InputError(
            "--device-max-force and --device-travel describe a real device; the virtual ones "
            "have their own"
        )
    delay = None if c.device_delay_ms is None else c.device_delay_ms / 1e3
    device = open_device(c.device, None, c.seed, kind, c.device_max_force, c.device_travel,
                         delay, c.device_report_hz)  # fmt: skip
    clock: Clock = SimulatedClock() if c.clock == "simulated" else WallClock()
    with claimed(c.loop_cpu, wanted=c.clock == "wall"), device:
        if not virtual:
            device.info = replace(device.info, max_force=real_max_force(device, c.device_max_force))
        return know_device(device, clock, c.rate_hz, clock.now_ns(), "full", c.device_profile, say)
