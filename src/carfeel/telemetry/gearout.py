"""Gear out: the H-shifter's slot as a virtual joystick's buttons (the sim-racing convention).

One button per gear slot, held while the lever is in that slot (`slot`) or once the gear is in
mesh (`engaged`: some games decide grind or shift themselves); neutral releases all. Backends:
Linux uinput (python-evdev, imported lazily, the `devices` extra), Windows vJoy (its own
interface DLL through ctypes: nothing to install but the driver), and a recording fake.

The mappings a game binds to (`GEAR_MAPPINGS`), each a pure function from a gear change to
button actions, so that it is tested without a device: `buttons` (a button per gear, held: the
H-shifter binding), `sequential` (an up and a down button, pulsed once per gear step: the
paddle or sequential binding), `range-splitter` (a truck's: a button per handle position,
held, plus a range and a splitter button held while high, from the game's own slot table).
`GearFollower` drives an output from a sequence of target gears (the game's, or the lever's)
with the pulses spaced in time as a game polls its inputs.
"""

from __future__ import annotations

import importlib
import math
import sys
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


GEAR_MAPPINGS = ("buttons", "sequential", "range-splitter")
NEUTRAL_REST_S = 1.0
"""Sequential binding: the lever in neutral this long means neutral; shorter, it is crossing
between two gears (the virtual hand's shifts rest 0.5-0.7 s there, a quick hand's 0.1-0.3)."""
PULSE_S = 0.05
"""A sequential pulse is held 50 ms and followed by 50 ms released: three frames of a 60 Hz
game, which samples its buttons once a frame."""


class GearOutput(Protocol):
    def press(self, button: int) -> None:
        """Hold `button` (0-based) and release any other."""
        ...

    def hold(self, mask: int) -> None:
        """Hold exactly the buttons of `mask` (bit i: button i)."""
        ...

    def release_all(self) -> None: ...

    def close(self) -> None: ...


Action = tuple[str, int]
"""("press", button): hold it alone; ("release", -1): release all; ("pulse", button): press
then release after PULSE_S; ("hold", bitmask): hold exactly the buttons of the bitmask."""


def buttons_for(gear: int, forward: int) -> list[Action]:
    """`buttons`: gear g (1..) holds button g - 1, reverse the button after the forward ones,
    neutral releases all."""
    if gear == 0:
        return [("release", -1)]
    return [("press", forward if gear < 0 else gear - 1)]


def prnd_buttons(position: int, positions: int) -> list[Action]:
    """An automatic's selector (models.gearshift.prnd): position index i (0 = P, 1 = R, 2 = N,
    3 = D, then any the preset adds) holds button i alone; every position has its own button,
    so a game bound to them sees P and N too."""
    if not 0 <= position < positions:
        raise ValueError(f"selector position {position} outside 0 .. {positions - 1}")
    return [("press", position)]


def sequential_for(before: int, after: int) -> list[Action]:
    """`sequential`: button 0 up, 1 down, one pulse per step (reverse below neutral, as the
    sequential games count: R, N, 1, 2 ...)."""
    step = after - before
    return [("pulse", 0 if step > 0 else 1)] * abs(step)


def range_splitter_for(gear: int, slots: tuple[tuple[int, int, int], ...], positions: int
                       ) -> list[Action] | None:  # fmt: skip
    """`range-splitter`: the game's slot table's first slot that gives `gear`: its handle
    position's button (0 .. positions - 1) held, then the range button (`positions`) and the
    splitter button (`positions + 1`) held where its selector's bit 0 or bit 1 is set; neutral
    releases all. None where the table has no slot for the gear."""
    if gear == 0:
        return [("release", -1)]
    for position, selector, slot_gear in slots:
        if slot_gear == gear and 0 <= position < positions:
            mask = 1 << position
            if selector & 1:
                mask |= 1 << positions
            if selector & 2:
                mask |= 1 << (positions + 1)
            return [("hold", mask)]
    return None


