"""A recorded fake of the part of pysdl2 that carfeel uses (checked against pysdl2 0.9.17).

Same names, signatures and constant values as `sdl2` (SDL_INIT_*, SDL_HAPTIC_*, and copies of
its SDL_HapticDirection / SDL_HapticConstant / SDL_HapticEffect ctypes layouts, the effect union
cut to the members used). Install it for one test with

    fake = FakeSDL2([sdl_wheel()])
    monkeypatch.setitem(sys.modules, "sdl2", fake)

Every call is appended to `fake.calls` as (name, args), in order; joysticks and haptics are
`Handle`s, and an effect passed by pointer is recorded as an `EffectSnapshot`. `fake.fail(name,
nth)` makes the nth call named `name` from now fail the SDL way (-1, NULL, 0 or SDL_FALSE, with
SDL_GetError() set) and leaves the device unplugged: every later call that can fail, fails.
"""

from __future__ import annotations

import ctypes
import types
from dataclasses import dataclass, field
from typing import Any, NamedTuple

# sdl2/_sdl_init.py, sdl2/stdinc.py, sdl2/haptic.py
SDL_INIT_JOYSTICK = 0x00000200
SDL_INIT_HAPTIC = 0x00001000
SDL_FALSE = 0
SDL_TRUE = 1
SDL_HAPTIC_CONSTANT = 1 << 0
SDL_HAPTIC_SINE = 1 << 1
SDL_HAPTIC_LEFTRIGHT = 1 << 2
SDL_HAPTIC_SPRING = 1 << 7
SDL_HAPTIC_GAIN = 1 << 12
SDL_HAPTIC_AUTOCENTER = 1 << 13
SDL_HAPTIC_STATUS = 1 << 14
SDL_HAPTIC_POLAR = 0
SDL_HAPTIC_CARTESIAN = 1
SDL_HAPTIC_SPHERICAL = 2
SDL_HAPTIC_INFINITY = 4294967295


class SDL_HapticDirection(ctypes.Structure):
    _fields_ = [("type", ctypes.c_uint8), ("dir", ctypes.c_int32 * 3)]


class SDL_HapticConstant(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_uint16),
        ("direction", SDL_HapticDirection),
        ("length", ctypes.c_uint32),
        ("delay", ctypes.c_uint16),
        ("button", ctypes.c_uint16),
        ("interval", ctypes.c_uint16),
        ("level", ctypes.c_int16),
        ("attack_length", ctypes.c_uint16),
        ("attack_level", ctypes.c_uint16),
        ("fade_length", ctypes.c_uint16),
        ("fade_level", ctypes.c_uint16),
    ]


class SDL_HapticLeftRight(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_uint16),
        ("length", ctypes.c_uint32),
        ("large_magnitude", ctypes.c_uint16),
        ("small_magnitude", ctypes.c_uint16),
    ]


class SDL_HapticEffect(ctypes.Union):
    _fields_ = [
        ("type", ctypes.c_uint16),
        ("constant", SDL_HapticConstant),
        ("leftright", SDL_HapticLeftRight),
    ]


class EffectSnapshot(NamedTuple):
    """An SDL_HapticEffect as it was passed (carfeel reuses its ctypes object)."""

    type: int
    direction_type: int
    dir: tuple[int, int, int]
    length_ms: int
    level: int


@dataclass(frozen=True)
class Handle:
    """An SDL_Joystick* or SDL_Haptic*; the NULL pointer is falsy."""

    kind: str
    index: int
    null: bool = False

    def __bool__(self) -> bool:
        return not self.null


NULL = Handle("null", -1, null=True)


