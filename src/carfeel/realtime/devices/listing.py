"""What `carfeel devices` shows: the force-feedback devices evdev and SDL2 can see.

Nothing here raises for a missing library, a missing /dev/input or a device that cannot be
opened: each becomes a plain message, so the listing itself is the diagnosis.
"""

from __future__ import annotations

import glob
import importlib
import os
import sys
from types import ModuleType
from typing import Any

from carfeel.realtime.devices.evdev_device import PIP_HINT
from carfeel.realtime.devices.sdl2_device import sdl_error

INPUT_DIR = "/dev/input"


def describe_backends(input_dir: str = INPUT_DIR) -> dict[str, Any]:
    """Both backends as plain data (for --json): availability, a message, the devices."""
    return {"evdev": describe_evdev(input_dir), "sdl2": describe_sdl2()}


def list_devices(input_dir: str = INPUT_DIR) -> list[str]:
    """Lines for `carfeel devices`: the evdev view, then the SDL2 view."""
    backends = describe_backends(input_dir)
    lines = ["evdev (Linux input devices):"]
    evdev = backends["evdev"]
    lines += [f"  {evdev['message']}"] if evdev["message"] else []
    for d in evdev["devices"]:
        lines.append(f"  {d['path']}  {d['name']}")
        lines.append(f"      {_evdev_summary(d)}")
    sdl2 = backends["sdl2"]
    lines.append("SDL2 (joysticks and haptics):")
    lines += [f"  {sdl2['message']}"] if sdl2["message"] else []
    for d in sdl2["devices"]:
        lines.append(f"  index {d['index']}  {d['name']}")
        lines.append(f"      {_sdl2_summary(d)}")
    return lines


def _evdev_summary(d: dict[str, Any]) -> str:
    if d.get("error"):
        return f"cannot open: {d['error']}"
    axes = ", ".join(d["axes"]) or "none of ABS_X, ABS_Y, ABS_WHEEL"
    if not d["force_feedback"]:
        ff = "no force feedback"
    elif not d["constant_force"]:
        ff = "force feedback without a constant-force effect (not usable)"
    else:
        ff = f"constant force, {d['effects']} effects: usable"
    if d["force_feedback"] and not d["writable"]:
        ff += " (read-only: force feedback needs write access)"
    return f"axes: {axes}; {ff}"


def _sdl2_summary(d: dict[str, Any]) -> str:
    if d.get("error"):
        return f"cannot open: {d['error']}"
    if not d["haptic"]:
        ff = "not haptic"
    elif not d["constant_force"]:
        ff = "haptic without a constant-force effect (not usable)"
    else:
        ff = "haptic with constant force: usable"
    return f"{d['axes']} axes; {ff}"


def _import(name: str) -> tuple[ModuleType | None, str | None]:
    try:
        return importlib.import_module(name), None
    except ImportError as exc:
        return None, str(exc)


def describe_evdev(input_dir: str = INPUT_DIR) -> dict[str, Any]:
    """The evdev view: every readable event device, its axes and its force feedback."""
    result: dict[str, Any] = {"available": False, "message": None, "devices": []}
    evdev, problem = _import("evdev")
    if evdev is None:
        where = "" if sys.platform.startswith("linux") else " (Linux only)"
        result["message"] = f"python-evdev is not installed{where}: {PIP_HINT} ({problem})"
        return result
    result["available"] = True
    if not os.path.isdir(input_dir):
        result["message"] = f"{input_dir} does not exist: no input devices on this machine"
        return result
    readable = sorted(evdev.list_devices(input_dir, writable=False))
    writable = set(evdev.list_devices(input_dir, writable=True))
    if not readable:
        present = glob.glob(os.path.join(input_dir, "event*"))
        result["message"] = (
            f"{len(present)} event devices in {input_dir} but none readable: add yourself to "
            "the 'input' group or install a udev rule"
            if present
            else f"no event devices in {input_dir}"
        )
        return result
    ecodes = evdev.ecodes
    named_axes = (("ABS_X", ecodes.ABS_X), ("ABS_Y", ecodes.ABS_Y), ("ABS_WHEEL", ecodes.ABS_WHEEL))
    for path in readable:
        entry: dict[str, Any] = {"path": path, "name": "?", "writable": path in writable}
        try:
            device = evdev.InputDevice(path)
        except OSError as exc:
            entry["error"] = str(exc)
            result["devices"].append(entry)
            continue
        try:
            capabilities = device.capabilities(absinfo=False)
            ff_codes = capabilities.get(ecodes.EV_FF, [])
            abs_codes = capabilities.get(ecodes.EV_ABS, [])
            entry.update(
                name=str(device.name),
                axes=[name for name, code in named_axes if code in abs_codes],
                force_feedback=bool(ff_codes),
                constant_force=ecodes.FF_CONSTANT in ff_codes,
                effects=int(device.ff_effects_count),
            )
        except OSError as exc:
            entry["error"] = str(exc)
        finally:
            device.close()
        result["devices"].append(entry)
    usable = sum(1 for d in result["devices"] if d.get("constant_force") and d["writable"])
    if not usable:
        result["message"] = "no usable force-feedback device (FF_CONSTANT, writable)"
    return result


def describe_sdl2() -> dict[str, Any]:
    """The SDL2 view: every joystick, whether it is haptic and has a constant-force effect."""
    result: dict[str, Any] = {"available": False, "message": None, "devices": []}
    sdl2, problem = _import("sdl2")
    if sdl2 is None:
        result["message"] = f"pysdl2 (with pysdl2-dll) is not installed: {PIP_HINT} ({problem})"
        return result
    result["available"] = True
    if sdl2.SDL_Init(sdl2.SDL_INIT_JOYSTICK | sdl2.SDL_INIT_HAPTIC) < 0:
        result["message"] = f"SDL_Init (joystick, haptic) failed: {sdl_error(sdl2)}"
        return result
    try:
        count = int(sdl2.SDL_NumJoysticks())
        if count < 0:
            result["message"] = f"SDL cannot count joysticks: {sdl_error(sdl2)}"
        elif count == 0:
            result["message"] = "no joysticks"
        for index in range(max(count, 0)):
            result["devices"].append(_describe_sdl2_joystick(sdl2, index))
    finally:
        sdl2.SDL_Quit()
    if result["devices"] and not any(d.get("constant_force") for d in result["devices"]):
        result["message"] = "no usable haptic joystick (SDL_HAPTIC_CONSTANT)"
    return result


def _describe_sdl2_joystick(sdl2: ModuleType, index: int) -> dict[str, Any]:
    raw_name = sdl2.SDL_JoystickNameForIndex(index)
    name = raw_name.decode("utf-8", "replace") if raw_name else "?"
    entry: dict[str, Any] = {"index": index, "name": name}
    joystick = sdl2.SDL_JoystickOpen(index)
    if not joystick:
        entry["error"] = sdl_error(sdl2)
        return entry
    try:
        entry["axes"] = int(sdl2.SDL_JoystickNumAxes(joystick))
        entry["haptic"] = sdl2.SDL_JoystickIsHaptic(joystick) == 1
        entry["constant_force"] = False
        if entry["haptic"]:
            haptic = sdl2.SDL_HapticOpenFromJoystick(joystick)
            if not haptic:
                entry["error"] = sdl_error(sdl2)
            else:
                features = int(sdl2.SDL_HapticQuery(haptic))
                entry["constant_force"] = bool(features & sdl2.SDL_HAPTIC_CONSTANT)
                sdl2.SDL_HapticClose(haptic)
    finally:
        sdl2.SDL_JoystickClose(joystick)
    return entry
