"""A recorded fake of the part of python-evdev that carfeel uses (checked against evdev 2.0.0).

Same names, signatures and constant values as the real package (the constants are those of
linux/input-event-codes.h and linux/input.h, from which evdev.ecodes is generated; `ff` holds
copies of evdev/ff.py's ctypes structures). Install it for one test with

    fake = FakeEvdev([wheel()])
    monkeypatch.setitem(sys.modules, "evdev", fake)

Every call is appended to `fake.calls` as (name, args), in order; an uploaded effect is recorded
as an `Uploaded` snapshot (the ctypes object itself changes later). `fake.fail(name, nth)` makes
the nth call named `name` from now raise OSError(ENODEV) and leaves the device unplugged: every
later call but `close` fails too, as the kernel answers for a removed device.
"""

from __future__ import annotations

import ctypes
import errno
import types
from dataclasses import dataclass, field
from typing import Any, NamedTuple

# linux/input-event-codes.h and linux/input.h
ECODES = {
    "EV_SYN": 0x00,
    "EV_KEY": 0x01,
    "EV_ABS": 0x03,
    "EV_FF": 0x15,
    "SYN_REPORT": 0,
    "KEY_A": 30,
    "BTN_TRIGGER": 0x120,
    "BTN_THUMB": 0x121,
    "BTN_THUMB2": 0x122,
    "ABS_X": 0x00,
    "ABS_Y": 0x01,
    "ABS_Z": 0x02,
    "ABS_RX": 0x03,
    "ABS_RZ": 0x05,
    "ABS_THROTTLE": 0x06,
    "ABS_WHEEL": 0x08,
    "ABS_HAT0X": 0x10,
    "FF_RUMBLE": 0x50,
    "FF_PERIODIC": 0x51,
    "FF_CONSTANT": 0x52,
    "FF_SPRING": 0x53,
    "FF_FRICTION": 0x54,
    "FF_DAMPER": 0x55,
    "FF_INERTIA": 0x56,
    "FF_RAMP": 0x57,
    "FF_SQUARE": 0x58,
    "FF_SINE": 0x5A,
    "FF_GAIN": 0x60,
    "FF_AUTOCENTER": 0x61,
}

ecodes = types.ModuleType("evdev.ecodes")
ecodes.__dict__.update(ECODES)
E = types.SimpleNamespace(**ECODES)
"""The same constants, typed loosely, for the tests."""


# evdev/ff.py (2.0.0), verbatim in layout.
class Replay(ctypes.Structure):
    _fields_ = [("length", ctypes.c_uint16), ("delay", ctypes.c_uint16)]


class Trigger(ctypes.Structure):
    _fields_ = [("button", ctypes.c_uint16), ("interval", ctypes.c_uint16)]


class Envelope(ctypes.Structure):
    _fields_ = [
        ("attack_length", ctypes.c_uint16),
        ("attack_level", ctypes.c_uint16),
        ("fade_length", ctypes.c_uint16),
        ("fade_level", ctypes.c_uint16),
    ]


class Constant(ctypes.Structure):
    _fields_ = [("level", ctypes.c_int16), ("ff_envelope", Envelope)]


class Ramp(ctypes.Structure):
    _fields_ = [
        ("start_level", ctypes.c_int16),
        ("end_level", ctypes.c_int16),
        ("ff_envelope", Envelope),
    ]


class Rumble(ctypes.Structure):
    _fields_ = [("strong_magnitude", ctypes.c_uint16), ("weak_magnitude", ctypes.c_uint16)]


class EffectType(ctypes.Union):
    _fields_ = [
        ("ff_constant_effect", Constant),
        ("ff_ramp_effect", Ramp),
        ("ff_rumble_effect", Rumble),
    ]


class Effect(ctypes.Structure):
    _fields_ = [
        ("type", ctypes.c_uint16),
        ("id", ctypes.c_int16),
        ("direction", ctypes.c_uint16),
        ("ff_trigger", Trigger),
        ("ff_replay", Replay),
        ("u", EffectType),
    ]


ff = types.ModuleType("evdev.ff")
ff.__dict__.update(
    Replay=Replay,
    Trigger=Trigger,
    Envelope=Envelope,
    Constant=Constant,
    Ramp=Ramp,
    Rumble=Rumble,
    EffectType=EffectType,
    Effect=Effect,
)


class AbsInfo(NamedTuple):
    """evdev.AbsInfo: the input_absinfo struct."""

    value: int
    min: int
    max: int
    fuzz: int
    flat: int
    resolution: int


class DeviceIds(NamedTuple):
    """evdev.DeviceInfo (`InputDevice.info`): the device's bus and USB ids."""

    bustype: int
    vendor: int
    product: int
    version: int


class EvdevError(Exception):
    """evdev.EvdevError: raised by `write` on a device opened read-only."""