@dataclass
class JoystickSpec:
    """One fake SDL joystick: its axes' values and its haptic features (0: not haptic)."""

    name: str
    axes: list[int]
    features: int = SDL_HAPTIC_CONSTANT | SDL_HAPTIC_GAIN | SDL_HAPTIC_AUTOCENTER
    buttons: list[int] = field(default_factory=lambda: [0] * 4)
    """Each button's state (1: pressed); a test presses one by setting it."""
    haptic_axes: int = 0
    max_effects: int = 16
    attached: bool = True
    effects: dict[int, EffectSnapshot] = field(default_factory=dict)
    running: list[tuple[int, int]] = field(default_factory=list)
    """(effect id, iterations) of every run."""
    gain: int | None = None
    autocenter: int | None = None

    def __post_init__(self) -> None:
        if self.haptic_axes == 0:
            self.haptic_axes = len(self.axes) if self.features else 0


def sdl_wheel(name: str = "Logitech G29 Driving Force Racing Wheel") -> JoystickSpec:
    """Wheel on axis 0, pedals on 1..3; constant force, gain, autocentre; one haptic axis."""
    return JoystickSpec(name, [0, 32767, 32767, 32767], haptic_axes=1)


def sdl_joystick(name: str = "Fake Force Feedback Joystick") -> JoystickSpec:
    return JoystickSpec(name, [0, 0, 0], haptic_axes=2)


def sdl_gamepad(name: str = "Xbox 360 Controller") -> JoystickSpec:
    """Rumble only: haptic, but without a constant-force effect."""
    return JoystickSpec(name, [0] * 6, features=SDL_HAPTIC_LEFTRIGHT, haptic_axes=0)


def _snapshot(pointer: Any) -> EffectSnapshot:
    if hasattr(pointer, "contents"):  # ctypes.pointer(effect)
        effect = pointer.contents
    elif hasattr(pointer, "_obj"):  # ctypes.byref(effect)
        effect = pointer._obj
    else:  # the effect itself (ctypes passes it by reference)
        effect = pointer
    c = effect.constant
    direction = c.direction
    return EffectSnapshot(effect.type, direction.type, tuple(direction.dir), c.length, c.level)


