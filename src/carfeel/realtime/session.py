"""A real-time run as one call: open the device, build the renderer, run the loop, record.

Kept apart from `loop.py` so that the loop itself imports no model, preset or file code.
"""

from __future__ import annotations

import math
import os
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.realtime.clock import Clock, SimulatedClock, WallClock
from carfeel.realtime.devices.base import Device, DeviceInfo
from carfeel.realtime.hands import HANDS
from carfeel.realtime.loop import (
    CALIBRATION_PULSE_S,
    CALIBRATION_SETTLE_S,
    LoopConfig,
    LoopObserver,
    LoopSummary,
    run_loop,
)
from carfeel.realtime.recording import Recorder
from carfeel.realtime.rendering import (
    ALIGNING,
    MODES,
    Gains,
    HPatternRenderer,
    Renderer,
    Scaling,
    ShiftRenderer,
    SteeringRenderer,
    SteeringRendering,
    default_scaling,
    ring_wall,
    velocity_sections,
)
from carfeel.realtime.safety import SafetyLimits
from carfeel.realtime.stability import Sizing

MODELS = ("shift", "hpattern", "steering")
DEFAULT_PRESETS = {"shift": "paper-first-gear", "hpattern": "5r", "steering": "b-segment"}
MODEL_FORCE_N = 100.0
"""The lever forces the shift models reach (the paper's 8-10 kgf), scaled onto the device."""
MODEL_TORQUE_NM = 10.0
MAX_RATE_HZ = 10_000.0
WEAVE_CYCLES = 2
"""The virtual hands' weave on a wheel (0.2 Hz, 15 deg), then they hold it at centre."""
MIN_RATE_HZ = 250.0
DEVICE_DAMPING_MAX = 1000.0
DEVICE_MASS_MIN = 1e-4
DEVICE_MASS_MAX = 50.0


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
    hand: str = "script"
    """script (the simulated driver holds the device), none, or release (script, then let go);
    virtual devices only."""
    release_angle_deg: float = 30.0
    """--hand release with --model steering: the rim angle held for 1 s before letting go."""
    device_delay_ms: float | None = None
    """Transport delay each way, ms: sets a virtual device's, declares a real one's."""
    device_report_hz: float | None = None
    device_damping: float | None = None
    """A real device's own damping, N*s/m or Nm*s/rad (declared; the sizing rests on it)."""
    device_mass: float | None = None
    """A real device's moving mass at the handle, kg (or its inertia, kg m^2)."""
    aligning: str = "front-axle"
    """--model steering: where tau0's Ay comes from (front-axle, or the paper's steady-state)."""
    steering_model: str = "paper"
    """--model steering: the paper's law, or the physical model behind a virtual coupling
    (`realtime.physical_steering`)."""
    road: str | None = None
    """--steering-model physical: the road under its tyres (dry, wet, snow), or None: the
    preset's own tyres.friction_coefficient."""
    passivity_controller: bool = True
    synchronizer: str | None = None
    """--model hpattern: fixed (the paper's timer) or physics; None: the preset's."""
    telemetry: str | None = None
    """FORMAT:HOST:PORT: the game's vehicle state drives the model (`carfeel.telemetry`)."""
    gear_output: str = "none"
    """--model hpattern: none, uinput or vjoy (a virtual joystick's buttons per gear slot)."""
    gear_timing: str = "slot"
    gear_mapping: str = "buttons"
    """--gear-mapping: the binding the game expects (buttons, sequential)."""
    car_presets: Path | None = None
    """A TOML file mapping the car a format names to the presets for it."""
    interlock: str = "tell"
    """--telemetry, --model hpattern: on a lever/game gear mismatch, tell the game (the gear
    output) or also hold: push the lever out of a gear the game stays in neutral on."""
    game_torque: float = 0.0
    """--telemetry, --model steering: the share of tau0 the game's own FFB torque takes (0 the
    law's alone, 1 the game's; `telemetry.driving.GameTorque`)."""
    identify: str = "auto"
    """How the device is known (`realtime.knowledge`): auto (its profile checked, else
    identified hands off), full (identified), off (as declared, sized over DECLARED_SET)."""
    device_profile: Path | None = None
    """A device profile to check and use (or write), instead of the device's own under the
    user's configuration folder."""
    loop_cpu: int | None = None
    """The core a wall-clock run is pinned to (`realtime.scheduling`); None: the last."""


