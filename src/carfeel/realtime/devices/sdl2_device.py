"""A force-feedback joystick or wheel through SDL2 haptics (pysdl2 + pysdl2-dll, lazily imported).

Positions: SDL_JoystickGetAxis (-32768..32767) scaled to [-travel, +travel] (m or rad).
Forces: one SDL_HAPTIC_CONSTANT effect per axis, a cartesian direction and a signed level:

    axis 0 (X, a wheel's only axis): dir = (1, 0)    level = +0x7FFF * force / max_force
    axis 1 (Y):                       dir = (0, 1)    (clamped to -0x7FFF..0x7FFF)

SDL's Linux backend turns (1, 0) into the evdev direction 0x4000 and (0, 1) into 0x8000, so
both backends send the same effect for the same force (see `evdev_device`). `invert_force`
flips the force of all axes for a device that pushes the other way, `signs` flips an axis.

The effects last `hold_s` and are refreshed as in the evdev backend (`LevelSchedule`): a level
goes out when it changed, no faster than `update_hz`, and every `hold_s / 2` while not zero.
"""

from __future__ import annotations

import ctypes
import dataclasses
import importlib
from collections.abc import Sequence
from types import ModuleType, TracebackType
from typing import Any

from carfeel.errors import InputError
from carfeel.realtime.devices.base import DeviceError, DeviceInfo, DeviceLost, DeviceSample
from carfeel.realtime.devices.evdev_device import (
    PIP_HINT,
    AxisScale,
    LevelSchedule,
    axis_scale,
    force_level,
    signs_of,
    validate,
)

AXIS_MIN = -32768
AXIS_MAX = 32767
GAIN_FULL_PERCENT = 100


def import_sdl2() -> ModuleType:
    """pysdl2 with its SDL2 library, or a DeviceError that says how to install them."""
    try:
        return importlib.import_module("sdl2")
    except ImportError as exc:  # pysdl2 missing, or present without an SDL2 library
        raise DeviceError(
            f"the SDL2 backend needs pysdl2 and pysdl2-dll: {PIP_HINT} ({exc})"
        ) from exc


def sdl_error(sdl2: ModuleType) -> str:
    """SDL's last error message, as text."""
    message = sdl2.SDL_GetError()
    if isinstance(message, bytes):
        message = message.decode("utf-8", "replace")
    return str(message or "no SDL error message")


