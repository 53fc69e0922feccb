"""A real-time run as one call: open the device, build the renderer, run the loop, record.

Kept apart from `loop.py` so that the loop itself imports no model, preset or file code.
"""

from __future__ import annotations

import math
import signal
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.realtime.clock import Clock, SimulatedClock, WallClock
from carfeel.realtime.devices.base import Device, DeviceError
from carfeel.realtime.loop import (
    CALIBRATION_PULSE_S,
    CALIBRATION_SETTLE_S,
    LoopConfig,
    LoopSummary,
    run_loop,
)
from carfeel.realtime.recording import Recorder
from carfeel.realtime.rendering import (
    MODES,
    Gains,
    HPatternRenderer,
    Renderer,
    Scaling,
    ShiftRenderer,
    SteeringRenderer,
    coupling_bound,
    default_scaling,
)
from carfeel.realtime.safety import SafetyLimits

MODELS = ("shift", "hpattern", "steering")
MODEL_FORCE_N = 100.0
"""The lever forces the shift models reach (the paper's 8-10 kgf), scaled onto the device."""
MODEL_TORQUE_NM = 10.0
MAX_RATE_HZ = 10_000.0
MIN_RATE_HZ = 250.0


@dataclass(frozen=True, slots=True)
class RealtimeRun:
    """A `carfeel run`."""

    model: str = "hpattern"
    device: str = "virtual"
    mode: str = "impedance"
    rate_hz: float = 1000.0
    duration_s: float | None = None
    sequence: tuple[str, ...] = ("N", "1", "2", "3", "4", "5", "4", "3", "2", "1", "N")
    preset: str | None = None
    speed_kmh: float = 30.0
    seed: int = 0
    clock: str = "wall"
    record: Path | None = None
    calibrate: bool = True
    device_max_force: float | None = None
    """A real device's force (N) or torque (Nm) limit; None: DEVICE_DEFAULTS."""
    device_travel: float | None = None
    substeps: int = 1
    """Model steps per loop tick (rate_hz * substeps at most 10 kHz)."""


@dataclass
class RealtimeResult:
    summary: LoopSummary
    scaling: Scaling
    device: str
    record: Path | None

    def as_dict(self) -> dict[str, Any]:
        s = self.summary
        return {
            "periods": s.periods,
            "overruns": s.overruns,
            "period_error_p50_us": _json_float(s.period_error_p50_us),
            "period_error_p99_us": _json_float(s.period_error_p99_us),
            "period_error_max_us": _json_float(s.period_error_max_us),
            "max_force_N": s.max_force_N,
            "faults": s.faults,
            "gears": s.gears,
            "notes": s.notes,
            "stopped": s.stopped,
            "device": self.device,
            "force_scale": self.scaling.force_scale,
            "position_scale": self.scaling.position_scale,
            "record": str(self.record) if self.record else None,
        }

    def text(self) -> str:
        s = self.summary
        lines = [
            f"{s.periods} periods on {self.device}, {s.overruns} overruns (> 1.5 periods); period "
            f"error p50 {s.period_error_p50_us:.1f} us, p99 {s.period_error_p99_us:.1f} us, max "
            f"{s.period_error_max_us:.1f} us",
            f"peak commanded force {s.max_force_N:.2f} (device units); scales: force "
            f"{self.scaling.force_scale:.3g}, position {self.scaling.position_scale:.3g}",
            f"gears engaged: {' '.join(s.gears) or 'none'}; stopped by {s.stopped}",
        ]
        lines += [f"fault: {f}" for f in s.faults]
        lines += [f"note: {n}" for n in s.notes]
        if self.record:
            lines.append(f"recorded {self.record} (+ .json)")
        return "\n".join(lines)


def _json_float(value: float) -> float | None:
    return None if math.isnan(value) else value