def gears_from_buttons(calls: list[tuple[str, Any]], mapping: str, forward: int,
                       slots: tuple[tuple[int, int, int], ...] = (), positions: int = 0,
                       start: int = 0) -> list[int]:  # fmt: skip
    """What a game bound to `mapping` reads from an output's calls, as its gear after each
    call (the inverse of the mappings, for tests and for checking a binding)."""
    gear, out = start, []
    pending: int | None = None
    for name, value in calls:
        if mapping == "buttons":
            if name == "press":
                gear = -1 if value == forward else value + 1
            elif name == "release_all":
                gear = 0
            else:
                continue
        elif mapping == "sequential":
            if name == "press":
                pending = value
                continue
            if name != "release_all" or pending is None:
                continue
            gear += 1 if pending == 0 else -1
            pending = None
        else:
            if name == "release_all":
                gear = 0
            elif name == "hold":
                position = next(p for p in range(positions) if value >> p & 1)
                selector = (value >> positions & 1) | (value >> (positions + 1) & 1) << 1
                gear = next(g for p, sel, g in slots if p == position and sel == selector)
            else:
                continue
        out.append(gear)
    return out


class GearFollower:
    """Drives `output` towards a target gear each tick, through `mapping`; sequential pulses
    are queued and spaced by PULSE_S of the tick's clock (never two presses in one frame)."""

    def __init__(
        self, output: Any, mapping: str, forward: int,
        slots: tuple[tuple[int, int, int], ...] = (), positions: int = 0,
    ) -> None:  # fmt: skip
        if mapping not in GEAR_MAPPINGS:
            raise InputError(
                f"--gear-mapping {mapping!r}: choose one of {', '.join(GEAR_MAPPINGS)}"
            )
        self.output, self.mapping, self.forward = output, mapping, forward
        self.slots, self.positions = slots, positions
        self.gear = 0
        """The gear the output has told the game so far."""
        self.queue: list[int] = []
        self.next_s = -1.0
        self.pressed = False
        self.unmapped = 0
        """Target gears the mapping could not express (no slot in the table)."""
        self._last = 0

    def update(self, gear: int, t_s: float) -> None:
        if self.mapping == "sequential":
            if not self.queue and not self.pressed and gear != self.gear:
                self.queue = [b for _, b in sequential_for(self.gear, gear)]
            self._pulse(t_s)
            return
        if gear == self.gear:
            return
        if self.mapping == "buttons":
            actions = buttons_for(gear, self.forward)
        else:
            found = range_splitter_for(gear, self.slots, self.positions)
            if found is None:
                self.unmapped += 1
                return
            actions = found
        for name, value in actions:
            if name == "press":
                self.output.press(value)
            elif name == "hold":
                self.output.hold(value)
            else:
                self.output.release_all()
        self.gear = gear

    def _pulse(self, t_s: float) -> None:
        if t_s < self.next_s:
            return
        if self.pressed:
            self.output.release_all()
            self.pressed = False
            self.gear += 1 if self._last == 0 else -1
            self.next_s = t_s + PULSE_S
        elif self.queue:
            self._last = self.queue.pop(0)
            self.output.press(self._last)
            self.pressed = True
            self.next_s = t_s + PULSE_S

    def release(self) -> None:
        self.output.release_all()
        self.queue.clear()
        self.pressed = False


class RecordingGearOutput:
    """The fake: records every call; `held` is the button held now (None: none)."""

    def __init__(self) -> None:
        self.calls: list[tuple[str, int | None]] = []
        self.held: int | None = None

    def press(self, button: int) -> None:
        self.calls.append(("press", button))
        self.held = button

    def hold(self, mask: int) -> None:
        """Hold exactly the buttons of `mask` (bit i: button i)."""
        self.calls.append(("hold", mask))
        self.held = mask

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
            if not sys.platform.startswith("linux"):  # python-evdev installs on Linux only
                instead = (
                    "use --gear-output vjoy (the vJoy driver)"
                    if sys.platform == "win32"
                    else "carfeel has no gear output"
                )
                raise InputError(
                    f"--gear-output uinput is Linux's (the kernel's uinput); on {sys.platform} "
                    f"{instead}"
                ) from exc
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

    def hold(self, mask: int) -> None:
        """Hold exactly the buttons of `mask` (bit i: button i), in one report."""
        for button in range(len(self.keys)):
            self._set(button, mask >> button & 1)
        self.device.syn()
        self.held = None

    def release_all(self) -> None:
        for button in range(len(self.keys)):
            self._set(button, 0)
        self.device.syn()
        self.held = None

    def close(self) -> None:
        self.release_all()
        self.device.close()


