"""The evdev and SDL2 backends and the device listing, against recorded fakes of their libraries.

The fakes stand in sys.modules for `evdev` and `sdl2`, so the backends' real code runs; the
tests read the calls the fakes recorded. Time is simulated: every call passes time_s.
"""

from __future__ import annotations

import ast
import json
import math
import sys
from collections.abc import Callable
from itertools import pairwise
from pathlib import Path
from typing import Any

import pytest

from carfeel.errors import InputError
from carfeel.realtime.devices import evdev_device, listing, sdl2_device
from carfeel.realtime.devices.base import Device, DeviceError, DeviceLost
from carfeel.realtime.devices.evdev_device import MAX_LEVEL, EvdevDevice, LevelSchedule
from carfeel.realtime.devices.sdl2_device import SDL2Device
from tests.fakes import fake_evdev as fe
from tests.fakes import fake_sdl2 as fs
from tests.fakes.fake_evdev import E, FakeEvdev, Uploaded
from tests.fakes.fake_sdl2 import EffectSnapshot, FakeSDL2, Handle

WHEEL = "/dev/input/event7"
STICK = "/dev/input/event5"
WHEEL_TRAVEL_RAD = math.radians(450.0)
HALF = round(0.5 * MAX_LEVEL)  # 16384: half of full scale, as the backends round it


def ms(k: int) -> float:
    """k milliseconds of the loop's clock, exactly as a 1 kHz loop computes them."""
    return k / 1000.0


@pytest.fixture
def evdev(monkeypatch):
    fake = FakeEvdev([fe.wheel(WHEEL), fe.joystick(STICK), fe.keyboard()])
    monkeypatch.setitem(sys.modules, "evdev", fake)
    return fake


@pytest.fixture
def sdl(monkeypatch):
    fake = FakeSDL2([fs.sdl_wheel(), fs.sdl_joystick(), fs.sdl_gamepad()])
    monkeypatch.setitem(sys.modules, "sdl2", fake)
    return fake


def evdev_wheel(**kwargs) -> EvdevDevice:
    return EvdevDevice(WHEEL, kind="wheel", max_force=4.0, travel=WHEEL_TRAVEL_RAD, **kwargs)


def evdev_stick(**kwargs) -> EvdevDevice:
    return EvdevDevice(STICK, kind="joystick", max_force=10.0, travel=0.04, **kwargs)


def sdl_wheel(**kwargs) -> SDL2Device:
    return SDL2Device(0, kind="wheel", max_force=4.0, travel=WHEEL_TRAVEL_RAD, **kwargs)


def sdl_stick(**kwargs) -> SDL2Device:
    return SDL2Device(1, kind="joystick", max_force=10.0, travel=0.04, **kwargs)


def run_in(device: Device, body: Callable[[Any], object]) -> None:
    """Open `device`, run `body` on it, close it (so pytest.raises holds one statement)."""
    with device:
        body(device)


def uploads(fake: FakeEvdev) -> list[Uploaded]:
    return [args[0] for args in fake.args_of("upload_effect")]


def updates(fake: FakeSDL2) -> list[tuple[int, EffectSnapshot]]:
    return [(args[1], args[2]) for args in fake.args_of("SDL_HapticUpdateEffect")]


def ff_calls(fake: FakeEvdev) -> list[tuple[str, tuple[Any, ...]]]:
    """The force-feedback calls only (axis reads left out)."""
    keep = {"write", "upload_effect", "erase_effect", "close"}
    return [(name, args) for name, args in fake.calls if name in keep]


# ---------------------------------------------------------------------------------------------
# The level schedule shared by both backends