def _check(run: RealtimeRun) -> None:
    if run.model not in MODELS:
        raise InputError(f"--model {run.model!r}: choose one of {', '.join(MODELS)}")
    if run.mode not in MODES:
        raise InputError(f"--mode {run.mode!r}: choose one of {', '.join(MODES)}")
    if run.model == "steering" and run.mode != "impedance":
        raise InputError(
            "--model steering renders the torque law straight onto a force-feedback wheel: "
            "use --mode impedance"
        )
    if not (MIN_RATE_HZ <= run.rate_hz <= MAX_RATE_HZ) or not math.isfinite(run.rate_hz):
        raise InputError(
            f"--rate-hz {run.rate_hz:g}: allowed {MIN_RATE_HZ:g} <= value <= {MAX_RATE_HZ:g} Hz "
            "(below, the rendering's filters and the walls' passivity no longer hold)"
        )
    if not (math.isfinite(run.speed_kmh) and 0.0 <= run.speed_kmh <= 250.0):
        raise InputError(f"--speed-kmh {run.speed_kmh:g}: allowed 0 <= value <= 250 km/h")
    if run.device == "virtual" and (run.device_max_force or run.device_travel):
        raise InputError(
            "--device-max-force and --device-travel describe a real device; the virtual ones "
            "have their own limits (a 10 N joystick, a 4 Nm wheel)"
        )
    if run.substeps < 1 or run.rate_hz * run.substeps > MAX_RATE_HZ:
        raise InputError(
            f"--substeps {run.substeps}: the model may step at most {MAX_RATE_HZ:g} times a "
            f"second: at --rate-hz {run.rate_hz:g}, allowed 1 .. "
            f"{max(1, int(MAX_RATE_HZ // run.rate_hz))}"
        )
    if run.duration_s is not None and not 0.0 < run.duration_s <= 3600.0:
        raise InputError(f"--duration {run.duration_s:g}: allowed 0 < value <= 3600 s")
    if run.clock not in ("wall", "simulated"):
        raise InputError(f"--clock {run.clock!r}: choose wall or simulated")
    if run.clock == "simulated" and not run.device.startswith(("virtual", "replay")):
        raise InputError(
            "--clock simulated needs a virtual or replay device; a real one lives in wall time"
        )


DEVICE_DEFAULTS = {"joystick": (10.0, 0.04), "wheel": (2.5, math.radians(450.0))}
"""A real device's force (N or Nm) and travel (m or rad) unless given: a 10 N joystick, a
2.5 Nm wheel of 900 degrees (a gear-driven wheel of the Logitech kind)."""


def open_device(
    spec: str,
    hand: Any = None,
    seed: int = 0,
    kind: str = "joystick",
    max_force: float | None = None,
    travel: float | None = None,
) -> Device:
    """A device from its command-line name: virtual, evdev:PATH, sdl:INDEX, replay:FILE."""
    force_default, travel_default = DEVICE_DEFAULTS[kind]
    force = max_force or force_default
    reach = travel or travel_default
    if spec == "virtual":
        from carfeel.realtime.devices.virtual import virtual_joystick, virtual_wheel

        make = virtual_wheel if kind == "wheel" else virtual_joystick
        return make(hand, seed=seed)
    name, _, argument = spec.partition(":")
    if name == "replay" and argument:
        from carfeel.realtime.devices.replay import ReplayDevice

        path = Path(argument)
        if not path.is_file():
            raise InputError(f"--device replay:{argument}: no such recording")
        return ReplayDevice(path)
    if name == "evdev" and argument:
        from carfeel.realtime.devices.evdev_device import EvdevDevice

        return EvdevDevice(argument, kind=kind, max_force=force, travel=reach)
    if name == "sdl" and argument:
        from carfeel.realtime.devices.sdl2_device import SDL2Device

        if not argument.isdigit():
            raise InputError(f"--device sdl:{argument}: expected a joystick index, e.g. sdl:0")
        return SDL2Device(int(argument), kind=kind, max_force=force, travel=reach)
    raise InputError(
        f"--device {spec!r}: expected virtual, evdev:PATH (e.g. evdev:/dev/input/event5), "
        "sdl:INDEX or replay:FILE.csv; `carfeel devices` lists what is attached"
    )