@dataclass
class RealtimeResult:
    summary: LoopSummary
    scaling: Scaling
    device: str
    record: Path | None
    stability: dict[str, float] = field(default_factory=dict)
    unit: str = "N"
    """The commands' unit: N on a joystick or shifter, Nm on a wheel."""
    device_knowledge: dict[str, Any] = field(default_factory=dict)
    """How the device is known and what was measured (`Knowledge.as_dict`)."""

    def as_dict(self) -> dict[str, Any]:
        s = self.summary
        return {
            "periods": s.periods,
            "overruns": s.overruns,
            "period_error_p50_us": _json_float(s.period_error_p50_us),
            "period_error_p99_us": _json_float(s.period_error_p99_us),
            "period_error_max_us": _json_float(s.period_error_max_us),
            "peak_command": s.peak_command,
            "command_unit": self.unit,
            "faults": s.faults,
            "gears": s.gears,
            "notes": s.notes,
            "stopped": s.stopped,
            "device": self.device,
            "force_scale": self.scaling.force_scale,
            "position_scale": self.scaling.position_scale,
            "record": str(self.record) if self.record else None,
            "time_at_limit_s": s.time_at_limit_s,
            "oscillation_rms": _json_float(s.oscillation_rms),
            "passivity_acted_s": s.passivity_acted_s,
            "stability": self.stability,
            "device_knowledge": self.device_knowledge,
        }

    def text(self) -> str:
        s = self.summary
        lines = [
            f"{s.periods} periods on {self.device}, {s.overruns} overruns (> 1.5 periods); period "
            f"error p50 {s.period_error_p50_us:.1f} us, p99 {s.period_error_p99_us:.1f} us, max "
            f"{s.period_error_max_us:.1f} us",
            f"peak command {s.peak_command:.2f} {self.unit}; scales: force "
            f"{self.scaling.force_scale:.3g}, position {self.scaling.position_scale:.3g}",
            (
                f"gears engaged: {' '.join(s.gears) or 'none'}; " if self.unit != "Nm" else ""
            )  # a wheel shifts no gears
            + f"stopped by {s.stopped}",
            f"time at the force limit {s.time_at_limit_s:.3f} s; largest 2-100 Hz command "
            f"{s.oscillation_rms:.3g} rms; passivity controller active {s.passivity_acted_s:.3f} s",
        ]
        if self.stability:
            st = self.stability
            lines.append(
                f"sized for this device: stiffness {st['stiffness']:.4g}, damping "
                f"{st['damping']:.3g} (cap {st['damping_cap']:.3g}), hands-off damping ratio "
                f"{st['zeta_hands_off']:.2f}, round-trip delay {st['latency_s'] * 1e3:.3g} ms, "
                f"passivity index {st['passivity_index']:.3g} "
                + (
                    "(under 1: passive for any hand)"
                    if st["passivity_index"] < 1.0
                    else "(1 or more: not passive for every hand; stable by the sizing above, "
                    "guarded by the passivity controller)"
                )
            )
            if "coupling_stiffness" in st:
                lines.append(
                    f"physical steering behind a coupling of {st['coupling_stiffness']:.4g} "
                    f"Nm/rad ({st['felt_stiffness_share']:.0%} of the car's on-centre stiffness "
                    f"felt), scheduled damping up to {st['added_damping_max']:.3g} Nm*s/rad, "
                    f"least damping ratio {st['zeta_physical']:.2f}, sized up to "
                    f"{st['top_speed_kmh']:.0f} km/h"
                )
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
        why = (
            f"above, a tick is shorter than the {1e6 / MAX_RATE_HZ:g} us the loop can keep to"
            if run.rate_hz > MAX_RATE_HZ
            else "below, the rendering's filters and the walls' passivity no longer hold"
            if run.rate_hz < MIN_RATE_HZ
            else "a rate is a finite number of ticks a second"
        )
        raise InputError(
            f"--rate-hz {run.rate_hz:g}: allowed {MIN_RATE_HZ:g} <= value <= {MAX_RATE_HZ:g} Hz "
            f"({why})"
        )
    if not (math.isfinite(run.speed_kmh) and 0.0 <= run.speed_kmh <= 250.0):
        raise InputError(f"--speed-kmh {run.speed_kmh:g}: allowed 0 <= value <= 250 km/h")
    virtual = run.device.startswith("virtual")
    declared = (run.device_max_force, run.device_travel, run.device_damping, run.device_mass)
    if virtual and any(v is not None for v in declared):
        raise InputError(
            "--device-max-force, --device-travel, --device-damping and --device-mass describe a "
            "real device; the virtual ones have their own (see --device virtual:KIND)"
        )
    if run.synchronizer not in (None, "fixed", "physics"):
        raise InputError(f"--synchronizer {run.synchronizer!r}: choose fixed or physics")
    if run.device.startswith("replay") and run.device_max_force is not None:
        raise InputError(
            "--device-max-force describes a real device; a replay takes the recorded device's "
            "limits from the recording's sidecar"
        )
    if run.device_max_force is not None and not 0.0 < run.device_max_force <= 200.0:
        raise InputError(
            f"--device-max-force {run.device_max_force:g}: allowed 0 < value <= 200 (N at a "
            "knob, Nm at a rim)"
        )
    if run.device_travel is not None and not 0.0 < run.device_travel <= 20.0:
        raise InputError(
            f"--device-travel {run.device_travel:g}: allowed 0 < value <= 20 (m at a knob, "
            "rad at a rim)"
        )
    if run.hand not in HANDS:
        raise InputError(f"--hand {run.hand!r}: choose one of {', '.join(HANDS)}")
    if run.hand != "script" and not virtual:
        raise InputError("--hand none|release needs a virtual device (a real one has your hand)")
    if run.aligning not in ALIGNING:
        raise InputError(f"--aligning {run.aligning!r}: choose one of {', '.join(ALIGNING)}")
    _check_steering_model(run)
    if run.device_delay_ms is not None and not 0.0 <= run.device_delay_ms <= 50.0:
        raise InputError(f"--device-delay-ms {run.device_delay_ms:g}: allowed 0 <= value <= 50")
    if run.device_report_hz is not None and not 100.0 <= run.device_report_hz <= 10_000.0:
        raise InputError(
            f"--device-report-hz {run.device_report_hz:g}: allowed 100 <= value <= 10000"
        )
    if not (math.isfinite(run.release_angle_deg) and 0.0 < run.release_angle_deg <= 180.0):
        raise InputError(f"--release-angle-deg {run.release_angle_deg:g}: allowed 0 < value <= 180")
    # Bounds beyond any device (a knob's mass or a rim's inertia, its own damping), so that the
    # sizing's discrete-time loop stays well conditioned (1e300 made it fail with a LinAlgError).
    for flag, value, low, high, unit in (
        ("--device-damping", run.device_damping, 0.0, DEVICE_DAMPING_MAX, "N*s/m at a knob, "
         "Nm*s/rad at a rim"),
        ("--device-mass", run.device_mass, DEVICE_MASS_MIN, DEVICE_MASS_MAX, "kg at a knob, "
         "kg*m^2 at a rim"),
    ):  # fmt: skip
        if value is not None and not (math.isfinite(value) and low < value <= high):
            raise InputError(f"{flag} {value:g}: allowed {low:g} < value <= {high:g} ({unit})")
    if run.substeps < 1 or run.rate_hz * run.substeps > MAX_RATE_HZ:
        raise InputError(
            f"--substeps {run.substeps}: the model may step at most {MAX_RATE_HZ:g} times a "
            f"second: at --rate-hz {run.rate_hz:g}, allowed 1 .. "
            f"{max(1, int(MAX_RATE_HZ // run.rate_hz))}"
        )
    if run.duration_s is not None and not 0.0 < run.duration_s <= 3600.0:
        raise InputError(f"--duration {run.duration_s:g}: allowed 0 < value <= 3600 s")
    _check_telemetry(run)
    from carfeel.realtime.knowledge import IDENTIFY_MODES

    if run.identify not in IDENTIFY_MODES:
        raise InputError(f"--identify {run.identify!r}: choose one of {', '.join(IDENTIFY_MODES)}")
    if run.device_profile is not None and run.identify == "off":
        raise InputError("--device-profile holds a measured device: drop --identify off")
    if run.device.startswith("replay") and (
        run.device_profile is not None or run.identify == "full"
    ):
        raise InputError(
            "a replayed device cannot be identified (it plays back a recording): drop "
            "--identify full and --device-profile"
        )
    if run.loop_cpu is not None:
        cores = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
        if not cores:
            raise InputError("--loop-cpu: this system cannot pin a process to a core")
        if run.loop_cpu not in cores:
            raise InputError(
                f"--loop-cpu {run.loop_cpu}: this process may use cores "
                f"{', '.join(map(str, cores))}"
            )
    if run.clock not in ("wall", "simulated"):
        raise InputError(f"--clock {run.clock!r}: choose wall or simulated")
    if run.clock == "simulated" and not run.device.startswith(("virtual", "replay")):
        raise InputError(
            "--clock simulated needs a virtual or replay device; a real one lives in wall time"
        )


