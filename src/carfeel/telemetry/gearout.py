"""Gear out: the H-shifter's slot as a virtual joystick's buttons (the sim-racing convention).

One button per gear slot, held while the lever is in that slot (`slot`) or once the gear is in
mesh (`engaged`: some games decide grind or shift themselves); neutral releases all. Backends:
Linux uinput (python-evdev), Windows vJoy (pyvjoy), and a recording fake; the first two are
imported lazily and come with the `devices` extra.
"""

from __future__ import annotations

import importlib
from typing import Any, Protocol

from carfeel.errors import InputError

GEAR_OUTPUTS = ("none", "uinput", "vjoy")
GEAR_TIMINGS = ("slot", "engaged")
UINPUT_NAME = "carfeel H-shifter"
"""A stable name (and vendor/product ids) so that games keep their bindings across runs."""
UINPUT_VENDOR, UINPUT_PRODUCT = 0x1209, 0xCAFE
BTN_JOYSTICK = 0x120
"""BTN_TRIGGER .. BTN_BASE6 (0x120-0x12f): buttons in this range tag the device a joystick
(udev's ID_INPUT_JOYSTICK)."""


class GearOutput(Protocol):
    def press(self, button: int) -> None:
        """Hold `button` (0-based) and release any other."""
        ...

    def release_all(self) -> None: ...

    def close(self) -> None: ...


class RecordingGearOutput:
    """The fake: records every call; `held` is the button held now (None: none)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, int | None]] = []
        self.held: int | None = None

    def press(self, button: int) -> None:
        self.calls.append(("press", button))
        self.held = button

    def release_all(self) -> None:
        self.calls.append(("release_all", None))
        self.held = None

    def close(self) -> None:
        self.calls.append(("close", None))
        self.held = None


class UInputGearOutput:
    """A uinput joystick with one button per slot (needs write access to /dev/uinput)."""

    def __init__(self, buttons: int) -> None:
        try:
            evdev: Any = importlib.import_module("evdev")
        except ImportError as exc:
            raise InputError(
                "--gear-output uinput needs python-evdev: pip install 'carfeel[devices]'"
            ) from exc
        e = evdev.ecodes
        self._e = e
        self.keys = [BTN_JOYSTICK + i for i in range(buttons)]
        try:
            self.device: Any = evdev.UInput(
                {e.EV_KEY: self.keys}, name=UINPUT_NAME, vendor=UINPUT_VENDOR,
                product=UINPUT_PRODUCT, version=1,
            )  # fmt: skip
        except (OSError, evdev.UInputError) as exc:
            raise InputError(
                f"--gear-output uinput: cannot create the virtual joystick ({exc}); it needs "
                "write access to /dev/uinput (the uinput module loaded, a udev rule or the "
                "input group)"
            ) from exc
        self.held: int | None = None

    def _set(self, button: int, value: int) -> None:
        self.device.write(self._e.EV_KEY, self.keys[button], value)

    def press(self, button: int) -> None:
        if self.held is not None and self.held != button:
            self._set(self.held, 0)
        self._set(button, 1)
        self.device.syn()
        self.held = button

    def release_all(self) -> None:
        for button in range(len(self.keys)):
            self._set(button, 0)
        self.device.syn()
        self.held = None

    def close(self) -> None:
        self.release_all()
        self.device.close()


class VJoyGearOutput:
    """vJoy's device `rid` (Windows; the vJoy driver and pyvjoy installed)."""

    def __init__(self, buttons: int, rid: int = 1) -> None:
        try:
            pyvjoy: Any = importlib.import_module("pyvjoy")
        except ImportError as exc:
            raise InputError(
                "--gear-output vjoy needs the vJoy driver and pyvjoy: pip install pyvjoy"
            ) from exc
        try:
            self.device: Any = pyvjoy.VJoyDevice(rid)
        except Exception as exc:  # pyvjoy raises its own exception types
            raise InputError(f"--gear-output vjoy: vJoy device {rid} unavailable ({exc})") from exc
        self.buttons = buttons
        self.held: int | None = None

    def press(self, button: int) -> None:
        if self.held is not None and self.held != button:
            self.device.set_button(self.held + 1, 0)  # vJoy buttons are 1-based
        self.device.set_button(button + 1, 1)
        self.held = button

    def release_all(self) -> None:
        for button in range(self.buttons):
            self.device.set_button(button + 1, 0)
        self.held = None

    def close(self) -> None:
        self.release_all()


def open_gear_output(name: str, buttons: int) -> GearOutput | None:
    if name == "none":
        return None
    if name == "uinput":
        return UInputGearOutput(buttons)
    if name == "vjoy":
        return VJoyGearOutput(buttons)
    raise InputError(f"--gear-output {name!r}: choose one of {', '.join(GEAR_OUTPUTS)}")


class GearDriver:
    """Watches the H-pattern's state each tick and holds the button of its slot or gear.

    Buttons: the forward gears in order (1 -> button 0), then reverse."""

    def __init__(self, output: GearOutput, layout: Any, timing: str = "slot") -> None:
        if timing not in GEAR_TIMINGS:
            raise InputError(f"--gear-timing {timing!r}: choose one of {', '.join(GEAR_TIMINGS)}")
        self.output, self.layout, self.timing = output, layout, timing
        names = sorted((g.name for g in layout.gears), key=lambda n: (n == "R", n))
        self.buttons = {name: i for i, name in enumerate(names)}
        self.held: str | None = None

    def update(self, state: Any) -> None:
        name: str | None
        if self.timing == "slot":
            slot = self.layout.gear_at(state.plane, state.direction) if state.in_slot else None
            name = None if slot is None else slot.name
        else:
            name = None if state.gear == "N" else state.gear
        if name != self.held:
            if name is None:
                self.output.release_all()
            else:
                self.output.press(self.buttons[name])
            self.held = name

    def release(self) -> None:
        self.output.release_all()
        self.held = None