def test_schedule_sends_changes_at_most_at_update_hz_and_refreshes_before_the_hold():
    schedule = LevelSchedule(axes=1, update_hz=500.0, hold_s=0.1, quantum=8)
    assert schedule.due([0], ms(0)) == []  # silent at open: nothing to send
    assert schedule.due([1000], ms(0)) == [0]
    schedule.sent(0, 1000, ms(0))
    assert schedule.due([2000], ms(1)) == []  # 1 ms < 1/500 Hz
    assert schedule.due([2000], ms(2)) == [0]
    schedule.sent(0, 2000, ms(2))
    assert schedule.due([2005], ms(10)) == []  # within the quantum
    assert schedule.due([2000], ms(51)) == []
    assert schedule.due([2000], ms(52)) == [0]  # hold_s / 2 after the last send
    schedule.sent(0, 2000, ms(52))
    assert schedule.due([3], ms(60)) == [0]  # back to (almost) zero is a change
    schedule.sent(0, 3, ms(60))
    assert schedule.due([0], ms(70)) == [0]  # and exactly zero is always sent
    schedule.sent(0, 0, ms(70))
    assert schedule.due([0], ms(1000)) == []  # a zero level needs no refresh


def test_backends_follow_the_device_protocol(evdev, sdl):
    devices: list[Device] = [evdev_wheel(), sdl_wheel()]
    for device in devices:
        assert device.info.kind == "wheel" and device.info.axes == 1
        assert device.info.update_hz == 500.0 and not device.info.measures_force


def test_device_libraries_are_imported_lazily():
    for module in (evdev_device, sdl2_device, listing):
        tree = ast.parse(Path(str(module.__file__)).read_text())
        top: set[str] = set()
        for node in tree.body:
            if isinstance(node, ast.Import):
                top.update(alias.name.split(".")[0] for alias in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module:
                top.add(node.module.split(".")[0])
        assert not top & {"evdev", "sdl2"}, f"{module.__name__} imports {top & {'evdev', 'sdl2'}}"


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "pedal"}, "kind"),
        ({"max_force": 0.0}, "max_force"),
        ({"travel": -1.0}, "travel"),
        ({"hold_s": 0.0}, "hold_s"),
        ({"hold_s": 40.0}, "hold_s"),
        ({"update_hz": math.nan}, "update_hz"),
        ({"signs": (1, 1)}, "signs"),
        ({"level_quantum": -1}, "level_quantum"),
    ],
)
def test_settings_are_checked_when_the_device_is_built(kwargs, match):
    settings = {"kind": "wheel", "max_force": 4.0, "travel": 1.0} | kwargs
    with pytest.raises(InputError, match=match):
        EvdevDevice(WHEEL, **settings)
    with pytest.raises(InputError, match=match):
        SDL2Device(0, **settings)


# ---------------------------------------------------------------------------------------------
# evdev


def test_evdev_open_sets_full_gain_and_no_autocentre_then_uploads_silent_effects(evdev):
    with evdev_wheel() as device:
        assert device.info.name == "Logitech G29 Driving Force Racing Wheel"
        assert ff_calls(evdev) == [
            ("write", (E.EV_FF, E.FF_GAIN, 0xFFFF)),
            ("write", (E.EV_FF, E.FF_AUTOCENTER, 0)),
            ("upload_effect", (Uploaded(E.FF_CONSTANT, -1, 0x4000, 0, 100, 0),)),
        ]
        assert evdev.names()[0] == "InputDevice"
        wheel = evdev.opened[0]
        assert wheel.gain == 0xFFFF and wheel.autocenter == 0 and list(wheel.effects) == [0]


def test_evdev_changes_the_level_by_reuploading_the_same_id_then_playing_it(evdev):
    with evdev_wheel() as device:
        start = len(evdev.calls)
        device.command((2.0,), ms(0))
        assert evdev.calls[start:] == [
            ("upload_effect", (Uploaded(E.FF_CONSTANT, 0, 0x4000, HALF, 100, 0),)),
            ("write", (E.EV_FF, 0, 1)),
        ]
        device.command((-1.0,), ms(2))
        assert uploads(evdev)[-1] == Uploaded(
            E.FF_CONSTANT, 0, 0x4000, -round(0.25 * MAX_LEVEL), 100, 0
        )
        assert evdev.opened[0].played == [(0, 1), (0, 1)]
        assert len(evdev.opened[0].effects) == 1  # updated in place, never a second effect


