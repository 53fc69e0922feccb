"""A real device's buttons pressing a lever's controls (`--lever-buttons`): read by the evdev and
SDL backends from strict fakes of their libraries, checked against the run before any device
opens, and applied by the lever's renderer tick by tick (simulated time, no device here)."""

from __future__ import annotations

import re
import sys
from collections.abc import Callable
from typing import Any

import pytest

from carfeel.contracts import DeviceSample
from carfeel.errors import InputError
from carfeel.io.presets import load_prnd, load_sequential
from carfeel.realtime.devices.base import DeviceError, DeviceLost
from carfeel.realtime.devices.evdev_device import EvdevDevice
from carfeel.realtime.devices.sdl2_device import SDL2Device
from carfeel.realtime.levers import LeverRenderer, PrndLever, SequentialLever
from carfeel.realtime.rendering import Gains, Scaling
from carfeel.realtime.run_options import (
    RealtimeRun,
    check_run,
    device_buttons,
    parse_lever_buttons,
)
from tests.fakes import fake_evdev as fe
from tests.fakes import fake_sdl2 as fs
from tests.fakes.fake_evdev import E, FakeEvdev
from tests.fakes.fake_sdl2 import FakeSDL2

STICK = "/dev/input/event5"


@pytest.fixture
def evdev(monkeypatch):
    fake = FakeEvdev([fe.joystick(STICK)])
    monkeypatch.setitem(sys.modules, "evdev", fake)
    return fake


@pytest.fixture
def sdl(monkeypatch):
    fake = FakeSDL2([fs.sdl_joystick()])
    monkeypatch.setitem(sys.modules, "sdl2", fake)
    return fake


def opened(device: Any, body: Callable[[Any], object] = lambda d: None) -> None:
    """Open `device`, run `body` on it, close it (so a pytest.raises holds one statement)."""
    with device:
        body(device)


def stick(**kwargs) -> EvdevDevice:
    return EvdevDevice(STICK, kind="joystick", max_force=10.0, travel=0.04, **kwargs)


def test_evdev_reads_the_asked_buttons_by_name_or_code_in_order(evdev):
    spec = evdev.devices[STICK]
    with stick(buttons=("BTN_THUMB", E.BTN_TRIGGER)) as device:
        assert device.read(0.0).buttons == (False, False)
        spec.pressed.add(E.BTN_THUMB)
        assert device.read(0.001).buttons == (True, False)
        spec.pressed.add(E.BTN_TRIGGER)
        spec.pressed.discard(E.BTN_THUMB)
        assert device.read(0.002).buttons == (False, True)
    # No button asked: the kernel is not asked either (one ioctl less a tick).
    with stick() as device:
        assert device.read(0.0).buttons is None
    assert len(evdev.args_of("active_keys")) == 3


@pytest.mark.parametrize(
    ("button", "words"),
    [
        ("BTN_BOGUS", "no button named 'BTN_BOGUS'"),
        ("KEY_A", "has no button KEY_A (code 30); it has codes 288, 289, 290"),
        (E.KEY_A, "has no button 30"),
    ],
)
def test_evdev_refuses_a_button_the_device_lacks_and_closes_it(evdev, button, words):
    with pytest.raises(DeviceError, match=re.escape(words)):
        opened(stick(buttons=(button,)))
    assert evdev.opened[-1].closed


def test_evdev_losing_the_device_while_reading_its_buttons_is_device_lost(evdev):
    def unplugged_then_read(device: EvdevDevice) -> None:
        evdev.fail("active_keys")
        device.read(0.0)

    with pytest.raises(DeviceLost, match="reading its buttons"):
        opened(stick(buttons=("BTN_THUMB",)), unplugged_then_read)


def test_sdl_reads_the_asked_buttons_by_index(sdl):
    joystick = sdl.joysticks[0]
    with SDL2Device(0, kind="joystick", max_force=10.0, travel=0.04, buttons=[3, 1]) as device:
        assert device.read(0.0).buttons == (False, False)
        joystick.buttons[1] = 1
        assert device.read(0.001).buttons == (False, True)
    with pytest.raises(
        DeviceError, match=re.escape("has 4 buttons (0 .. 3); cannot read buttons (4,)")
    ):
        opened(SDL2Device(0, kind="joystick", max_force=10.0, travel=0.04, buttons=[4]))
    with pytest.raises(InputError, match="SDL numbers a joystick's buttons"):
        SDL2Device(0, kind="joystick", max_force=10.0, travel=0.04, buttons=[-1])