def _check_steering_model(run: RealtimeRun) -> None:
    from carfeel.simulation.steering import ROAD_FRICTION, STEERING_MODELS

    if run.steering_model not in STEERING_MODELS:
        raise InputError(
            f"--steering-model {run.steering_model!r}: choose one of {', '.join(STEERING_MODELS)}"
        )
    if run.road is not None and run.road not in ROAD_FRICTION:
        raise InputError(f"--road {run.road!r}: choose one of {', '.join(ROAD_FRICTION)}")
    if run.steering_model == "physical" and run.model != "steering":
        raise InputError("--steering-model physical needs --model steering")
    if run.road is not None and run.steering_model != "physical":
        raise InputError(
            "--road sets the physical model's tyres: give --steering-model physical too"
        )
    if run.steering_model == "physical" and run.rate_hz * run.substeps < 1000.0 - 1e-9:
        from math import ceil

        raise InputError(
            f"--steering-model physical steps at 1 ms at most (its rack and end stops need it): "
            f"at --rate-hz {run.rate_hz:g} give --substeps {ceil(1000.0 / run.rate_hz - 1e-9)}"
        )
    if run.steering_model == "physical" and run.aligning != "front-axle":
        raise InputError(
            "--aligning chooses the paper law's aligning torque; the physical model's comes "
            "from its own tyres (drop --aligning, or use --steering-model paper)"
        )


def _check_telemetry(run: RealtimeRun) -> None:
    from carfeel.telemetry.gearout import GEAR_OUTPUTS, GEAR_TIMINGS

    if run.gear_output not in GEAR_OUTPUTS:
        raise InputError(
            f"--gear-output {run.gear_output!r}: choose one of {', '.join(GEAR_OUTPUTS)}"
        )
    if run.gear_timing not in GEAR_TIMINGS:
        raise InputError(
            f"--gear-timing {run.gear_timing!r}: choose one of {', '.join(GEAR_TIMINGS)}"
        )
    if run.gear_output != "none" and run.model != "hpattern":
        raise InputError("--gear-output needs --model hpattern (the lever's slot is the gear)")
    if run.gear_output != "none" and run.telemetry is None:
        raise InputError(
            f"--gear-output {run.gear_output} presses the gear's buttons for a game: it needs "
            "--telemetry (without it no button is pressed)"
        )
    if run.car_presets is not None and run.telemetry is None:
        raise InputError("--car-presets needs --telemetry (the format names the car)")
    if run.interlock not in ("tell", "hold"):
        raise InputError(f"--interlock {run.interlock!r}: choose tell or hold")
    if run.interlock == "hold" and (run.telemetry is None or run.model != "hpattern"):
        raise InputError(
            "--interlock hold needs --model hpattern and --telemetry (the game's gear)"
        )
    if run.game_torque != 0.0:
        if not 0.0 <= run.game_torque <= 1.0:  # NaN fails too
            raise InputError(
                f"--game-torque {run.game_torque:g}: a share from 0 (the law's tau0) to 1 "
                "(the game's own force-feedback torque instead)"
            )
        if run.telemetry is None or run.model != "steering" or run.steering_model == "physical":
            raise InputError(
                "--game-torque blends the game's force-feedback torque into the paper law's "
                "tau0: it needs --model steering (--steering-model paper) and --telemetry"
            )
    if run.telemetry is not None:
        from carfeel.telemetry.receiver import parse_source

        parse_source(run.telemetry)
        if run.model not in ("steering", "hpattern"):
            raise InputError("--telemetry drives --model steering or hpattern")


