"""A Linux force-feedback joystick or wheel through evdev (python-evdev, imported when opened).

Positions come from the absolute axes (EV_ABS), scaled from the axis's [min, max] to
[-travel, +travel] (m or rad). Forces are one FF_CONSTANT effect per axis, each with a fixed
direction and a signed level:

    axis 0 (X, a wheel's only axis): direction 0x4000    level = +0x7FFF * force / max_force
    axis 1 (Y):                       direction 0x8000    (clamped to -0x7FFF..0x7FFF)

The kernel's ff-memless renders a constant effect as level*sin(angle) on X and
-level*cos(angle) on Y (angle = direction * 360 deg / 0x10000), so 0x4000 puts +level on X
alone and 0x8000 +level on Y alone. Whether +X pushes toward +ABS_X is the driver's choice:
pass `invert_force=True` for a device that pushes the other way, and `signs` to flip an axis
(position and force together).

Each effect lasts `hold_s` (its replay length): a stalled loop's force dies by itself. A level
is re-uploaded (same effect id, then played) when it changed by more than `level_quantum`, no
faster than `update_hz`, and in any case every `hold_s / 2` while it is not zero.

`LevelSchedule`, `force_level` and the validation here are shared with the SDL2 backend.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
from collections.abc import Sequence
from types import ModuleType, TracebackType
from typing import Any, NamedTuple

from carfeel.errors import InputError
from carfeel.realtime.devices.base import DeviceError, DeviceInfo, DeviceLost, DeviceSample

PIP_HINT = "pip install 'carfeel[devices]'"
MAX_LEVEL = 0x7FFF
"""Full-scale effect level (evdev's and SDL2's constant effects are signed 16 bit)."""
X_DIRECTION = 0x4000
Y_DIRECTION = 0x8000
GAIN_FULL = 0xFFFF
CLOCK_SLACK_S = 1e-6
"""Rounding of the loop's clock: an update 1 us early still counts as on time."""
KINDS = ("joystick", "wheel")


class AxisScale(NamedTuple):
    """Raw reading -> position: (raw - centre) * per_count."""

    centre: float
    per_count: float
    """m (or rad) per count, signed by the axis's sign."""

    def position(self, raw: int) -> float:
        return (raw - self.centre) * self.per_count


def axis_scale(minimum: int, maximum: int, travel: float, sign: float) -> AxisScale:
    """Map [minimum, maximum] to [-travel, +travel] (flipped when `sign` is -1)."""
    half = 0.5 * (maximum - minimum)
    return AxisScale(0.5 * (maximum + minimum), sign * travel / half)


def force_level(force: float, max_force: float, polarity: int) -> int:
    """Signed effect level for `force` (N or Nm); beyond +-max_force it saturates, NaN is 0."""
    ratio = force / max_force
    if ratio != ratio:  # NaN: render nothing rather than fail inside the loop
        return 0
    ratio = min(1.0, max(-1.0, ratio))
    return polarity * round(ratio * MAX_LEVEL)


class LevelSchedule:
    """Which axes to send now, given the levels wanted at `time_s` (s, the loop's clock).

    An axis is sent when its level moved by more than `quantum` (or to zero) and at least
    1/update_hz has passed since the last send; or, whatever the rate, when its non-zero
    level was last sent `hold_s / 2` ago (its effect must not run out while commanded).
    """

    __slots__ = ("levels", "period_s", "quantum", "refresh_s", "sent_at_s", "updated_at_s")

    def __init__(self, axes: int, update_hz: float, hold_s: float, quantum: int) -> None:
        self.period_s = 1.0 / update_hz
        self.refresh_s = 0.5 * hold_s
        self.quantum = quantum
        self.levels = [0] * axes
        """Last level sent per axis (0 at open: the effects are uploaded silent)."""
        self.sent_at_s = [-math.inf] * axes
        self.updated_at_s = -math.inf

    def due(self, levels: Sequence[int], time_s: float) -> list[int]:
        rate_ok = time_s - self.updated_at_s + CLOCK_SLACK_S >= self.period_s
        due = []
        for axis, level in enumerate(levels):
            sent = self.levels[axis]
            expiring = sent != 0 and time_s - self.sent_at_s[axis] + CLOCK_SLACK_S >= self.refresh_s
            changed = abs(level - sent) > self.quantum or (level == 0 and sent != 0)
            if expiring or (rate_ok and changed):
                due.append(axis)
        return due

    def sent(self, axis: int, level: int, time_s: float) -> None:
        self.levels[axis] = level
        self.sent_at_s[axis] = time_s
        self.updated_at_s = time_s