@contextmanager
def _stop_on_signals() -> Iterator[list[bool]]:
    """Ctrl-C and SIGTERM ask the loop to stop (it zeroes the force first)."""
    flag = [False]

    def handler(signum: int, frame: Any) -> None:
        flag[0] = True

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def run_realtime(run: RealtimeRun) -> RealtimeResult:
    """Render a model on a device at a fixed rate; record and summarize."""
    _check(run)
    from carfeel.io.presets import load_hpattern, load_shift, load_steering
    from carfeel.models.drivers.hpattern import Script
    from carfeel.realtime import hands

    wheel = run.model == "steering"
    # The virtual hand waits for the calibration pulses and the ramp-in.
    ready_s = (
        2 * (CALIBRATION_PULSE_S + CALIBRATION_SETTLE_S) + SafetyLimits(1.0, 1.0).ramp_s
        if run.calibrate
        else 0.0
    )
    kind = "wheel" if wheel else "joystick"
    # The device first: the scales come from its limits (its hand, if virtual, comes after).
    device = open_device(run.device, None, run.seed, kind, run.device_max_force, run.device_travel)
    if device.info.kind != kind or device.info.axes < (1 if wheel else 2):
        raise InputError(
            f"--model {run.model} needs a {kind} with {1 if wheel else 2} axes; "
            f"{device.info.name} is a {device.info.kind} with {device.info.axes}"
        )
    info = device.info
    renderer: Renderer
    hand: Any = None
    duration = run.duration_s
    virtual = run.device == "virtual"
    if run.model == "shift":
        shift = load_shift(run.preset or "paper-first-gear").params
        scaling = default_scaling(MODEL_FORCE_N, shift.gearbox.in_gear_position_m + 0.005, info)
        hand = hands.ShiftHand(shift.driver, scaling.force_scale, scaling.position_scale, ready_s)
        renderer = ShiftRenderer(shift.gearbox, run.mode, scaling, run.rate_hz, seed=run.seed)
        duration = duration or 2.0 + ready_s
    elif run.model == "hpattern":
        preset = load_hpattern(run.preset or "5r")
        layout = preset.setup.layout
        names = {g.name for g in layout.gears} | {"N"}
        unknown = [g for g in run.sequence if g not in names]
        if unknown:
            raise InputError(
                f"--sequence: no gear {', '.join(unknown)} in layout {preset.name}; it has "
                f"{', '.join(sorted(names))}"
            )
        travel = max(preset.shift.gearbox.in_gear_position_m + 0.005,
                     max(abs(y) for y in layout.planes_y_m) + layout.slot_width_m)  # fmt: skip
        scaling = default_scaling(MODEL_FORCE_N, travel, info)
        script = Script(run.sequence, layout, preset.shift.driver, preset.setup.driver)
        hand = hands.HPatternHand(script, scaling.force_scale, scaling.position_scale, ready_s)
        renderer = HPatternRenderer(
            preset.pattern(), run.mode, scaling, run.rate_hz, seed=run.seed,
            vehicle_speed_m_s=run.speed_kmh / 3.6, engine_speed_rad_s=800 * math.pi / 30,
            clutch=hand if virtual else None,
        )  # fmt: skip
        duration = duration or 1.2 * len(run.sequence) + 1.0 + ready_s
    else:
        car = load_steering(run.preset or "b-segment").params
        scaling = Scaling(0.9 * info.max_force / MODEL_TORQUE_NM, 1.0)
        amplitude = math.radians(15.0)
        hand = hands.WheelHand(hands.weave_target(amplitude, 0.2))
        renderer = SteeringRenderer(car, run.speed_kmh / 3.6, scaling, run.rate_hz)
        duration = duration or 10.0
    renderer.substeps = run.substeps
    if virtual:
        device.hand = hand  # type: ignore[attr-defined]
    if run.device.startswith("replay"):
        recorded = getattr(device, "duration_s", duration)
        duration = min(duration, recorded - (ready_s - SafetyLimits(1.0, 1.0).ramp_s))
    limits = SafetyLimits(
        max_force=device.info.max_force,
        max_slew_per_s=max(device.info.max_force / 0.05, 200.0 * device.info.max_force),
    )
    clock: Clock = SimulatedClock() if run.clock == "simulated" else WallClock()
    metadata = {
        "carfeel_version": __version__,
        "model": run.model,
        "preset": run.preset,
        "mode": run.mode,
        "device": device.info.name,
        "device_spec": run.device,
        "rate_hz": run.rate_hz,
        "substeps": run.substeps,
        "duration_s": duration,
        "clock": run.clock,
        "force_scale": scaling.force_scale,
        "position_scale": scaling.position_scale,
        "sequence": ",".join(run.sequence) if run.model == "hpattern" else None,
        "speed_kmh": run.speed_kmh,
        "seed": run.seed,
        "max_force": limits.max_force,
        "travel": device.info.travel,
        "coupling_bound": coupling_bound(Gains(), scaling, run.rate_hz),
        "device_kind": device.info.kind,
        "max_slew_per_s": limits.max_slew_per_s,
    }
    axes = device.info.axes
    columns = ("time_s", "overrun", *(f"command_{i}" for i in range(axes)), "fault",
               *renderer.columns)  # fmt: skip
    recorder = Recorder(run.record, columns, metadata) if run.record else None
    bound = coupling_bound(Gains(), scaling, run.rate_hz)
    plant = getattr(device, "plant", None)
    caution = (
        f"the coupling's K*T/2 + B at the handle, {bound:.2g}, is not below the device's own "
        f"damping, {plant.damping:.2g}: the rendering may not be passive"
        if run.mode == "impedance" and plant is not None and bound >= plant.damping
        else None
    )
    summary = None
    try:
        with _stop_on_signals() as stop, device:
            summary = run_loop(
                renderer, device, clock, LoopConfig(run.rate_hz, duration, run.calibrate), limits,
                recorder, should_stop=lambda: stop[0],
            )  # fmt: skip
    except DeviceError:
        raise
    finally:
        if recorder is not None:
            recorder.close(summary.as_dict() if summary else {"stopped": "error"})
    if caution and summary is not None:
        summary.notes.append(caution)
    return RealtimeResult(summary, scaling, device.info.name, run.record)