class SDL2Device:
    """The SDL joystick at `index` with its haptic device, as a `Device`.

    `max_force` is the force (N, joystick) or torque (Nm, wheel) at full level; `travel` the
    half-range (m or rad) that an axis's -32768..32767 spans. `axis_indices` are the SDL axes
    read (default 0, 1 for a joystick and 0 for a wheel). `signs` flips an axis (+1 or -1 per
    axis), `invert_force` the force of all axes.
    """

    def __init__(
        self,
        index: int = 0,
        *,
        kind: str = "wheel",
        max_force: float,
        travel: float,
        axis_indices: Sequence[int] | None = None,
        hold_s: float = 0.1,
        update_hz: float = 500.0,
        level_quantum: int = 8,
        signs: Sequence[int] | None = None,
        invert_force: bool = False,
        buttons: Sequence[int] = (),
    ) -> None:
        axes = len(axis_indices) if axis_indices is not None else (2 if kind == "joystick" else 1)
        self._hold_ms = validate(kind, axes, max_force, travel, hold_s, update_hz)
        if level_quantum < 0:
            raise InputError(f"level_quantum = {level_quantum} must be >= 0 (levels)")
        if index < 0:
            raise InputError(f"SDL joystick index = {index} must be >= 0")
        if axis_indices is not None and any(i < 0 for i in axis_indices):
            raise InputError(f"axis_indices = {tuple(axis_indices)} must be >= 0")
        if any(isinstance(b, bool) or not isinstance(b, int) or b < 0 for b in buttons):
            raise InputError(
                f"buttons = {tuple(buttons)}: SDL numbers a joystick's buttons 0, 1, ..."
            )
        self._buttons = tuple(buttons)
        """The joystick's button indices whose state `read` reports."""
        self.index = index
        self.info = DeviceInfo(
            f"SDL joystick {index}", kind, axes, max_force, travel, update_hz, measures_force=False
        )
        self.hold_s = hold_s
        self.level_quantum = level_quantum
        self._axis_indices = tuple(axis_indices) if axis_indices is not None else tuple(range(axes))
        signs_ = signs_of(signs, axes)
        self._scales = tuple(axis_scale(AXIS_MIN, AXIS_MAX, travel, s) for s in signs_)
        self._polarity = tuple(-s if invert_force else s for s in signs_)
        self._sdl: ModuleType | None = None
        self._joystick: Any = None
        self._haptic: Any = None
        self._effects: list[Any] = []
        self._pointers: list[Any] = []
        self._ids: list[int] = []
        self._schedule = LevelSchedule(axes, update_hz, hold_s, level_quantum)

    def __enter__(self) -> SDL2Device:
        sdl2 = import_sdl2()
        if sdl2.SDL_Init(sdl2.SDL_INIT_JOYSTICK | sdl2.SDL_INIT_HAPTIC) < 0:
            raise DeviceError(f"SDL_Init (joystick, haptic) failed: {sdl_error(sdl2)}")
        self._sdl = sdl2
        self._schedule = LevelSchedule(
            self.info.axes, self.info.update_hz, self.hold_s, self.level_quantum
        )
        try:
            self._configure(sdl2)
        except BaseException:
            self._release()
            raise
        return self

    def _configure(self, sdl2: ModuleType) -> None:
        index = self.index
        count = int(sdl2.SDL_NumJoysticks())
        if count < 0:
            raise DeviceError(f"SDL cannot count joysticks: {sdl_error(sdl2)}")
        if index >= count:
            raise DeviceError(
                f"no SDL joystick at index {index} ({count} found); `carfeel devices` lists them"
            )
        raw_name = sdl2.SDL_JoystickNameForIndex(index)
        name = raw_name.decode("utf-8", "replace") if raw_name else f"SDL joystick {index}"
        joystick = sdl2.SDL_JoystickOpen(index)
        if not joystick:
            raise DeviceError(f"cannot open SDL joystick {index} ({name}): {sdl_error(sdl2)}")
        self._joystick = joystick
        axes_found = int(sdl2.SDL_JoystickNumAxes(joystick))
        if max(self._axis_indices) >= axes_found:
            raise DeviceError(
                f"{name} has {axes_found} axes; cannot read axes {self._axis_indices}"
            )
        if self._buttons:
            buttons_found = int(sdl2.SDL_JoystickNumButtons(joystick))
            if max(self._buttons) >= buttons_found:
                raise DeviceError(
                    f"{name} has {buttons_found} buttons (0 .. {buttons_found - 1}); cannot read "
                    f"buttons {self._buttons}"
                )
        haptic = sdl2.SDL_HapticOpenFromJoystick(joystick)
        if not haptic:
            raise DeviceError(f"{name} has no force feedback in SDL: {sdl_error(sdl2)}")
        self._haptic = haptic
        features = int(sdl2.SDL_HapticQuery(haptic))
        if not features & sdl2.SDL_HAPTIC_CONSTANT:
            raise DeviceError(f"{name} has no constant-force effect (SDL_HAPTIC_CONSTANT)")
        haptic_axes = int(sdl2.SDL_HapticNumAxes(haptic))
        if haptic_axes < self.info.axes:
            raise DeviceError(f"{name} renders forces on {haptic_axes} axes, not {self.info.axes}")
        guid = ""
        if hasattr(sdl2, "SDL_JoystickGetGUID") and hasattr(sdl2, "SDL_JoystickGetGUIDString"):
            buffer = ctypes.create_string_buffer(33)
            sdl2.SDL_JoystickGetGUIDString(sdl2.SDL_JoystickGetGUID(joystick), buffer, 33)
            guid = buffer.value.decode("ascii", "replace")
        # Its identity for its profile: SDL's GUID (bus, vendor, product, version) and name.
        ident = f"sdl:{guid or index}:{name}"
        self.info = dataclasses.replace(self.info, name=name, ident=ident)
        # Full gain and no spring of the driver's own, where the device has these settings.
        if features & sdl2.SDL_HAPTIC_GAIN and (
            sdl2.SDL_HapticSetGain(haptic, GAIN_FULL_PERCENT) < 0
        ):
            raise DeviceError(f"{name}: SDL_HapticSetGain failed: {sdl_error(sdl2)}")
        if features & sdl2.SDL_HAPTIC_AUTOCENTER and sdl2.SDL_HapticSetAutocenter(haptic, 0) < 0:
            raise DeviceError(f"{name}: SDL_HapticSetAutocenter failed: {sdl_error(sdl2)}")
        for axis in range(self.info.axes):
            effect = sdl2.SDL_HapticEffect()
            effect.type = sdl2.SDL_HAPTIC_CONSTANT
            constant = effect.constant
            constant.direction.type = sdl2.SDL_HAPTIC_CARTESIAN
            constant.direction.dir[0] = 1 if axis == 0 else 0
            constant.direction.dir[1] = 0 if axis == 0 else 1
            constant.length = self._hold_ms
            constant.level = 0
            pointer = ctypes.pointer(effect)
            effect_id = int(sdl2.SDL_HapticNewEffect(haptic, pointer))
            if effect_id < 0:
                raise DeviceError(f"{name}: SDL_HapticNewEffect failed: {sdl_error(sdl2)}")
            self._effects.append(effect)
            self._pointers.append(pointer)
            self._ids.append(effect_id)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        failure = self._release()
        if failure is not None and exc_type is None:
            raise DeviceLost(
                f"{self.info.name} failed while stopping its force: {failure}; "
                f"the force stops by itself within {self.hold_s} s"
            )

    def _release(self) -> str | None:
        """Zero, stop and destroy the effects, close, quit SDL; return the first failure."""
        sdl2 = self._sdl
        if sdl2 is None:
            return None
        failures: list[str] = []
        haptic = self._haptic
        if haptic:
            for effect, pointer, effect_id in zip(
                self._effects, self._pointers, self._ids, strict=True
            ):
                effect.constant.level = 0
                if sdl2.SDL_HapticUpdateEffect(haptic, effect_id, pointer) < 0:
                    failures.append(f"SDL_HapticUpdateEffect: {sdl_error(sdl2)}")
            if sdl2.SDL_HapticStopAll(haptic) < 0:
                failures.append(f"SDL_HapticStopAll: {sdl_error(sdl2)}")
            for effect_id in self._ids:
                sdl2.SDL_HapticDestroyEffect(haptic, effect_id)
            sdl2.SDL_HapticClose(haptic)
        if self._joystick:
            sdl2.SDL_JoystickClose(self._joystick)
        sdl2.SDL_Quit()
        self._sdl = self._haptic = self._joystick = None
        self._effects, self._pointers, self._ids = [], [], []
        return failures[0] if failures else None

    def _closed(self) -> DeviceLost:
        return DeviceLost(f"{self.info.name} is closed: open it (with ...) before using it")

    def read(self, time_s: float) -> DeviceSample:
        if self._sdl is None:
            raise self._closed()
        sdl2: Any = self._sdl
        joystick = self._joystick
        sdl2.SDL_JoystickUpdate()
        if not sdl2.SDL_JoystickGetAttached(joystick):
            raise self._lost("reading its axes", sdl_error(sdl2))
        get_axis = sdl2.SDL_JoystickGetAxis
        scales: tuple[AxisScale, ...] = self._scales
        positions = tuple(
            scale.position(get_axis(joystick, i))
            for scale, i in zip(scales, self._axis_indices, strict=True)
        )
        if not self._buttons:
            return DeviceSample(time_s, positions, None)
        get_button = sdl2.SDL_JoystickGetButton
        buttons = tuple(get_button(joystick, i) == 1 for i in self._buttons)
        return DeviceSample(time_s, positions, None, buttons)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        if self._sdl is None:
            raise self._closed()
        top = self.info.max_force
        levels = [force_level(f, top, p) for f, p in zip(forces, self._polarity, strict=True)]
        due = self._schedule.due(levels, time_s)
        if not due:
            return
        sdl2: Any = self._sdl
        haptic = self._haptic
        for axis in due:
            level, effect_id = levels[axis], self._ids[axis]
            self._effects[axis].constant.level = level
            if sdl2.SDL_HapticUpdateEffect(haptic, effect_id, self._pointers[axis]) < 0:
                raise self._lost("updating its force", sdl_error(sdl2))
            if sdl2.SDL_HapticRunEffect(haptic, effect_id, 1) < 0:
                raise self._lost("playing its force", sdl_error(sdl2))
            self._schedule.sent(axis, level, time_s)

    def _lost(self, doing: str, error: str) -> DeviceLost:
        return DeviceLost(
            f"{self.info.name} (SDL joystick {self.index}) stopped answering while {doing}: "
            f"{error}; its force stops by itself within {self.hold_s} s"
        )