VJOY_DLL_PATHS = (
    r"C:\Program Files\vJoy\x64\vJoyInterface.dll",
    r"C:\Program Files\vJoy\x86\vJoyInterface.dll",
    "vJoyInterface.dll",
)
"""Where the vJoy driver's installer puts its interface DLL (the original's and the maintained
fork's, which keep its API); the last: wherever Windows' DLL search finds it."""
VJD_STAT_OWN, VJD_STAT_FREE = 0, 1


def _load_vjoy() -> Any:
    import ctypes

    loader = getattr(ctypes, "WinDLL", None)
    if loader is None:
        raise InputError(
            "--gear-output vjoy is Windows' (the vJoy driver); on Linux use --gear-output uinput"
        )
    for path in VJOY_DLL_PATHS:
        try:
            return loader(path)
        except OSError:
            continue
    raise InputError(
        "--gear-output vjoy: vJoyInterface.dll not found: install the vJoy driver (its "
        "installer puts the DLL in C:\\Program Files\\vJoy) and configure device 1 with "
        "enough buttons (vJoyConf)"
    )


class VJoyGearOutput:
    """vJoy's device `rid` through its own interface DLL (ctypes: AcquireVJD, SetBtn,
    RelinquishVJD), so nothing but the driver is needed (pyvjoy, a thin wrapper of the same
    DLL, is unmaintained since 2019; vgamepad emulates an Xbox pad, too few buttons for a
    truck's 14+2)."""

    def __init__(self, buttons: int, rid: int = 1, dll: Any = None) -> None:
        self.dll = dll if dll is not None else _load_vjoy()
        if not self.dll.vJoyEnabled():
            raise InputError("--gear-output vjoy: the vJoy driver is installed but not enabled")
        status = self.dll.GetVJDStatus(rid)
        if status not in (VJD_STAT_OWN, VJD_STAT_FREE) or not self.dll.AcquireVJD(rid):
            raise InputError(
                f"--gear-output vjoy: vJoy device {rid} is not free (status {status}: another "
                "program holds it, or it is not configured in vJoyConf)"
            )
        have = self.dll.GetVJDButtonNumber(rid)
        if have < buttons:
            self.dll.RelinquishVJD(rid)
            raise InputError(
                f"--gear-output vjoy: vJoy device {rid} has {have} buttons, {buttons} needed: "
                "add them in vJoyConf"
            )
        self.rid, self.buttons = rid, buttons
        self.held: int | None = None

    def _set(self, button: int, value: int) -> None:
        self.dll.SetBtn(value, self.rid, button + 1)  # vJoy buttons are 1-based

    def press(self, button: int) -> None:
        if self.held is not None and self.held != button:
            self._set(self.held, 0)
        self._set(button, 1)
        self.held = button

    def hold(self, mask: int) -> None:
        for button in range(self.buttons):
            self._set(button, mask >> button & 1)
        self.held = None

    def release_all(self) -> None:
        for button in range(self.buttons):
            self._set(button, 0)
        self.held = None

    def close(self) -> None:
        self.release_all()
        self.dll.RelinquishVJD(self.rid)


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

    def __init__(
        self, output: GearOutput, layout: Any, timing: str = "slot", mapping: str = "buttons",
        rate_hz: float = 1000.0,
    ) -> None:  # fmt: skip
        if timing not in GEAR_TIMINGS:
            raise InputError(f"--gear-timing {timing!r}: choose one of {', '.join(GEAR_TIMINGS)}")
        if mapping not in GEAR_MAPPINGS:
            raise InputError(
                f"--gear-mapping {mapping!r}: choose one of {', '.join(GEAR_MAPPINGS)}"
            )
        if mapping == "range-splitter" and not layout.truck:
            raise InputError(
                "--gear-mapping range-splitter needs a truck's layout (a range/splitter gear "
                "table, `layout.truck`: --preset truck-14r2); for this layout use buttons or "
                "sequential"
            )
        self.output, self.layout, self.timing = output, layout, timing
        self.mapping = mapping
        self.positions = button_count(layout, "range-splitter") - 2 if layout.truck else 0
        names = sorted((g.name for g in layout.gears), key=lambda n: (n == "R", n))
        self.buttons = {name: i for i, name in enumerate(names)}
        self.held: str | None = None
        self.held_truck: tuple[str, bool, bool] | None = None
        """`range-splitter`: the gear, range and splitter whose buttons are held."""
        forward = sum(1 for n in names if n != "R")
        self.follower = (
            GearFollower(output, "sequential", forward) if mapping == "sequential" else None
        )
        self.ticks, self.rate_hz = 0, rate_hz
        self.neutral_since = math.inf
        self.follower_target = 0

    def update(self, state: Any) -> None:
        name: str | None
        if self.timing == "slot":
            slot = self.layout.gear_at(state.plane, state.direction) if state.in_slot else None
            name = None if slot is None else slot.name
        else:
            name = None if state.gear == "N" else state.gear
        if self.layout.truck:
            name = self._truck(state, name)
            if self.mapping == "range-splitter":
                self._hold(state, name)
                return
        if self.follower is not None:  # sequential: pulses towards the lever's gear
            t = self.ticks / self.rate_hz
            self.ticks += 1
            if name is None:  # the lever crosses neutral between two gears: not a gear step
                self.neutral_since = min(self.neutral_since, t)
                resting = t - self.neutral_since >= NEUTRAL_REST_S
                target = 0 if resting else self.follower_target
            else:
                self.neutral_since = math.inf
                target = gear_number(name)
            self.follower_target = target
            self.follower.update(target, t)
            return
        if name != self.held:
            if name is None:
                self.output.release_all()
            else:
                self.output.press(self.buttons[name])
            self.held = name

    def _truck(self, state: Any, name: str | None) -> str | None:
        """A truck's gear (the table's name) from its slot, range and splitter in effect; with
        `buttons` the slot's own name (a button per slot, as the H-shifter binding has)."""
        if name is None:
            return None
        slot = self.layout.gear_at(state.plane, state.direction)
        if slot is None:
            return None
        if self.mapping == "buttons":
            return str(slot.name)
        row = self.layout.truck_gear(slot.name, state.range_high, state.splitter_high)
        return None if row is None else str(row.name)

    def _hold(self, state: Any, name: str | None) -> None:
        """`range-splitter`: the slot's handle-position button held, with the range button
        (`positions`) and the splitter button (`positions + 1`) held while high: the switches'
        states the box has executed (a pre-selection shows once it takes effect, so the game
        reads the gear the lever is in)."""
        key = None if name is None else (name, bool(state.range_high), bool(state.splitter_high))
        if key == self.held_truck:
            return
        if name is None:
            self.output.release_all()
        else:
            slot = self.layout.gear_at(state.plane, state.direction)
            row = self.layout.truck_gear(slot.name, state.range_high, state.splitter_high)
            mask = 1 << row.handle_position
            mask |= (state.range_high << self.positions) | (
                state.splitter_high << (self.positions + 1)
            )
            self.output.hold(mask)
        self.held_truck = key

    def release(self) -> None:
        self.output.release_all()
        self.held = self.held_truck = None
        if self.follower is not None:
            self.follower.release()


def gear_number(name: str) -> int:
    """A gear's number as games count it: "3" -> 3, "R" -> -1, "R2" -> -2."""
    if name.startswith("R"):
        return -int(name[1:] or 1)
    return int(name)


def button_count(layout: Any, mapping: str) -> int:
    """Buttons the gear output needs for `layout` through `mapping`: a truck's handle
    positions and its range and splitter buttons for `range-splitter`, else one per slot."""
    if mapping == "range-splitter" and layout.truck:
        return int(max(row.handle_position for row in layout.truck)) + 1 + 2
    return len(layout.gears)