class Uploaded(NamedTuple):
    """What `upload_effect` was given (a snapshot: carfeel reuses its ctypes Effect)."""

    type: int
    id: int
    direction: int
    level: int
    length_ms: int
    delay_ms: int


@dataclass
class DeviceSpec:
    """One fake event device: its axes (code -> AbsInfo) and force-feedback codes."""

    path: str
    name: str
    axes: dict[int, AbsInfo]
    ff: tuple[int, ...] = ()
    ff_effects_count: int = 16
    writable: bool = True
    keys: tuple[int, ...] = ()
    pressed: set[int] = field(default_factory=set)
    """The keys held down now; a test presses one by adding its code."""
    values: dict[int, int] = field(default_factory=dict)
    """Current axis values; a test moves an axis by setting one."""
    ids: tuple[int, int, int, int] = (0x03, 0x0000, 0x0000, 0x0111)
    """evdev.DeviceInfo: bus type, vendor, product, version."""
    uniq: str = ""
    phys: str = "usb-0000:00:14.0-1/input0"

    def __post_init__(self) -> None:
        for code, info in self.axes.items():
            self.values.setdefault(code, info.value)


def wheel(path: str = "/dev/input/event7", name: str = "Logitech G29 Driving Force Racing Wheel"):
    """A G29 as hid-lg4ff presents it: 16-bit wheel on ABS_X, pedals, constant force only
    (USB 046d:c24f, as the kernel's hid-ids.h has it)."""
    pedal = AbsInfo(255, 0, 255, 0, 0, 0)
    return DeviceSpec(
        path,
        name,
        {E.ABS_X: AbsInfo(32768, 0, 65535, 0, 0, 0), E.ABS_Y: pedal, E.ABS_Z: pedal},
        ff=(E.FF_CONSTANT, E.FF_GAIN, E.FF_AUTOCENTER),
        ff_effects_count=16,
        keys=(E.BTN_TRIGGER,),
        ids=(0x03, 0x046D, 0xC24F, 0x0111),
    )


def joystick(path: str = "/dev/input/event5", name: str = "Fake Force Feedback Joystick"):
    """A 2-axis joystick with 10-bit axes (0..1023, not centred on 0) and a full effect set."""
    axis = AbsInfo(512, 0, 1023, 0, 0, 0)
    return DeviceSpec(
        path,
        name,
        {E.ABS_X: axis, E.ABS_Y: axis, E.ABS_RZ: AbsInfo(32, 0, 63, 0, 0, 0)},
        ff=(E.FF_CONSTANT, E.FF_PERIODIC, E.FF_SPRING, E.FF_SINE, E.FF_GAIN, E.FF_AUTOCENTER),
        ff_effects_count=8,
        keys=(E.BTN_TRIGGER, E.BTN_THUMB, E.BTN_THUMB2),
    )


def keyboard(path: str = "/dev/input/event0", name: str = "AT Translated Set 2 keyboard"):
    return DeviceSpec(path, name, {}, keys=(E.KEY_A,))