@pytest.mark.parametrize("write_back_id", [True, False])
def test_evdev_tracks_effect_ids_itself(monkeypatch, write_back_id):
    """python-evdev before 2.0 did not write the kernel's id back into the Effect."""
    fake = FakeEvdev([fe.joystick(STICK)], write_back_id=write_back_id)
    monkeypatch.setitem(sys.modules, "evdev", fake)
    with evdev_stick() as device:
        assert [u.id for u in uploads(fake)] == [-1, -1]  # two new effects: X then Y
        assert [u.direction for u in uploads(fake)] == [0x4000, 0x8000]
        device.command((5.0, -5.0), ms(0))
        device.command((10.0, 10.0), ms(2))
    sent = uploads(fake)[2:]
    assert [(u.id, u.direction) for u in sent[:4]] == [(0, 0x4000), (1, 0x8000)] * 2
    assert [u.level for u in sent[:4]] == [HALF, -HALF, MAX_LEVEL, MAX_LEVEL]
    assert fake.opened[0].effects == {}  # both erased at exit


def test_evdev_sends_nothing_while_the_level_is_unchanged(evdev):
    with evdev_wheel(level_quantum=8) as device:
        device.command((1.0,), ms(0))
        count = len(uploads(evdev))
        for k in range(1, 40):
            device.command((1.0,), ms(k))
        assert len(uploads(evdev)) == count
        for k in range(40, 48):
            device.command((1.0 + 1e-3 * (-1) ** k,), ms(k))  # +-8 levels: within the quantum
        assert len(uploads(evdev)) == count
        device.command((1.0 + 1.2e-3,), ms(48))  # 10 levels: beyond it
        assert len(uploads(evdev)) == count + 1


def test_evdev_updates_no_faster_than_update_hz(evdev):
    sent_at = []
    with evdev_wheel(update_hz=500.0) as device:
        for k in range(100):
            before = len(uploads(evdev))
            device.command((4.0 * math.sin(0.3 * k),), ms(k))  # a new level every 1 ms
            if len(uploads(evdev)) > before:
                sent_at.append(k)
    gaps = [b - a for a, b in pairwise(sent_at)]
    assert len(sent_at) == 50 and min(gaps) == 2  # every other 1 ms tick: 500 Hz


def test_evdev_reuploads_an_unchanged_level_before_its_effect_runs_out(evdev):
    plays = []
    with evdev_wheel(hold_s=0.1) as device:
        for k in range(301):
            before = len(evdev.opened[0].played)
            device.command((1.5,), ms(k))
            if len(evdev.opened[0].played) > before:
                plays.append(k)
    gaps_ms = [b - a for a, b in pairwise(plays)]
    assert plays[0] == 0 and len(plays) == 7  # every 50 ms, not every tick
    assert max(gaps_ms) < 100  # never as late as the 100 ms replay length
    assert all(u.length_ms == 100 for u in uploads(evdev))


def test_evdev_exit_zeroes_erases_and_closes(evdev):
    with evdev_wheel() as device:
        device.command((3.0,), ms(0))
        start = len(evdev.calls)
    assert evdev.calls[start:] == [
        ("upload_effect", (Uploaded(E.FF_CONSTANT, 0, 0x4000, 0, 100, 0),)),
        ("erase_effect", (0,)),
        ("close", ()),
    ]
    assert evdev.opened[0].closed and evdev.opened[0].effects == {}


def test_evdev_exit_zeroes_erases_and_closes_on_an_exception_in_the_block(evdev):
    def body(device):
        device.command((3.0, -3.0), ms(0))
        raise ZeroDivisionError

    with pytest.raises(ZeroDivisionError):
        run_in(evdev_stick(), body)
    tail = ff_calls(evdev)[-5:]
    assert [(name, args[0].level if name == "upload_effect" else args) for name, args in tail] == [
        ("upload_effect", 0),
        ("erase_effect", (0,)),
        ("upload_effect", 0),
        ("erase_effect", (1,)),
        ("close", ()),
    ]
    assert evdev.opened[0].closed