def validate(
    kind: str, axes: int, max_force: float, travel: float, hold_s: float, update_hz: float
) -> int:
    """Check the common settings once; return the effect length in ms."""
    if kind not in KINDS:
        raise InputError(f"device kind {kind!r} is not one of {', '.join(KINDS)}")
    if kind == "wheel" and axes != 1:
        raise InputError(f"a wheel has one axis, not {axes}")
    if not 1 <= axes <= 2:
        raise InputError(f"a joystick has 1 or 2 axes, not {axes}")
    if not (math.isfinite(max_force) and max_force > 0.0):
        raise InputError(f"max_force = {max_force} (N or Nm) must be finite and > 0")
    if not (math.isfinite(travel) and travel > 0.0):
        raise InputError(f"travel = {travel} (m or rad) must be finite and > 0")
    if not (math.isfinite(update_hz) and update_hz > 0.0):
        raise InputError(f"update_hz = {update_hz} Hz must be finite and > 0")
    hold_ms = round(hold_s * 1000.0) if math.isfinite(hold_s) else 0
    if not 1 <= hold_ms <= 0x7FFF:
        raise InputError(f"hold_s = {hold_s} s must be within 0.001..32.767 s")
    return hold_ms


def signs_of(signs: Sequence[int] | None, axes: int) -> tuple[int, ...]:
    if signs is None:
        return (1,) * axes
    if len(signs) != axes or any(s not in (1, -1) for s in signs):
        raise InputError(f"signs = {tuple(signs)} must be {axes} values of +1 or -1")
    return tuple(signs)


def import_evdev() -> ModuleType:
    """python-evdev, or a DeviceError that says how to install it."""
    try:
        return importlib.import_module("evdev")
    except ImportError as exc:
        raise DeviceError(
            f"the evdev backend needs python-evdev (Linux only): {PIP_HINT} ({exc})"
        ) from exc