DEVICE_DEFAULTS = {"joystick": (10.0, 0.04), "wheel": (2.5, math.radians(450.0))}
"""A real device's force (N or Nm) and travel (m or rad) unless given: a 10 N joystick, a
2.5 Nm wheel of 900 degrees (a gear-driven wheel of the Logitech kind)."""
REAL_DYNAMICS = {"joystick": (0.1, 2.0), "wheel": (0.04, 0.03)}
"""A real device's mass (kg, kg m^2) and damping (N*s/m, Nm*s/rad) unless declared: on the low
side of consumer devices, so the sizing errs toward soft and stable."""
REAL_DELAY_S = 0.002
REAL_REPORT_HZ = 500.0
"""Unless declared: 2 ms each way, 500 reports a second (what USB force-feedback devices of the
Logitech kind manage)."""


def open_device(
    spec: str,
    hand: Any = None,
    seed: int = 0,
    kind: str = "joystick",
    max_force: float | None = None,
    travel: float | None = None,
    delay_s: float | None = None,
    report_hz: float | None = None,
) -> Device:
    """A device from its command-line name: virtual[:KIND], evdev:PATH, sdl:INDEX, replay:FILE."""
    force_default, travel_default = DEVICE_DEFAULTS[kind]
    force = max_force or force_default
    reach = travel or travel_default
    name, _, argument = spec.partition(":")
    if name == "virtual":
        from carfeel.realtime.devices.virtual import PLANTS, parse_virtual, virtual_device

        try:
            plant, changes = parse_virtual(argument or ("wheel" if kind == "wheel" else "joystick"))
        except ValueError as exc:
            raise InputError(f"--device {spec}: {exc}") from None
        if plant not in PLANTS or PLANTS[plant][2] != kind:
            fitting = [k for k, (_, _, c) in PLANTS.items() if c == kind]
            raise InputError(
                f"--device {spec}: this model needs one of virtual:{', virtual:'.join(fitting)} "
                "(then :KEY=VALUE,... for a true plant unlike the catalogue's)"
            )
        try:
            # A session's device keeps no log: its memory must not grow with the session.
            return virtual_device(plant, hand, delay_s, report_hz, changes, seed=seed,
                                  log_limit=0)  # fmt: skip
        except ValueError as exc:
            raise InputError(f"--device {spec}: {exc}") from None
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
        f"--device {spec!r}: expected virtual[:KIND], evdev:PATH (e.g. evdev:/dev/input/event5), "
        "sdl:INDEX or replay:FILE.csv; `carfeel devices` lists what is attached"
    )


@contextmanager
def _stop_on_signals() -> Iterator[list[str]]:
    """Ctrl-C and SIGTERM ask the loop to stop (it zeroes the force first); the list holds the
    signal's name once one came."""
    flag: list[str] = []

    def handler(signum: int, frame: Any) -> None:
        if not flag:
            flag.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield flag
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def _declared_info(device: Device, run: RealtimeRun, kind: str) -> DeviceInfo:
    """A real device's dynamics as declared on the command line, or the defaults; a virtual or
    replayed device knows its own (a delay or report rate given for it is already in)."""
    info = device.info
    if run.device.startswith(("virtual", "replay")):
        return info
    mass, damping = REAL_DYNAMICS[kind]
    delay = REAL_DELAY_S if run.device_delay_ms is None else run.device_delay_ms / 1e3
    return replace(
        info,
        mass=run.device_mass or mass,
        damping=run.device_damping or damping,
        command_delay_s=delay,
        reading_delay_s=delay,
        report_hz=run.device_report_hz or min(REAL_REPORT_HZ, info.update_hz),
    )


def _delay_text(info: DeviceInfo) -> str:
    """The round trip the sizing covered, as a refusal names it."""
    short, long = info.delay_range_s or (info.round_trip_s, info.round_trip_s)
    text = f"{info.round_trip_s * 1e3:.3g} ms of round-trip delay"
    if long > short:
        text += f" (sized for {short * 1e3:.3g} to {long * 1e3:.3g} ms)"
    return text


def _refuse_soft(info: DeviceInfo, sizing: Sizing, run: RealtimeRun) -> None:
    """A coupling softer than the force limit over the whole travel cannot render a gearbox."""
    need = info.max_force / info.travel
    if sizing.stiffness < need:
        raise InputError(
            f"{info.name} cannot render --model {run.model} stably at {run.rate_hz:g} Hz with "
            f"{_delay_text(info)} and "
            f"{info.report_hz:g} reports a second: hands off, it stays stable only up to "
            f"{sizing.stiffness:.3g} (device units per m) of coupling, and a gearbox needs at "
            f"least {need:.3g} (its force limit over its travel). Lower the delay, raise the rate "
            "or use a device with more damping"
        )


class _Shifted:
    """A device seen from the loop, whose times start at the loop's start: the device itself
    is `offset_s` further on (the time its identification took)."""

    def __init__(self, device: Device, offset_s: float) -> None:
        self.device, self.offset_s = device, offset_s
        self.info = device.info

    def __enter__(self) -> _Shifted:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def read(self, time_s: float) -> Any:
        return self.device.read(time_s + self.offset_s)._replace(time_s=time_s)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        self.device.command(forces, time_s + self.offset_s)


@dataclass(frozen=True, slots=True)
class RunParts:
    """What a run is built of, handed to a `SessionObserver` just before the loop starts."""

    renderer: Renderer
    info: DeviceInfo
    sizing: Sizing
    scaling: Scaling
    limits: SafetyLimits
    columns: tuple[str, ...]
    """The rows' columns, as a recording's."""
    metadata: dict[str, Any]
    """A recording's sidecar."""