def test_evdev_positions_are_scaled_from_absinfo(evdev):
    stick = evdev.devices[STICK]
    with evdev_stick() as device:
        stick.values.update({E.ABS_X: 1023, E.ABS_Y: 0})
        sample = device.read(ms(5))
        assert sample.time_s == ms(5) and sample.forces is None
        assert sample.positions == pytest.approx((0.04, -0.04), rel=1e-12)
        stick.values.update({E.ABS_X: 512, E.ABS_Y: 256})
        # Centre 511.5 of 0..1023; 1023 counts span 2 * 0.04 m.
        expected = ((512 - 511.5) * 0.08 / 1023, (256 - 511.5) * 0.08 / 1023)
        assert device.read(ms(6)).positions == pytest.approx(expected, rel=1e-12)
    wheel = evdev.devices[WHEEL]
    with evdev_wheel(signs=(-1,)) as device:
        wheel.values[E.ABS_X] = 65535
        assert device.read(ms(0)).positions == pytest.approx((-WHEEL_TRAVEL_RAD,), rel=1e-12)


def test_evdev_wheel_falls_back_to_abs_wheel(monkeypatch):
    spec = fe.DeviceSpec(
        WHEEL,
        "ABS_WHEEL wheel",
        {E.ABS_WHEEL: fe.AbsInfo(0, -540, 540, 0, 0, 0)},
        ff=(E.FF_CONSTANT,),
    )
    fake = FakeEvdev([spec])
    monkeypatch.setitem(sys.modules, "evdev", fake)
    with evdev_wheel() as device:
        spec.values[E.ABS_WHEEL] = 270
        assert device.read(ms(0)).positions == pytest.approx((0.5 * WHEEL_TRAVEL_RAD,))
    assert set(fake.args_of("absinfo")) == {(E.ABS_WHEEL,)}


def test_evdev_force_levels_saturate_keep_sign_and_follow_invert_force(evdev):
    with evdev_wheel(invert_force=True) as device:
        device.command((10.0,), ms(0))  # beyond max_force: full level, inverted
        device.command((-1.0,), ms(2))
        device.command((math.nan,), ms(4))  # a NaN renders nothing
    assert [u.level for u in uploads(evdev)[1:4]] == [-MAX_LEVEL, round(0.25 * MAX_LEVEL), 0]


def test_evdev_read_error_is_device_lost_and_exit_still_closes(evdev):
    def body(device):
        device.read(ms(0))
        evdev.fail("absinfo")
        device.read(ms(1))

    with pytest.raises(DeviceLost, match=WHEEL):
        run_in(evdev_wheel(), body)
    assert evdev.opened[0].closed


def test_evdev_command_error_is_device_lost(evdev):
    evdev.fail("upload_effect", 2)  # the first after the one at open
    with pytest.raises(DeviceLost, match="updating its force"):
        run_in(evdev_wheel(), lambda device: device.command((1.0,), ms(0)))
    assert evdev.opened[0].closed


def test_evdev_play_error_is_device_lost(evdev):
    evdev.fail("write", 3)  # gain, autocentre, then the first play
    with pytest.raises(DeviceLost, match="No such device"):
        run_in(evdev_wheel(), lambda device: device.command((1.0,), ms(0)))


def test_evdev_failure_while_stopping_is_reported_after_closing(evdev):
    evdev.fail("erase_effect")
    with pytest.raises(DeviceLost, match="stopping its force"):
        run_in(evdev_wheel(), lambda device: device.command((1.0,), ms(0)))
    assert evdev.opened[0].closed


def test_evdev_missing_library_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "evdev", None)
    with pytest.raises(DeviceError, match=r"pip install 'carfeel\[devices\]'"):
        evdev_wheel().__enter__()


def test_evdev_missing_path_names_it(evdev):
    with pytest.raises(DeviceError, match="/dev/input/event42"):
        EvdevDevice("/dev/input/event42", max_force=4.0, travel=1.0).__enter__()


def test_evdev_device_without_constant_force_is_refused_and_closed(evdev):
    with pytest.raises(DeviceError, match="FF_CONSTANT"):
        EvdevDevice("/dev/input/event0", max_force=4.0, travel=1.0).__enter__()
    assert evdev.opened[0].closed


