"""Opening a run's device from its command-line name, with a real device's declared dynamics
(or the defaults), and the device as the loop sees it (`ShiftedDevice`)."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.realtime.devices.base import Device, DeviceInfo
from carfeel.realtime.run_options import RealtimeRun

DEVICE_DEFAULTS = {"joystick": (10.0, 0.04), "wheel": (2.5, math.radians(450.0))}
"""A real device's force (N or Nm) and travel (m or rad) unless given: a 10 N joystick, a
2.5 Nm wheel of 900 degrees (a gear-driven wheel of the Logitech kind)."""
REAL_DYNAMICS = {"joystick": (0.1, 2.0), "wheel": (0.04, 0.03)}
"""A real device's mass (kg, kg m^2) and damping (N*s/m, Nm*s/rad) unless declared: on the low
side of consumer devices, so the sizing errs toward soft and stable."""
REAL_DELAY_S = 0.002
REAL_REPORT_HZ = 500.0
"""Unless declared: 2 ms each way, 500 reports a second (what USB force-feedback devices of the
Logitech kind manage)."""


def open_device(
    spec: str,
    hand: Any = None,
    seed: int = 0,
    kind: str = "joystick",
    max_force: float | None = None,
    travel: float | None = None,
    delay_s: float | None = None,
    report_hz: float | None = None,
    buttons: tuple[int | str, ...] = (),
) -> Device:
    """A device from its command-line name: virtual[:KIND], evdev:PATH, sdl:INDEX, replay:FILE;
    `buttons`, a real one's to read (`--lever-buttons`)."""
    force_default, travel_default = DEVICE_DEFAULTS[kind]
    force = max_force or force_default
    reach = travel or travel_default
    name, _, argument = spec.partition(":")
    if name == "virtual":
        from carfeel.realtime.devices.virtual import PLANTS, parse_virtual, virtual_device

        try:
            plant, changes = parse_virtual(argument or ("wheel" if kind == "wheel" else "joystick"))
        except ValueError as exc:
            raise InputError(f"--device {spec}: {exc}") from None
        if plant not in PLANTS or PLANTS[plant][2] != kind:
            fitting = [k for k, (_, _, c) in PLANTS.items() if c == kind]
            raise InputError(
                f"--device {spec}: this model needs one of virtual:{', virtual:'.join(fitting)} "
                "(then :KEY=VALUE,... for a true plant unlike the catalogue's)"
            )
        try:
            # A session's device keeps no log: its memory must not grow with the session.
            return virtual_device(plant, hand, delay_s, report_hz, changes, seed=seed,
                                  log_limit=0)  # fmt: skip
        except ValueError as exc:
            raise InputError(f"--device {spec}: {exc}") from None
    if name == "replay" and argument:
        from carfeel.realtime.devices.replay import ReplayDevice

        path = Path(argument)
        if not path.is_file():
            raise InputError(f"--device replay:{argument}: no such recording")
        return ReplayDevice(path)
    if name == "evdev" and argument:
        from carfeel.realtime.devices.evdev_device import EvdevDevice

        return EvdevDevice(argument, kind=kind, max_force=force, travel=reach, buttons=buttons)
    if name == "sdl" and argument:
        from carfeel.realtime.devices.sdl2_device import SDL2Device

        if not argument.isdigit():
            raise InputError(f"--device sdl:{argument}: expected a joystick index, e.g. sdl:0")
        indices = [b for b in buttons if isinstance(b, int)]
        if len(indices) != len(buttons):
            raise InputError("--lever-buttons on an SDL device: button indices 0, 1, ...")
        return SDL2Device(int(argument), kind=kind, max_force=force, travel=reach, buttons=indices)
    raise InputError(
        f"--device {spec!r}: expected virtual[:KIND], evdev:PATH (e.g. evdev:/dev/input/event5), "
        "sdl:INDEX or replay:FILE.csv; `carfeel devices` lists what is attached"
    )


def declared_info(device: Device, run: RealtimeRun, kind: str) -> DeviceInfo:
    """A real device's dynamics as declared on the command line, or the defaults; a virtual or
    replayed device knows its own (a delay or report rate given for it is already in)."""
    info = device.info
    if run.device.startswith(("virtual", "replay")):
        return info
    mass, damping = REAL_DYNAMICS[kind]
    delay = REAL_DELAY_S if run.device_delay_ms is None else run.device_delay_ms / 1e3
    return replace(
        info,
        mass=run.device_mass or mass,
        damping=run.device_damping or damping,
        command_delay_s=delay,
        reading_delay_s=delay,
        report_hz=run.device_report_hz or min(REAL_REPORT_HZ, info.update_hz),
    )


class ShiftedDevice:
    """A device seen from the loop, whose times start at the loop's start: the device itself
    is `offset_s` further on (the time its identification took)."""

    def __init__(self, device: Device, offset_s: float) -> None:
        self.device, self.offset_s = device, offset_s
        self.info = device.info

    def __enter__(self) -> ShiftedDevice:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def read(self, time_s: float) -> Any:
        return self.device.read(time_s + self.offset_s)._replace(time_s=time_s)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        self.device.command(forces, time_s + self.offset_s)