class SessionObserver(LoopObserver, Protocol):
    """A loop observer (a live panel) that is also shown the run's parts before it starts."""

    def prepare(self, parts: RunParts) -> None: ...


def run_realtime(
    run: RealtimeRun,
    announce: Callable[[], None] | None = None,
    observer: SessionObserver | None = None,
    say: Callable[[str], None] | None = None,
) -> RealtimeResult:
    """Render a model on a device at a fixed rate; record and summarize. The device is known
    first (identified hands off, its profile checked, or as declared: `realtime.knowledge`),
    `say` telling the user what to do meanwhile; then `announce` is called once everything is
    checked, just before the loop starts; then `observer.prepare`, and the observer watches the
    loop (`LoopObserver`)."""
    _check(run)
    preset_name = run.preset or DEFAULT_PRESETS[run.model]
    kind = "wheel" if run.model == "steering" else "joystick"
    delay = None if run.device_delay_ms is None else run.device_delay_ms / 1e3
    receiver = None
    if run.telemetry is not None:
        # Before the device: a port in use or a bad source stops the run before anything starts.
        from carfeel.telemetry.receiver import open_receiver

        receiver = open_receiver(run.telemetry)
    try:
        return _run_realtime(run, announce, receiver, preset_name, kind, delay, observer, say)
    finally:
        if receiver is not None:
            receiver.close()


def _run_realtime(
    run: RealtimeRun,
    announce: Callable[[], None] | None,
    receiver: Any,
    preset_name: str,
    kind: str,
    delay: float | None,
    observer: SessionObserver | None = None,
    say: Callable[[str], None] | None = None,
) -> RealtimeResult:
    from carfeel.realtime.knowledge import know_device, real_max_force
    from carfeel.realtime.scheduling import claimed

    wheel = run.model == "steering"
    if receiver is not None:
        from carfeel.telemetry.carmap import profile_for_car

        profile = profile_for_car(run.car_presets, receiver)
        if profile is not None:
            preset_name = profile.presets.get(run.model) or preset_name
            receiver.notes.append(profile.describe(run.model))
            receiver.torque_scale_Nm = profile.torque_scale_Nm
    # The device first: the scales come from its limits (its hand, if virtual, comes after).
    device = open_device(
        run.device, None, run.seed, kind, run.device_max_force, run.device_travel, delay,
        run.device_report_hz,
    )  # fmt: skip
    if device.info.kind != kind or device.info.axes < (1 if wheel else 2):
        raise InputError(
            f"--model {run.model} needs a {kind} with {1 if wheel else 2} axes; "
            f"{device.info.name} is a {device.info.kind} with {device.info.axes}"
        )
    device.info = _declared_info(device, run, kind)
    clock: Clock = SimulatedClock() if run.clock == "simulated" else WallClock()
    origin = clock.now_ns()
    # The device is opened before anything is recorded: a device that cannot be opened leaves
    # no recording behind.
    wall = run.clock == "wall"
    with claimed(run.loop_cpu, wanted=wall) as taken, _stop_on_signals() as stop, device:
        if not run.device.startswith(("virtual", "replay")):
            device.info = replace(
                device.info, max_force=real_max_force(device, run.device_max_force)
            )
        knowledge = know_device(
            device, clock, run.rate_hz, origin, run.identify, run.device_profile, say,
            recorded=run.device.startswith("replay"),
        )  # fmt: skip
        info = device.info = knowledge.info
        started_s = (clock.now_ns() - origin) / 1e9
        result = _render(run, announce, receiver, preset_name, device, info, knowledge, clock,
                         origin, started_s, stop, observer)  # fmt: skip
        if wall:
            result.summary.notes.insert(0, taken.text())
        return result