class FakeSDL2(types.ModuleType):
    """Stands for the `sdl2` package in sys.modules; records every call in `calls`."""

    def __init__(self, joysticks: list[JoystickSpec] | None = None) -> None:
        super().__init__("sdl2")
        for name, value in globals().items():
            if name.startswith("SDL_"):
                setattr(self, name, value)
        self.joysticks = list(joysticks or [])
        self.calls: list[tuple[str, tuple[Any, ...]]] = []
        self.initialised = 0
        """SDL_Init calls not yet matched by SDL_Quit."""
        self.subsystems = 0
        """The SDL_INIT_* flags initialised (SDL refuses joystick and haptic calls without)."""
        self.open_joysticks: set[int] = set()
        self.open_haptics: set[int] = set()
        self.error = b""
        self.unplugged = False
        self._fail: list[Any] | None = None
        self._next_id = 0

    # Recording and failures
    def fail(self, name: str, nth: int = 1) -> None:
        """Unplug the device at the nth call named `name` from now."""
        self._fail = [name, nth]

    def _failing(self, name: str, args: tuple[Any, ...]) -> bool:
        """Record the call; True if it must fail (then SDL_GetError says why)."""
        self.calls.append((name, args))
        if self._fail is not None and self._fail[0] == name:
            self._fail[1] -= 1
            if self._fail[1] == 0:
                self._fail, self.unplugged = None, True
        if self.unplugged:
            self.error = b"Haptic: fake device unplugged"
        return self.unplugged

    def _void(self, name: str, args: tuple[Any, ...]) -> None:
        self.calls.append((name, args))

    def names(self) -> list[str]:
        return [name for name, _ in self.calls]

    def args_of(self, name: str) -> list[tuple[Any, ...]]:
        return [args for n, args in self.calls if n == name]

    def _set_error(self, message: str) -> int:
        self.error = message.encode()
        return -1

    def _refused(self, subsystem: int, handle: Handle | None = None) -> bool:
        """SDL's own checks: the subsystem initialised, the handle open (SDL's messages)."""
        if not self.subsystems & subsystem:
            name = "Joystick" if subsystem == SDL_INIT_JOYSTICK else "Haptic"
            self._set_error(f"{name} subsystem not initialized")
            return True
        if handle is None:
            return False
        if handle.kind == "joystick" and handle.index not in self.open_joysticks:
            self._set_error("Joystick hasn't been opened yet")
            return True
        if handle.kind == "haptic" and handle.index not in self.open_haptics:
            self._set_error("Haptic: Invalid haptic device identifier")
            return True
        return False

    # SDL_Init / error
    def SDL_Init(self, flags: int) -> int:
        if self._failing("SDL_Init", (flags,)):
            return -1
        self.initialised += 1
        self.subsystems |= flags
        return 0

    def SDL_Quit(self) -> None:
        self._void("SDL_Quit", ())
        self.initialised = 0
        self.subsystems = 0
        self.open_joysticks.clear()
        self.open_haptics.clear()

    def SDL_GetError(self) -> bytes:
        self._void("SDL_GetError", ())
        return self.error

    # Joysticks
    def SDL_NumJoysticks(self) -> int:
        if self._failing("SDL_NumJoysticks", ()):
            return -1
        if self._refused(SDL_INIT_JOYSTICK, None):
            return -1
        return len(self.joysticks)

    def SDL_JoystickNameForIndex(self, device_index: int) -> bytes | None:
        if self._failing("SDL_JoystickNameForIndex", (device_index,)):
            return None
        if self._refused(SDL_INIT_JOYSTICK, None):
            return None
        if not 0 <= device_index < len(self.joysticks):
            self._set_error(f"There are {len(self.joysticks)} joysticks available")
            return None
        return self.joysticks[device_index].name.encode()

    def SDL_JoystickOpen(self, device_index: int) -> Handle:
        if self._failing("SDL_JoystickOpen", (device_index,)):
            return NULL
        if self._refused(SDL_INIT_JOYSTICK, None):
            return NULL
        if not 0 <= device_index < len(self.joysticks):
            self._set_error(f"There are {len(self.joysticks)} joysticks available")
            return NULL
        self.open_joysticks.add(device_index)
        return Handle("joystick", device_index)

    def SDL_JoystickClose(self, joystick: Handle) -> None:
        self._void("SDL_JoystickClose", (joystick,))
        self.open_joysticks.discard(joystick.index)

    def SDL_JoystickNumAxes(self, joystick: Handle) -> int:
        if self._failing("SDL_JoystickNumAxes", (joystick,)):
            return -1
        if self._refused(SDL_INIT_JOYSTICK, joystick):
            return -1
        return len(self.joysticks[joystick.index].axes)

    def SDL_JoystickNumButtons(self, joystick: Handle) -> int:
        if self._failing("SDL_JoystickNumButtons", (joystick,)):
            return -1
        if self._refused(SDL_INIT_JOYSTICK, joystick):
            return -1
        return len(self.joysticks[joystick.index].buttons)

    def SDL_JoystickGetButton(self, joystick: Handle, button: int) -> int:
        if self._failing("SDL_JoystickGetButton", (joystick, button)):
            return 0
        if self._refused(SDL_INIT_JOYSTICK, joystick):
            return 0
        buttons = self.joysticks[joystick.index].buttons
        return buttons[button] if 0 <= button < len(buttons) else 0

    def SDL_JoystickUpdate(self) -> None:
        self._void("SDL_JoystickUpdate", ())

    def SDL_JoystickGetAttached(self, joystick: Handle) -> int:
        if self._failing("SDL_JoystickGetAttached", (joystick,)):
            return SDL_FALSE
        if self._refused(SDL_INIT_JOYSTICK, joystick):
            return SDL_FALSE
        return SDL_TRUE if self.joysticks[joystick.index].attached else SDL_FALSE

    def SDL_JoystickGetAxis(self, joystick: Handle, axis: int) -> int:
        if self._failing("SDL_JoystickGetAxis", (joystick, axis)):
            return 0
        if self._refused(SDL_INIT_JOYSTICK, joystick):
            return 0
        return self.joysticks[joystick.index].axes[axis]

    def SDL_JoystickIsHaptic(self, joystick: Handle) -> int:
        if self._failing("SDL_JoystickIsHaptic", (joystick,)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, joystick):
            return -1
        return SDL_TRUE if self.joysticks[joystick.index].features else SDL_FALSE

    # Haptics
    def SDL_HapticOpenFromJoystick(self, joystick: Handle) -> Handle:
        if self._failing("SDL_HapticOpenFromJoystick", (joystick,)):
            return NULL
        if self._refused(SDL_INIT_HAPTIC, joystick):
            return NULL
        if not self.joysticks[joystick.index].features:
            self._set_error("Haptic: Joystick isn't a haptic device.")
            return NULL
        self.open_haptics.add(joystick.index)
        return Handle("haptic", joystick.index)

    def SDL_HapticClose(self, haptic: Handle) -> None:
        self._void("SDL_HapticClose", (haptic,))
        self.open_haptics.discard(haptic.index)

    def SDL_HapticQuery(self, haptic: Handle) -> int:
        if self._failing("SDL_HapticQuery", (haptic,)):
            return 0
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return 0
        return self.joysticks[haptic.index].features

    def SDL_HapticNumAxes(self, haptic: Handle) -> int:
        if self._failing("SDL_HapticNumAxes", (haptic,)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        return self.joysticks[haptic.index].haptic_axes

    def SDL_HapticSetGain(self, haptic: Handle, gain: int) -> int:
        if self._failing("SDL_HapticSetGain", (haptic, gain)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        spec = self.joysticks[haptic.index]
        if not spec.features & SDL_HAPTIC_GAIN:
            return self._set_error("Haptic: Device does not support setting gain.")
        spec.gain = gain
        return 0

    def SDL_HapticSetAutocenter(self, haptic: Handle, autocenter: int) -> int:
        if self._failing("SDL_HapticSetAutocenter", (haptic, autocenter)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        spec = self.joysticks[haptic.index]
        if not spec.features & SDL_HAPTIC_AUTOCENTER:
            return self._set_error("Haptic: Device does not support setting autocenter.")
        spec.autocenter = autocenter
        return 0

    def SDL_HapticNewEffect(self, haptic: Handle, effect: Any) -> int:
        snapshot = _snapshot(effect)
        if self._failing("SDL_HapticNewEffect", (haptic, snapshot)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        spec = self.joysticks[haptic.index]
        if not spec.features & snapshot.type:
            return self._set_error("Haptic: Effect not supported by haptic device.")
        if len(spec.effects) >= spec.max_effects:
            return self._set_error("Haptic: Device has no free space left.")
        effect_id = self._next_id
        self._next_id += 1
        spec.effects[effect_id] = snapshot
        return effect_id

    def SDL_HapticUpdateEffect(self, haptic: Handle, effect: int, data: Any) -> int:
        snapshot = _snapshot(data)
        if self._failing("SDL_HapticUpdateEffect", (haptic, effect, snapshot)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        spec = self.joysticks[haptic.index]
        if effect not in spec.effects:
            return self._set_error("Haptic: Invalid effect identifier.")
        if spec.effects[effect].type != snapshot.type:
            return self._set_error("Haptic: Updating effect type is illegal.")
        spec.effects[effect] = snapshot
        return 0

    def SDL_HapticRunEffect(self, haptic: Handle, effect: int, iterations: int) -> int:
        if self._failing("SDL_HapticRunEffect", (haptic, effect, iterations)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        spec = self.joysticks[haptic.index]
        if effect not in spec.effects:
            return self._set_error("Haptic: Invalid effect identifier.")
        spec.running.append((effect, iterations))
        return 0

    def SDL_HapticStopAll(self, haptic: Handle) -> int:
        if self._failing("SDL_HapticStopAll", (haptic,)):
            return -1
        if self._refused(SDL_INIT_HAPTIC, haptic):
            return -1
        return 0

    def SDL_HapticDestroyEffect(self, haptic: Handle, effect: int) -> None:
        self._void("SDL_HapticDestroyEffect", (haptic, effect))
        self.joysticks[haptic.index].effects.pop(effect, None)