def test_evdev_read_only_device_is_refused_and_closed(evdev):
    evdev.devices[WHEEL].writable = False
    with pytest.raises(DeviceError, match="no write access"):
        evdev_wheel().__enter__()
    assert evdev.opened[0].closed


def test_evdev_failing_upload_at_open_closes_the_device(evdev):
    evdev.fail("upload_effect", 2)  # the joystick's Y effect
    with pytest.raises(DeviceError, match=STICK):
        evdev_stick().__enter__()
    assert evdev.opened[0].closed


# ---------------------------------------------------------------------------------------------
# SDL2


def test_sdl2_open_sequence(sdl):
    with sdl_wheel() as device:
        assert device.info.name == "Logitech G29 Driving Force Racing Wheel"
        joystick, haptic = Handle("joystick", 0), Handle("haptic", 0)
        calls = [c for c in sdl.calls if c[0] != "SDL_GetError"]
        assert calls == [
            ("SDL_Init", (fs.SDL_INIT_JOYSTICK | fs.SDL_INIT_HAPTIC,)),
            ("SDL_NumJoysticks", ()),
            ("SDL_JoystickNameForIndex", (0,)),
            ("SDL_JoystickOpen", (0,)),
            ("SDL_JoystickNumAxes", (joystick,)),
            ("SDL_HapticOpenFromJoystick", (joystick,)),
            ("SDL_HapticQuery", (haptic,)),
            ("SDL_HapticNumAxes", (haptic,)),
            ("SDL_HapticSetGain", (haptic, 100)),
            ("SDL_HapticSetAutocenter", (haptic, 0)),
            (
                "SDL_HapticNewEffect",
                (
                    haptic,
                    EffectSnapshot(
                        fs.SDL_HAPTIC_CONSTANT, fs.SDL_HAPTIC_CARTESIAN, (1, 0, 0), 100, 0
                    ),
                ),
            ),
        ]


def test_sdl2_changes_the_level_by_updating_the_same_effect_then_running_it(sdl):
    haptic = Handle("haptic", 0)
    with sdl_wheel() as device:
        start = len(sdl.calls)
        device.command((2.0,), ms(0))
        expected = EffectSnapshot(
            fs.SDL_HAPTIC_CONSTANT, fs.SDL_HAPTIC_CARTESIAN, (1, 0, 0), 100, HALF
        )
        assert sdl.calls[start:] == [
            ("SDL_HapticUpdateEffect", (haptic, 0, expected)),
            ("SDL_HapticRunEffect", (haptic, 0, 1)),
        ]
        device.command((2.0,), ms(10))  # unchanged: nothing sent
        assert len(sdl.calls) == start + 2
        device.command((-4.0,), ms(11))
        assert updates(sdl)[-1][1].level == -MAX_LEVEL


def test_sdl2_joystick_has_one_effect_per_axis_direction(sdl):
    with sdl_stick() as device:
        device.command((5.0, -10.0), ms(0))
    new = [args[1] for args in sdl.args_of("SDL_HapticNewEffect")]
    assert [e.dir for e in new] == [(1, 0, 0), (0, 1, 0)]
    assert [(i, e.dir, e.level) for i, e in updates(sdl)[:2]] == [
        (0, (1, 0, 0), HALF),
        (1, (0, 1, 0), -MAX_LEVEL),
    ]


def test_sdl2_rate_limit_and_refresh(sdl):
    sent_at = []
    with sdl_wheel(update_hz=500.0, hold_s=0.1) as device:
        for k in range(100):
            before = len(sdl.args_of("SDL_HapticRunEffect"))
            device.command((4.0 * math.sin(0.3 * k),), ms(k))
            if len(sdl.args_of("SDL_HapticRunEffect")) > before:
                sent_at.append(k)
        assert min(b - a for a, b in pairwise(sent_at)) == 2
        runs = len(sdl.args_of("SDL_HapticRunEffect"))
        for k in range(100, 400):
            device.command((1.0,), ms(k))
        refreshes = len(sdl.args_of("SDL_HapticRunEffect")) - runs
        assert 6 <= refreshes <= 7  # one change, then every 50 ms for 300 ms