def _render(
    run: RealtimeRun,
    announce: Callable[[], None] | None,
    receiver: Any,
    preset_name: str,
    device: Device,
    info: DeviceInfo,
    knowledge: Any,
    clock: Clock,
    origin: int,
    started_s: float,
    stop: list[str],
    observer: SessionObserver | None,
) -> RealtimeResult:
    """Size, build and run the rendering on a known, open device (times since `origin`; the
    loop starts at `started_s`, after the identification)."""
    from carfeel.io.presets import load_hpattern, load_shift, load_steering
    from carfeel.models.drivers.hpattern import Script
    from carfeel.realtime import hands, stability
    from carfeel.realtime.knowledge import describe

    wheel = run.model == "steering"
    # The virtual hand waits for the calibration pulses (none where the polarity was measured)
    # and the ramp-in, from the loop's start.
    pulses = run.calibrate and knowledge.polarity is None
    calibration_s = 2 * (CALIBRATION_PULSE_S + CALIBRATION_SETTLE_S) if pulses else 0.0
    ready_s = calibration_s + SafetyLimits(1.0, 1.0).ramp_s if run.calibrate else 0.0
    t0 = started_s
    sizing = stability.size(info, run.rate_hz, velocity_sections(run.rate_hz))
    renderer: Renderer
    hand: Any = None
    duration = run.duration_s
    physical_figure: dict[str, float] = {}
    virtual = run.device.startswith("virtual")
    notes: list[str] = []
    if run.model == "shift":
        _refuse_soft(info, sizing, run)
        shift = load_shift(preset_name).params
        scaling = default_scaling(MODEL_FORCE_N, shift.gearbox.in_gear_position_m + 0.005, info)
        hand = hands.ShiftHand(shift.driver, scaling.force_scale, scaling.position_scale,
                               t0 + ready_s)  # fmt: skip
        if run.hand == "release":
            pushing = hand
            # Lets go once the driver has pushed the lever home and relaxed its push.
            hand = hands.ReleasingHand(
                pushing,
                lambda t: (
                    pushing.state.phase.value == "release" and pushing.state.activation < 0.05
                ),
            )
        # The ring blocks only while the hand pushes: sized for the preset's hand on it.
        wall = ring_wall(info, run.rate_hz, scaling, shift.driver)
        renderer = ShiftRenderer(shift.gearbox, run.mode, scaling, run.rate_hz,
                                 Gains.sized(sizing, scaling), seed=run.seed,
                                 wall=wall)  # fmt: skip
        duration = duration or 2.0 + ready_s
    elif run.model == "hpattern":
        _refuse_soft(info, sizing, run)
        preset = load_hpattern(preset_name)
        layout = preset.setup.layout
        names = {*layout.gear_names(), "N"}
        unknown = [g for g in run.sequence if g not in names]
        if unknown:
            raise InputError(
                f"--sequence: no gear {', '.join(unknown)} in layout {preset.name}; it has "
                f"{', '.join(sorted(names))}"
            )
        travel = max(preset.shift.gearbox.in_gear_position_m + 0.005,
                     max(abs(y) for y in layout.planes_y_m) + layout.slot_width_m)  # fmt: skip
        scaling = default_scaling(MODEL_FORCE_N, travel, info)
        gains = Gains.sized(sizing, scaling)
        # The hand presses the knob against the gate's end for the outer planes, as far as the
        # coupling's stretch at its full select force (the model's knob lags the handle).
        reach = layout.slot_width_m + preset.setup.driver.select_force_N / gains.coupling_stiffness
        script = Script(run.sequence, layout, preset.shift.driver, preset.setup.driver,
                        outer_push_m=reach)  # fmt: skip
        hand = hands.HPatternHand(script, scaling.force_scale, scaling.position_scale,
                                  t0 + ready_s)  # fmt: skip
        if run.hand == "release":
            scripted = hand
            hand = hands.ReleasingHand(scripted, lambda t: scripted.done)
        renderer = HPatternRenderer(
            preset.pattern(None if run.synchronizer is None else run.synchronizer == "physics"),
            run.mode, scaling, run.rate_hz, gains,
            seed=run.seed, vehicle_speed_m_s=run.speed_kmh / 3.6,
            engine_speed_rad_s=800 * math.pi / 30, clutch=hand if virtual else None,
            wall=ring_wall(info, run.rate_hz, scaling, preset.shift.driver),
        )  # fmt: skip
        duration = duration or 1.2 * len(run.sequence) + 1.0 + ready_s
    else:
        car = load_steering(preset_name).params
        if run.hand == "release":
            hand = hands.holding_wheel(
                math.radians(run.release_angle_deg), t0 + calibration_s,
                1.0 + ready_s - calibration_s,
            )  # fmt: skip
        else:
            weave = hands.weave_target(math.radians(15.0), 0.2, t0 + ready_s, WEAVE_CYCLES)
            hand = hands.WheelHand(weave, start_s=t0 + calibration_s)
        duration = duration or ready_s + WEAVE_CYCLES / 0.2 + 2.0
        if run.steering_model == "physical":
            renderer, scaling, physical_figure = _physical_renderer(
                car, preset_name, run, info, sizing, receiver is not None, notes
            )
        else:
            scaling = _steering_scaling(car, run, info, sizing, notes)
            renderer = SteeringRenderer(car, run.speed_kmh / 3.6, scaling, run.rate_hz, sizing,
                                        info, SteeringRendering(aligning=run.aligning))  # fmt: skip
    renderer.substeps = run.substeps
    driven = None
    if receiver is not None:
        driven = _drive_by_telemetry(run, renderer, receiver, info, hand if virtual else None)
        renderer = driven
    if virtual and run.hand != "none":
        device.hand = hand  # type: ignore[attr-defined]
    if run.device.startswith("replay"):
        recorded = getattr(device, "duration_s", duration)
        duration = min(duration, recorded - (ready_s - SafetyLimits(1.0, 1.0).ramp_s))
    limits = SafetyLimits(
        max_force=info.max_force,
        max_slew_per_s=max(info.max_force / 0.05, 200.0 * info.max_force),
    )
    figure = stability_figure(sizing, info, run.rate_hz)
    figure.update(physical_figure)
    metadata = {
        "carfeel_version": __version__,
        "model": run.model,
        "preset": preset_name,
        "mode": run.mode,
        "device": info.name,
        "device_spec": run.device,
        "rate_hz": run.rate_hz,
        "substeps": run.substeps,
        "duration_s": duration,
        "clock": run.clock,
        "hand": run.hand,
        "force_scale": scaling.force_scale,
        "position_scale": scaling.position_scale,
        "sequence": ",".join(run.sequence) if run.model == "hpattern" else None,
        "speed_kmh": run.speed_kmh,
        "seed": run.seed,
        "max_force": limits.max_force,
        "travel": info.travel,
        "device_kind": info.kind,
        "device_mass": info.mass,
        "device_damping": info.damping,
        "command_delay_s": info.command_delay_s,
        "reading_delay_s": info.reading_delay_s,
        "report_hz": info.report_hz,
        "resolution": info.resolution,
        "noise": info.noise,
        "max_slew_per_s": limits.max_slew_per_s,
        "stability": figure,
        "device_knowledge": knowledge.as_dict(),
    }
    if wheel:
        metadata["steering_model"] = run.steering_model
        if run.steering_model == "physical":
            metadata["road"] = run.road or "the preset's"
        else:
            metadata["aligning"] = run.aligning
    axes = info.axes
    columns = ("time_s", "overrun", *(f"command_{i}" for i in range(axes)), "fault",
               *renderer.columns)  # fmt: skip
    config = LoopConfig(
        run.rate_hz, duration, run.calibrate,
        passivity=run.passivity_controller, polarity=knowledge.polarity,
    )  # fmt: skip
    summary = None
    recorder = None
    if announce is not None:
        announce()
    if observer is not None:
        observer.prepare(RunParts(renderer, info, sizing, scaling, limits, columns, metadata))
    recorder = Recorder(run.record, columns, metadata) if run.record else None
    try:
        # The loop's times (the recording's, the renderer's) count from its start; the device
        # (and a virtual device's hand) lives on in its own time, after the identification.
        summary = run_loop(
            renderer, _Shifted(device, t0), clock, config, limits, recorder,
            should_stop=lambda: bool(stop), observer=observer,
        )  # fmt: skip
        if stop and summary.stopped == "stopped":
            summary.stopped = stop[0]
    finally:
        if recorder is not None:
            recorder.close(summary.as_dict() if summary else {"stopped": "error"})
        if driven is not None:
            driven.close()
    if driven is not None:
        r = driven.source.receiver
        notes += driven.source.events + r.notes
        notes.append(
            f"telemetry {r.format.name} on {r.where}: {r.packets} good packets, "
            f"{r.bad} bad, {r.ignored} "
            f"ignored{'; car ' + r.latest.car if r.latest.car else ''}"
        )
    summary.notes[:0] = [describe(knowledge), *knowledge.notes]
    summary.notes.extend(notes)
    unit = "Nm" if wheel else "N"
    return RealtimeResult(summary, scaling, info.name, run.record, figure, unit,
                          knowledge.as_dict())  # fmt: skip