@pytest.mark.parametrize(
    ("run", "words"),
    [
        (RealtimeRun(model="hpattern", device="evdev:/dev/input/event5",
                     lever_buttons=(("lift", "BTN_TRIGGER"),)), "--model hpattern has none"),
        (RealtimeRun(model="sequential", device="evdev:/dev/input/event5",
                     lever_buttons=(("brake", "BTN_TRIGGER"),)), "controls are lift"),
        (RealtimeRun(model="prnd", device="sdl:0",
                     lever_buttons=(("button", "0"), ("button", "1"))), "names a control twice"),
        (RealtimeRun(model="prnd", device="virtual:joystick",
                     lever_buttons=(("button", "0"),)), "virtual hand presses the controls"),
        (RealtimeRun(model="prnd", device="sdl:0",
                     lever_buttons=(("brake", "BTN_TRIGGER"),)), "SDL numbers"),
        (RealtimeRun(model="sequential", device="evdev:/dev/input/event5",
                     lever_buttons=(("lift", "BTN;rm"),)), "an EV_KEY name"),
    ],
)  # fmt: skip
def test_lever_buttons_that_do_not_fit_the_run_are_refused_before_any_device_opens(run, words):
    with pytest.raises(InputError, match=words):
        check_run(run)


def test_lever_buttons_are_parsed_as_pairs_and_handed_to_the_device_in_order():
    pairs = parse_lever_buttons("button=0, brake=BTN_THUMB")
    assert pairs == (("button", "0"), ("brake", "BTN_THUMB"))
    assert device_buttons(RealtimeRun(model="prnd", lever_buttons=pairs)) == (0, "BTN_THUMB")
    for bad in ("lift", "lift=", "=BTN_TRIGGER", "lift=BTN_TRIGGER,,"):
        with pytest.raises(InputError, match="CONTROL=BUTTON"):
            parse_lever_buttons(bad)


def test_the_cli_refuses_lever_buttons_on_a_virtual_device_with_exit_2(capsys):
    from carfeel.cli import main

    code = main(["run", "--model", "sequential", "--lever-buttons", "lift=BTN_TRIGGER",
                 "--clock", "simulated", "--duration", "1"])  # fmt: skip
    assert code == 2
    err = capsys.readouterr().err
    assert "virtual hand presses the controls itself" in err and "Traceback" not in err


def drive(renderer: LeverRenderer, path, buttons) -> list[str]:
    """Tick `renderer` at 1 kHz with the handle at path(t) (m, device = model units here) and
    the device's buttons as given; the gears it registers."""
    gears = []
    steps = 1500
    for i in range(steps):
        t = i * 1e-3
        sample = DeviceSample(t, (path(t), 0.0), None, buttons(t))
        renderer.tick(sample, 1e-3)
        gears.append(renderer.gear)
    return gears


def renderer_for(lever, controls_from: tuple[str, ...]) -> LeverRenderer:
    # A stiff coupling in model units (10 kN/m, 60 N*s/m on a lever under 1 kg: 100 N at 10 mm
    # of stretch, over the click's and the centring's sum): the handle, moved by the test,
    # drags the lever as a hand would through a device.
    gains = Gains(0.0, 0.0, 10000.0, 60.0, 0.0, 0.0)
    renderer = LeverRenderer(lever, Scaling(1.0, 1.0), 1000.0, gains)
    renderer.buttons = controls_from
    return renderer


def ramp(target_m: float):
    """Out to `target_m` over 0.3 s, held 0.4 s, back to 0 over 0.3 s."""

    def at(t: float) -> float:
        if t < 0.3:
            return target_m * t / 0.3
        if t < 0.7:
            return target_m
        return target_m * max(0.0, 1.0 - (t - 0.7) / 0.3)

    return at


def test_the_sequential_lift_comes_from_the_device_button():
    params = load_sequential().params.lever
    down = -params.up_direction * (params.end_m - 0.002)  # past the click, short of the end
    # N -> R is the lift-down: held, the lever goes to R; not held, the lock holds it in N.
    for held, expected in ((False, {"N"}), (True, {"N", "R"})):
        renderer = renderer_for(SequentialLever(params), ("lift",))
        gears = drive(renderer, ramp(down), lambda t, held=held: (held,))
        assert set(gears) - {""} == expected, (held, sorted(set(gears)))
        assert renderer.controls.lift is held
    # A sample without buttons (a replay, a virtual device) leaves the controls as they are.
    renderer = renderer_for(SequentialLever(params), ("lift",))
    renderer.controls.lift = True
    drive(renderer, ramp(0.0), lambda t: None)
    assert renderer.controls.lift is True


def test_the_selectors_brake_and_lock_button_come_from_the_device():
    params = load_prnd().params.selector
    to_r = params.centre_m(params.positions.index("R"))
    for brake, expected in ((False, {"P"}), (True, {"P", "R"})):
        renderer = renderer_for(PrndLever(params), ("button", "brake"))
        gears = drive(renderer, ramp(to_r), lambda t, brake=brake: (True, brake))
        assert set(gears) - {""} == expected, (brake, sorted(set(gears)))
        assert renderer.controls.button is True and renderer.controls.brake is brake