def test_sdl2_positions_are_scaled_from_the_axes(sdl):
    with sdl_stick() as device:
        sdl.joysticks[1].axes[:2] = [32767, -32768]
        assert device.read(ms(0)).positions == pytest.approx((0.04, -0.04), rel=1e-12)
        sdl.joysticks[1].axes[:2] = [0, 16384]
        expected = (0.5 / 32767.5 * 0.04, 16384.5 / 32767.5 * 0.04)
        assert device.read(ms(1)).positions == pytest.approx(expected, rel=1e-12)
    assert "SDL_JoystickUpdate" in sdl.names()


def test_sdl2_exit_zeroes_stops_destroys_closes_and_quits(sdl):
    haptic, joystick = Handle("haptic", 0), Handle("joystick", 0)
    with sdl_wheel() as device:
        device.command((3.0,), ms(0))
        start = len(sdl.calls)
    zero = EffectSnapshot(fs.SDL_HAPTIC_CONSTANT, fs.SDL_HAPTIC_CARTESIAN, (1, 0, 0), 100, 0)
    assert sdl.calls[start:] == [
        ("SDL_HapticUpdateEffect", (haptic, 0, zero)),
        ("SDL_HapticStopAll", (haptic,)),
        ("SDL_HapticDestroyEffect", (haptic, 0)),
        ("SDL_HapticClose", (haptic,)),
        ("SDL_JoystickClose", (joystick,)),
        ("SDL_Quit", ()),
    ]
    assert sdl.initialised == 0 and not sdl.open_haptics and not sdl.open_joysticks


def test_sdl2_exit_cleans_up_on_an_exception_in_the_block(sdl):
    def body(device):
        device.command((3.0, 3.0), ms(0))
        raise KeyError("boom")

    with pytest.raises(KeyError):
        run_in(sdl_stick(), body)
    assert sdl.names()[-8:] == [
        "SDL_HapticUpdateEffect",
        "SDL_HapticUpdateEffect",
        "SDL_HapticStopAll",
        "SDL_HapticDestroyEffect",
        "SDL_HapticDestroyEffect",
        "SDL_HapticClose",
        "SDL_JoystickClose",
        "SDL_Quit",
    ]
    assert all(e.level == 0 for _, e in updates(sdl)[-2:])
    assert sdl.joysticks[1].effects == {} and sdl.initialised == 0


def test_sdl2_errors_are_device_lost_with_the_sdl_message(sdl):
    sdl.fail("SDL_HapticUpdateEffect")
    with pytest.raises(DeviceLost, match="fake device unplugged"):
        run_in(sdl_wheel(), lambda device: device.command((1.0,), ms(0)))
    assert sdl.initialised == 0 and not sdl.open_joysticks


def test_sdl2_run_error_is_device_lost(sdl):
    sdl.fail("SDL_HapticRunEffect")
    with pytest.raises(DeviceLost, match="playing its force"):
        run_in(sdl_wheel(), lambda device: device.command((1.0,), ms(0)))


def test_sdl2_detached_joystick_is_device_lost(sdl):
    def body(device):
        device.read(ms(0))
        sdl.joysticks[0].attached = False
        device.read(ms(1))

    with pytest.raises(DeviceLost, match="reading its axes"):
        run_in(sdl_wheel(), body)
    assert sdl.initialised == 0


def test_sdl2_missing_library_says_how_to_install_it(monkeypatch):
    monkeypatch.setitem(sys.modules, "sdl2", None)
    with pytest.raises(DeviceError, match=r"pip install 'carfeel\[devices\]'"):
        sdl_wheel().__enter__()


def test_sdl2_missing_index_is_refused_and_sdl_quit(sdl):
    with pytest.raises(DeviceError, match=r"index 7 \(3 found\)"):
        SDL2Device(7, max_force=4.0, travel=1.0).__enter__()
    assert sdl.initialised == 0 and sdl.names()[-1] == "SDL_Quit"