class EvdevDevice:
    """A force-feedback device at an evdev path (/dev/input/eventN), as a `Device`.

    `max_force` is the force (N, joystick) or torque (Nm, wheel) at full level; `travel` the
    half-range of each axis (m or rad) that the axis's [min, max] spans. `axis_codes` are the
    EV_ABS codes read: by default ABS_X, ABS_Y for a joystick and ABS_X (else ABS_WHEEL) for a
    wheel. `signs` flips an axis (+1 or -1 per axis), `invert_force` the force of all axes.
    `buttons` are the EV_KEY codes (or names, BTN_TRIGGER) whose state `read` reports.
    """

    def __init__(
        self,
        path: str,
        *,
        kind: str = "wheel",
        max_force: float,
        travel: float,
        axis_codes: Sequence[int] | None = None,
        hold_s: float = 0.1,
        update_hz: float = 500.0,
        level_quantum: int = 8,
        signs: Sequence[int] | None = None,
        invert_force: bool = False,
        buttons: Sequence[int | str] = (),
    ) -> None:
        axes = len(axis_codes) if axis_codes is not None else (2 if kind == "joystick" else 1)
        self._hold_ms = validate(kind, axes, max_force, travel, hold_s, update_hz)
        if level_quantum < 0:
            raise InputError(f"level_quantum = {level_quantum} must be >= 0 (levels)")
        self.path = path
        self.info = DeviceInfo(path, kind, axes, max_force, travel, update_hz, measures_force=False)
        self.hold_s = hold_s
        self.level_quantum = level_quantum
        self._signs = signs_of(signs, axes)
        self._polarity = tuple(-s if invert_force else s for s in self._signs)
        self._requested_codes = tuple(axis_codes) if axis_codes is not None else None
        self._requested_buttons = tuple(buttons)
        self._button_codes: tuple[int, ...] = ()
        self._device: Any = None
        self._codes: tuple[int, ...] = ()
        self._scales: tuple[AxisScale, ...] = ()
        self._effects: list[Any] = []
        self._ids: list[int] = []
        """Effect ids as the kernel gave them (older python-evdev does not write them back)."""
        self._ev_ff = 0x15
        self._errors: tuple[type[BaseException], ...] = (OSError,)
        self._schedule = LevelSchedule(axes, update_hz, hold_s, level_quantum)

    def __enter__(self) -> EvdevDevice:
        evdev = import_evdev()
        try:
            device = evdev.InputDevice(self.path)
        except FileNotFoundError as exc:
            raise DeviceError(
                f"no input device at {self.path}; `carfeel devices` lists them"
            ) from exc
        except PermissionError as exc:
            raise DeviceError(
                f"no permission to open {self.path}: add yourself to the 'input' group or "
                "install a udev rule for the device"
            ) from exc
        except OSError as exc:
            raise DeviceError(f"cannot open {self.path}: {exc}") from exc
        self._device = device
        self._ev_ff = int(evdev.ecodes.EV_FF)
        self._errors = (OSError, evdev.EvdevError)
        self._schedule = LevelSchedule(
            self.info.axes, self.info.update_hz, self.hold_s, self.level_quantum
        )
        try:
            self._configure(evdev, device)
        except self._errors as exc:
            self._release()
            raise DeviceError(f"cannot set up force feedback on {self.path}: {exc}") from exc
        except BaseException:
            self._release()
            raise
        return self

    def _configure(self, evdev: ModuleType, device: Any) -> None:
        ecodes = evdev.ecodes
        name = str(device.name)
        capabilities = device.capabilities(absinfo=False)
        if ecodes.FF_CONSTANT not in capabilities.get(ecodes.EV_FF, []):
            raise DeviceError(f"{self.path} ({name}) has no constant-force effect (FF_CONSTANT)")
        present = set(capabilities.get(ecodes.EV_ABS, []))
        codes = self._requested_codes
        if codes is None:
            if self.info.kind == "joystick":
                codes = (ecodes.ABS_X, ecodes.ABS_Y)
            elif ecodes.ABS_X in present or ecodes.ABS_WHEEL not in present:
                codes = (ecodes.ABS_X,)
            else:
                codes = (ecodes.ABS_WHEEL,)
        missing = [code for code in codes if code not in present]
        if missing:
            raise DeviceError(f"{self.path} ({name}) has no absolute axis with code {missing}")
        if int(device.ff_effects_count) < len(codes):
            raise DeviceError(
                f"{self.path} ({name}) keeps {device.ff_effects_count} effects, needs {len(codes)}"
            )
        scales = []
        for code, sign in zip(codes, self._signs, strict=True):
            info = device.absinfo(code)
            if info.max <= info.min:
                raise DeviceError(f"{self.path} axis {code}: range [{info.min}, {info.max}]")
            scales.append(axis_scale(info.min, info.max, self.info.travel, sign))
        self._codes, self._scales = tuple(codes), tuple(scales)
        self._button_codes = self._buttons_of(ecodes, name, capabilities.get(ecodes.EV_KEY, []))
        # Its identity for its profile: the USB ids and serial (or the port it is on), which
        # outlive the event node's number.
        ids = getattr(device, "info", None)
        where = str(getattr(device, "uniq", "") or getattr(device, "phys", "") or self.path)
        ident = f"evdev:{getattr(ids, 'vendor', 0):04x}:{getattr(ids, 'product', 0):04x}:{where}"
        self.info = dataclasses.replace(self.info, name=name, ident=ident)
        # Full gain and no spring of the driver's own: the model renders every force.
        device.write(ecodes.EV_FF, ecodes.FF_GAIN, GAIN_FULL)
        device.write(ecodes.EV_FF, ecodes.FF_AUTOCENTER, 0)
        ff = evdev.ff
        for axis in range(len(codes)):
            effect = ff.Effect(
                ecodes.FF_CONSTANT,
                -1,  # a new effect: the kernel assigns the id
                X_DIRECTION if axis == 0 else Y_DIRECTION,
                ff.Trigger(0, 0),
                ff.Replay(self._hold_ms, 0),
                ff.EffectType(ff_constant_effect=ff.Constant(0, ff.Envelope(0, 0, 0, 0))),
            )
            effect_id = int(device.upload_effect(effect))
            effect.id = effect_id
            self._effects.append(effect)
            self._ids.append(effect_id)

    def _buttons_of(self, ecodes: Any, name: str, keys: Sequence[int]) -> tuple[int, ...]:
        """The asked buttons' EV_KEY codes, each one the device has."""
        codes = []
        for button in self._requested_buttons:
            code = button if isinstance(button, int) else getattr(ecodes, str(button), None)
            if not isinstance(code, int):
                raise DeviceError(
                    f"no button named {button!r}: give an EV_KEY name as evdev spells it "
                    "(BTN_TRIGGER, BTN_THUMB, BTN_TOP, ...) or its number"
                )
            if code not in keys:
                raise DeviceError(
                    f"{self.path} ({name}) has no button {button} (code {code}); it has codes "
                    f"{', '.join(str(k) for k in sorted(keys)[:24]) or 'none'}"
                )
            codes.append(code)
        return tuple(codes)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        failure = self._release()
        if failure is not None and exc_type is None:
            raise DeviceLost(
                f"{self.path} ({self.info.name}) failed while stopping its force: {failure}; "
                f"the force stops by itself within {self.hold_s} s"
            ) from failure

    def _release(self) -> BaseException | None:
        """Zero and erase the effects, close; return the first failure (best effort)."""
        device = self._device
        if device is None:
            return None
        failure: BaseException | None = None
        for effect, effect_id in zip(self._effects, self._ids, strict=True):
            try:
                effect.id = effect_id
                effect.u.ff_constant_effect.level = 0
                device.upload_effect(effect)
                device.erase_effect(effect_id)
            except self._errors as exc:
                failure = failure or exc
        try:
            device.close()
        except OSError as exc:
            failure = failure or exc
        self._device = None
        self._effects, self._ids = [], []
        return failure

    def _closed(self) -> DeviceLost:
        return DeviceLost(f"{self.info.name} is closed: open it (with ...) before using it")

    def read(self, time_s: float) -> DeviceSample:
        if self._device is None:
            raise self._closed()
        device = self._device
        try:
            raws = [device.absinfo(code).value for code in self._codes]
        except self._errors as exc:
            raise self._lost("reading its axes", exc) from exc
        positions = tuple(s.position(raw) for s, raw in zip(self._scales, raws, strict=True))
        if not self._button_codes:
            return DeviceSample(time_s, positions, None)
        try:
            pressed = device.active_keys()  # one EVIOCGKEY: the kernel's state, no event queue
        except self._errors as exc:
            raise self._lost("reading its buttons", exc) from exc
        buttons = tuple(code in pressed for code in self._button_codes)
        return DeviceSample(time_s, positions, None, buttons)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        if self._device is None:
            raise self._closed()
        top = self.info.max_force
        levels = [force_level(f, top, p) for f, p in zip(forces, self._polarity, strict=True)]
        due = self._schedule.due(levels, time_s)
        if not due:
            return
        device = self._device
        try:
            for axis in due:
                level, effect, effect_id = levels[axis], self._effects[axis], self._ids[axis]
                effect.id = effect_id  # the same id: the kernel updates the effect in place
                effect.u.ff_constant_effect.level = level
                device.upload_effect(effect)
                device.write(self._ev_ff, effect_id, 1)  # (re)start it for another hold_s
                self._schedule.sent(axis, level, time_s)
        except self._errors as exc:
            raise self._lost("updating its force", exc) from exc

    def _lost(self, doing: str, exc: BaseException) -> DeviceLost:
        return DeviceLost(
            f"{self.path} ({self.info.name}) stopped answering while {doing}: {exc}; "
            f"its force stops by itself within {self.hold_s} s"
        )