def _drive_by_telemetry(
    run: RealtimeRun, renderer: Any, receiver: Any, info: DeviceInfo, hand: Any
) -> Any:
    """The renderer wrapped so the game's vehicle state drives it (`carfeel.telemetry.driving`)."""
    from carfeel.telemetry import driving
    from carfeel.telemetry.cues import LeverCues
    from carfeel.telemetry.gearout import GearDriver, button_count, open_gear_output
    from carfeel.telemetry.source import VehicleSource

    steering = run.model == "steering"
    needs = driving.steering_needs if steering else driving.hpattern_needs
    if steering and run.steering_model == "physical":
        needs = driving.speed_needs  # the model's Ay is its own tyres'; the game's speed drives it
    source = VehicleSource(receiver, needs)
    vibration = driving.EngineVibration(run.rate_hz, 0.03 * info.max_force, 0.05 * info.max_force)
    gear_driver = None
    if not steering:
        layout = renderer.pattern.layout
        output = open_gear_output(run.gear_output, button_count(layout, run.gear_mapping))
        if output is not None:
            gear_driver = GearDriver(output, renderer.pattern.layout, run.gear_timing,
                                     run.gear_mapping, run.rate_hz)  # fmt: skip
    cues = (
        None
        if steering
        else LeverCues(renderer.pattern, run.rate_hz, None, run.interlock == "hold")
    )
    game_torque = None
    if steering and run.game_torque > 0.0:  # the model's torque at the device's full force
        full = info.max_force / renderer.scaling.force_scale
        recorded = getattr(receiver.source, "path", None) is not None  # a file image
        game_torque = driving.GameTorque(run.game_torque, full, receiver.torque_scale_Nm, recorded)
    return driving.TelemetryDriven(
        renderer, source, run.model, vibration, gear_driver, game_torque, cues
    )


def stability_figure(sizing: Sizing, info: DeviceInfo, rate_hz: float) -> dict[str, float]:
    """What the rendering was sized to on this device (recorded with every run)."""
    return {
        "stiffness": sizing.stiffness,
        "damping": sizing.damping,
        "damping_cap": sizing.damping_cap,
        "zeta_hands_off": sizing.zeta,
        "latency_s": sizing.latency_s,
        "passivity_index": sizing.passivity_index,
        "rate_hz": rate_hz,
    }


def _steering_scaling(
    car: Any, run: RealtimeRun, info: DeviceInfo, sizing: Sizing, notes: list[str]
) -> Scaling:
    """The torque scale: 90 % of the wheel's torque for 10 Nm, lowered where the car's on-centre
    spring at this speed would not fit the device's stiffness budget (with the friction's share)."""
    from carfeel.models.vehicle.single_track import steady_state_lateral_accel

    fs = 0.9 * info.max_force / MODEL_TORQUE_NM
    gradient = car.torque.k1_Nm_s2_m * steady_state_lateral_accel(
        run.speed_kmh / 3.6, 1.0, car.vehicle
    )  # Nm per rad of wheel angle, model units
    room = (1.0 - SteeringRendering().friction_share) * sizing.stiffness
    if gradient * fs > room:
        lowered = room / gradient
        if lowered < 0.25 * fs:
            raise InputError(
                f"{info.name} cannot render the steering at {run.speed_kmh:g} km/h stably with "
                f"{_delay_text(info)} at {run.rate_hz:g} Hz: "
                f"the car's on-centre spring ({gradient * fs:.3g} Nm/rad on the device) is "
                f"beyond the {room:.3g} Nm/rad it can hold hands off, by more than 4 times. "
                "Lower the delay, raise the rate or the speed's"
            )
        notes.append(
            f"the wheel renders {lowered / fs:.0%} of its torque scale at this speed: the "
            "car's on-centre spring at full scale would be stiffer than it can hold stably"
        )
        fs = lowered
    return Scaling(fs, 1.0)