def test_sdl2_joystick_without_constant_force_is_refused_and_closed(sdl):
    with pytest.raises(DeviceError, match="SDL_HAPTIC_CONSTANT"):
        SDL2Device(2, max_force=4.0, travel=1.0).__enter__()
    assert sdl.initialised == 0 and not sdl.open_joysticks and not sdl.open_haptics


def test_sdl2_non_haptic_joystick_is_refused(monkeypatch):
    fake = FakeSDL2([fs.JoystickSpec("plain stick", [0, 0], features=0)])
    monkeypatch.setitem(sys.modules, "sdl2", fake)
    with pytest.raises(DeviceError, match="isn't a haptic device"):
        SDL2Device(0, kind="joystick", max_force=1.0, travel=0.04).__enter__()
    assert fake.initialised == 0 and not fake.open_joysticks


def test_sdl2_skips_gain_and_autocentre_the_device_lacks(monkeypatch):
    fake = FakeSDL2([fs.JoystickSpec("bare wheel", [0], features=fs.SDL_HAPTIC_CONSTANT)])
    monkeypatch.setitem(sys.modules, "sdl2", fake)
    with sdl_wheel() as device:
        device.command((1.0,), ms(0))
    assert "SDL_HapticSetGain" not in fake.names()
    assert "SDL_HapticSetAutocenter" not in fake.names()


def test_sdl2_init_failure_is_a_device_error(sdl):
    sdl.fail("SDL_Init")
    with pytest.raises(DeviceError, match="SDL_Init"):
        sdl_wheel().__enter__()


# ---------------------------------------------------------------------------------------------
# Listing


def test_listing_without_libraries_says_so_and_does_not_raise(monkeypatch):
    monkeypatch.setitem(sys.modules, "evdev", None)
    monkeypatch.setitem(sys.modules, "sdl2", None)
    lines = listing.list_devices()
    text = "\n".join(lines)
    assert "python-evdev is not installed" in text and "pysdl2" in text
    assert text.count("pip install 'carfeel[devices]'") == 2
    backends = listing.describe_backends()
    assert not backends["evdev"]["available"] and not backends["sdl2"]["available"]
    json.dumps(backends)


def test_listing_without_dev_input_says_so(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "evdev", FakeEvdev([fe.wheel()]))
    monkeypatch.setitem(sys.modules, "sdl2", FakeSDL2([]))
    lines = listing.list_devices(str(tmp_path / "input"))
    assert f"  {tmp_path / 'input'} does not exist: no input devices on this machine" in lines
    assert "  no joysticks" in lines


def test_listing_with_no_devices_says_so(monkeypatch, tmp_path):
    monkeypatch.setitem(sys.modules, "evdev", FakeEvdev([]))
    monkeypatch.setitem(sys.modules, "sdl2", FakeSDL2([]))
    assert listing.list_devices(str(tmp_path)) == [
        "evdev (Linux input devices):",
        f"  no event devices in {tmp_path}",
        "SDL2 (joysticks and haptics):",
        "  no joysticks",
    ]


def test_listing_with_unreadable_event_files_points_at_permissions(monkeypatch, tmp_path):
    (tmp_path / "event3").write_text("")
    monkeypatch.setitem(sys.modules, "evdev", FakeEvdev([]))
    monkeypatch.setitem(sys.modules, "sdl2", FakeSDL2([]))
    text = "\n".join(listing.list_devices(str(tmp_path)))
    assert "1 event devices" in text and "'input' group" in text