class FakeInputDevice:
    """evdev.InputDevice over a DeviceSpec, with a kernel-like effect memory."""

    def __init__(self, module: FakeEvdev, spec: DeviceSpec) -> None:
        self._module = module
        self.spec = spec
        self.path = spec.path
        self.name = spec.name
        self.info = DeviceIds(*spec.ids)
        self.uniq = spec.uniq
        self.phys = spec.phys
        self.fd = 3
        self.ff_effects_count = spec.ff_effects_count if spec.ff else 0
        self.effects: dict[int, Uploaded] = {}
        """Effects in the device's memory, by id."""
        self.played: list[tuple[int, int]] = []
        """(effect id, count) of every play request."""
        self.gain: int | None = None
        self.autocenter: int | None = None
        self.closed = False
        self.ignored: list[tuple[int, int]] = []
        """Play requests for effect ids not in the device's memory: the kernel's ff-core drops
        them without an error (check_effect_access fails), so a backend never learns; the
        tests check this stays empty."""

    def _call(self, name: str, *args: Any) -> None:
        self._module._record(name, args, can_fail=True)
        if self.closed:  # python-evdev on a closed descriptor: the kernel answers EBADF
            raise OSError(errno.EBADF, "Bad file descriptor")

    def capabilities(self, verbose: bool = False, absinfo: bool = True) -> dict[int, list[Any]]:
        self._call("capabilities", verbose, absinfo)
        caps: dict[int, list[Any]] = {E.EV_SYN: [E.EV_SYN, E.EV_KEY]}
        if self.spec.keys:
            caps[E.EV_KEY] = list(self.spec.keys)
        if self.spec.axes:
            caps[E.EV_SYN].append(E.EV_ABS)
            caps[E.EV_ABS] = [
                (code, info._replace(value=self.spec.values[code])) if absinfo else code
                for code, info in sorted(self.spec.axes.items())
            ]
        if self.spec.ff:
            caps[E.EV_SYN].append(E.EV_FF)
            caps[E.EV_FF] = sorted(self.spec.ff)
        return caps

    def absinfo(self, axis_num: int) -> AbsInfo:
        self._call("absinfo", axis_num)
        if axis_num not in self.spec.axes:
            raise OSError(errno.EINVAL, "Invalid argument")
        return self.spec.axes[axis_num]._replace(value=self.spec.values[axis_num])

    def active_keys(self, verbose: bool = False) -> list[int]:
        """The keys held down (EVIOCGKEY): only ones the device has."""
        self._call("active_keys", verbose)
        return sorted(code for code in self.spec.pressed if code in self.spec.keys)

    def write(self, etype: int, code: int, value: int) -> None:
        self._call("write", etype, code, value)
        if not self.spec.writable:
            raise EvdevError(f'no write access to device "{self.path}"')
        if etype == E.EV_FF and code == E.FF_GAIN:
            self.gain = value
        elif etype == E.EV_FF and code == E.FF_AUTOCENTER:
            self.autocenter = value
        elif etype == E.EV_FF:
            if code in self.effects:
                self.played.append((code, value))
            else:
                self.ignored.append((code, value))

    def upload_effect(self, effect: Effect, writeback_id: bool = True) -> int:
        snapshot = Uploaded(
            effect.type,
            effect.id,
            effect.direction,
            effect.u.ff_constant_effect.level,
            effect.ff_replay.length,
            effect.ff_replay.delay,
        )
        self._call("upload_effect", snapshot)
        if not self.spec.writable:
            raise PermissionError(errno.EPERM, "Operation not permitted")
        if effect.type not in self.spec.ff:
            raise OSError(errno.EINVAL, "Invalid argument")
        if effect.id == -1:
            free = [i for i in range(self.ff_effects_count) if i not in self.effects]
            if not free:
                raise OSError(errno.ENOSPC, "No space left on device")
            effect_id = free[0]
        elif effect.id in self.effects:
            effect_id = effect.id
        else:
            raise OSError(errno.EINVAL, "Invalid argument")
        self.effects[effect_id] = snapshot._replace(id=effect_id)
        if writeback_id and self._module.write_back_id:
            effect.id = effect_id
        return effect_id

    def erase_effect(self, ff_id: int) -> None:
        self._call("erase_effect", ff_id)
        if ff_id not in self.effects:
            raise OSError(errno.EINVAL, "Invalid argument")
        del self.effects[ff_id]

    def close(self) -> None:
        self._module._record("close", (), can_fail=False)
        # python-evdev's close is idempotent (it checks fd > -1); the effects the process
        # uploaded are erased by the kernel when its descriptor closes.
        if not self.closed:
            self.effects.clear()
        self.closed = True
        self.fd = -1


class FakeEvdev(types.ModuleType):
    """Stands for the `evdev` package in sys.modules; records every call in `calls`."""

    EvdevError = EvdevError
    AbsInfo = AbsInfo

    def __init__(self, devices: list[DeviceSpec] | None = None, *, write_back_id: bool = True):
        super().__init__("evdev")
        self.ecodes = ecodes
        self.ff = ff
        self.devices = {spec.path: spec for spec in devices or []}
        self.write_back_id = write_back_id
        """False mimics python-evdev before 2.0: upload_effect leaves effect.id alone."""
        self.calls: list[tuple[str, tuple[Any, ...]]] = []
        self.opened: list[FakeInputDevice] = []
        self._fail: list[Any] | None = None
        self.unplugged = False

    def fail(self, name: str, nth: int = 1) -> None:
        """Unplug the device at the nth call named `name` from now (OSError ENODEV)."""
        self._fail = [name, nth]

    def _record(self, name: str, args: tuple[Any, ...], *, can_fail: bool) -> None:
        self.calls.append((name, args))
        if not can_fail:
            return
        if self._fail is not None and self._fail[0] == name:
            self._fail[1] -= 1
            if self._fail[1] == 0:
                self._fail, self.unplugged = None, True
        if self.unplugged:
            raise OSError(errno.ENODEV, "No such device")

    def names(self) -> list[str]:
        """The names of the calls so far, in order."""
        return [name for name, _ in self.calls]

    def args_of(self, name: str) -> list[tuple[Any, ...]]:
        return [args for n, args in self.calls if n == name]

    def InputDevice(self, dev: str, readonly: bool = False) -> FakeInputDevice:
        self._record("InputDevice", (dev,), can_fail=True)
        spec = self.devices.get(str(dev))
        if spec is None:
            raise FileNotFoundError(errno.ENOENT, "No such file or directory", str(dev))
        device = FakeInputDevice(self, spec)
        self.opened.append(device)
        return device

    def list_devices(self, input_device_dir: str = "/dev/input", writable: bool = True):
        self._record("list_devices", (input_device_dir, writable), can_fail=False)
        return [path for path, spec in self.devices.items() if spec.writable or not writable]