def _physical_renderer(
    car: Any,
    preset_name: str,
    run: RealtimeRun,
    info: DeviceInfo,
    sizing: Sizing,
    telemetry: bool,
    notes: list[str],
) -> tuple[Any, Scaling, dict[str, float]]:
    """The physical steering model behind a virtual coupling sized for this device (or the
    reason it cannot be rendered stably: exit 2)."""
    from carfeel.realtime.physical_steering import (
        SPEEDS_M_S,
        PhysicalSteeringRenderer,
        felt_share,
        size_physical,
    )

    if not car.has_physical:
        raise InputError(
            f"--steering-model physical: preset {preset_name} has no [tyres] and "
            "[steering_system] tables (the shipped b-segment and d-segment have them)"
        )
    params = car.physical(run.road)
    scaling = Scaling(0.9 * info.max_force / MODEL_TORQUE_NM, 1.0)
    speed = run.speed_kmh / 3.6
    # With telemetry the game's speed moves: every speed of the grid; else the run's.
    speeds = SPEEDS_M_S if telemetry else (speed,)
    sized = size_physical(
        info, run.rate_hz, velocity_sections(run.rate_hz), params, scaling, sizing,
        run.substeps, speeds,
    )  # fmt: skip
    cannot = (
        f"{info.name} cannot render the physical steering model at {run.rate_hz:g} Hz with "
        f"{_delay_text(info)}"
    )
    if isinstance(sized, str):
        raise InputError(
            f"{cannot} stably: no coupling within its stiffness budget "
            f"({sizing.stiffness:.3g} Nm/rad) keeps the released wheel damped ({sized}). "
            "Lower the delay, raise the rate, or use --steering-model paper"
        )
    share = felt_share(params, sized, scaling, max(speed, 1.0))
    if share < MIN_FELT_SHARE:
        raise InputError(
            f"{cannot} faithfully: the stiffest coupling it holds stably "
            f"({sized.coupling_stiffness:.3g} Nm/rad) "
            f"would let through only {share:.0%} of the car's on-centre stiffness at "
            f"{run.speed_kmh:g} km/h: the wheel would feel the coupling, not the car. Lower the "
            "delay or use --steering-model paper"
        )
    if telemetry and sized.top_speed_m_s < SPEEDS_M_S[-1]:
        notes.append(
            f"the physical model is rendered up to {sized.top_speed_m_s * 3.6:.0f} km/h on "
            "this device: above, its speed is held there (the released wheel would not stay "
            "damped)"
        )
    renderer = PhysicalSteeringRenderer(params, speed, scaling, run.rate_hz, sized, info)
    figure = {
        "coupling_stiffness": sized.coupling_stiffness,
        "coupling_damping": sized.coupling_damping,
        "coupling_share": sized.share,
        "felt_stiffness_share": share,
        "rim_inertia_kg_m2": sized.rim_inertia_kg_m2,
        "added_damping_max": max(b for _, b in sized.schedule),
        "zeta_physical": min(sized.zeta),
        "top_speed_kmh": sized.top_speed_m_s * 3.6,
        "wall_stiffness": sized.wall_stiffness,
    }
    return renderer, scaling, figure


MIN_FELT_SHARE = 0.5
"""The share of the car's on-centre stiffness the coupling must let through (in series, a
coupling as stiff as the car passes half): below it the wheel feels the coupling."""


@dataclass(frozen=True, slots=True)
class Calibration:
    """`carfeel calibrate`: identify a device hands off and store its profile."""

    device: str = "virtual"
    kind: str | None = None
    """joystick or wheel; None: a virtual device's own, else joystick."""
    rate_hz: float = 1000.0
    clock: str = "wall"
    device_max_force: float | None = None
    device_travel: float | None = None
    device_delay_ms: float | None = None
    device_report_hz: float | None = None
    device_profile: Path | None = None
    seed: int = 0
    loop_cpu: int | None = None


def calibrate_device(calibration: Calibration, say: Callable[[str], None] | None = None) -> Any:
    """Identify the device (hands off, through the safety chain) and write its profile; the
    `knowledge.Knowledge` measured (its `profile` is where it was written)."""
    from carfeel.realtime.knowledge import know_device, real_max_force
    from carfeel.realtime.scheduling import claimed

    c = calibration
    kind = c.kind
    if kind is None:
        kind = "joystick"
        name, _, argument = c.device.partition(":")
        if name == "virtual" and argument:
            from carfeel.realtime.devices.virtual import PLANTS

            plant = argument.partition(":")[0]
            if plant in PLANTS:
                kind = PLANTS[plant][2]
        elif name == "virtual":
            kind = "joystick"
    if kind not in ("joystick", "wheel"):
        raise InputError(f"--kind {kind!r}: choose joystick or wheel")
    if c.device.startswith("replay"):
        raise InputError("a replayed device cannot be identified (it plays back a recording)")
    if c.clock == "simulated" and not c.device.startswith("virtual"):
        raise InputError("--clock simulated needs a virtual device; a real one lives in wall time")
    if not (MIN_RATE_HZ <= c.rate_hz <= MAX_RATE_HZ):
        raise InputError(f"--rate-hz {c.rate_hz:g}: allowed {MIN_RATE_HZ:g} .. {MAX_RATE_HZ:g}")
    virtual = c.device.startswith("virtual")
    if virtual and (c.device_max_force is not None or c.device_travel is not None):
        raise InputError(
            "--device-max-force and --device-travel describe a real device; the virtual ones "
            "have their own"
        )
    delay = None if c.device_delay_ms is None else c.device_delay_ms / 1e3
    device = open_device(c.device, None, c.seed, kind, c.device_max_force, c.device_travel,
                         delay, c.device_report_hz)  # fmt: skip
    clock: Clock = SimulatedClock() if c.clock == "simulated" else WallClock()
    with claimed(c.loop_cpu, wanted=c.clock == "wall"), device:
        if not virtual:
            device.info = replace(device.info, max_force=real_max_force(device, c.device_max_force))
        return know_device(device, clock, c.rate_hz, clock.now_ns(), "full", c.device_profile, say)