def test_listing_shows_which_devices_have_constant_force(monkeypatch, tmp_path):
    read_only = fe.joystick(STICK)
    read_only.writable = False
    fake_evdev = FakeEvdev([fe.wheel(WHEEL), read_only, fe.keyboard()])
    fake_sdl = FakeSDL2([fs.sdl_wheel(), fs.sdl_gamepad(), fs.JoystickSpec("pad", [0], features=0)])
    monkeypatch.setitem(sys.modules, "evdev", fake_evdev)
    monkeypatch.setitem(sys.modules, "sdl2", fake_sdl)
    lines = listing.list_devices(str(tmp_path))
    text = "\n".join(lines)
    assert f"  {WHEEL}  Logitech G29 Driving Force Racing Wheel" in lines
    assert "axes: ABS_X, ABS_Y; constant force, 16 effects: usable" in text
    assert "read-only: force feedback needs write access" in text
    assert "no force feedback" in text  # the keyboard
    assert "  index 1  Xbox 360 Controller" in lines
    assert "haptic without a constant-force effect (not usable)" in text
    assert "not haptic" in text and "haptic with constant force: usable" in text
    assert all(d.closed for d in fake_evdev.opened)
    assert fake_sdl.initialised == 0 and not fake_sdl.open_joysticks and not fake_sdl.open_haptics
    backends = listing.describe_backends(str(tmp_path))
    json.dumps(backends)
    wheel = next(d for d in backends["evdev"]["devices"] if d["path"] == WHEEL)
    assert wheel["constant_force"] and wheel["writable"] and wheel["effects"] == 16
    assert [d["constant_force"] for d in backends["sdl2"]["devices"]] == [True, False, False]


def test_listing_reports_a_device_that_fails_to_answer(monkeypatch, tmp_path):
    fake = FakeEvdev([fe.wheel(WHEEL)])
    fake.fail("capabilities")
    monkeypatch.setitem(sys.modules, "evdev", fake)
    monkeypatch.setitem(sys.modules, "sdl2", FakeSDL2([]))
    text = "\n".join(listing.list_devices(str(tmp_path)))
    assert "cannot open: [Errno 19] No such device" in text
    assert "no usable force-feedback device" in text


# ---------------------------------------------------------------- the fakes are as strict as
# the libraries: a backend that calls out of order fails here as it would on a real device.


def test_the_evdev_fake_refuses_a_closed_device_and_drops_unknown_effects(evdev):
    device = evdev.InputDevice(WHEEL)
    device.write(E.EV_FF, 5, 1)  # effect 5 was never uploaded: the kernel drops the request
    assert device.ignored == [(5, 1)] and device.played == []
    device.close()
    device.close()  # idempotent, as python-evdev's
    for call in (lambda: device.write(E.EV_FF, 0, 1), lambda: device.absinfo(E.ABS_X),
                 lambda: device.capabilities()):  # fmt: skip
        with pytest.raises(OSError, match="Bad file descriptor"):
            call()


def test_the_sdl_fake_needs_sdl_init_and_open_handles():
    fake = FakeSDL2([fs.sdl_wheel()])
    assert fake.SDL_NumJoysticks() == -1
    assert b"not initialized" in fake.SDL_GetError()
    fake.SDL_Init(fs.SDL_INIT_JOYSTICK | fs.SDL_INIT_HAPTIC)
    stick = fake.SDL_JoystickOpen(0)
    haptic = fake.SDL_HapticOpenFromJoystick(stick)
    assert fake.SDL_HapticRunEffect(haptic, 7, 1) == -1  # never created
    fake.SDL_HapticClose(haptic)
    assert fake.SDL_HapticStopAll(haptic) == -1
    assert b"Invalid haptic device" in fake.SDL_GetError()


def test_the_backends_play_only_what_they_uploaded_and_nothing_after_closing(evdev, sdl):
    """A whole run's worth of commands through each backend: every play request names an
    effect in the device's memory, and a command after the device is closed is an error
    (DeviceLost), not a silent success."""
    wheel = evdev_wheel()
    with wheel:
        handle = wheel._device  # the fake's InputDevice
        for k in range(200):
            wheel.command((2.0 * math.sin(k / 20.0),), ms(k))
    assert handle.ignored == [] and handle.played and handle.closed
    with pytest.raises(DeviceLost):
        wheel.command((1.0,), ms(300))
    stick = sdl_stick()
    with stick:
        for k in range(200):
            stick.command((3.0 * math.sin(k / 20.0), -1.0), ms(k))
    assert all(spec.running for spec in sdl.joysticks[1:2])
    with pytest.raises(DeviceLost):
        stick.command((1.0, 0.0), ms(300))
