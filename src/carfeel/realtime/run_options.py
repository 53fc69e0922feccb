"""A `carfeel run`'s options (`RealtimeRun`) and their checks, before anything is opened.

Each refusal is an `InputError` naming the flag and what it allows (exit 2).
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from pathlib import Path

from carfeel.errors import InputError
from carfeel.realtime.hands import HANDS
from carfeel.realtime.rendering import ALIGNING, MODES

MODELS = ("shift", "hpattern", "sequential", "prnd", "steering")
LEVER_MODELS = ("sequential", "prnd")
"""The one-axis levers (`realtime.levers`): the sequential lever and the PRND selector."""
DEFAULT_PRESETS = {"shift": "paper-first-gear", "hpattern": "5r", "sequential": "rally-6",
                   "prnd": "automatic", "steering": "b-segment"}  # fmt: skip
DEFAULT_SEQUENCES = {
    "hpattern": ("N", "1", "2", "3", "4", "5", "4", "3", "2", "1", "N"),
    # Up to 2 and back; a down without the lift (locked: the wall), then N, R and a down past R
    # (locked), and back up to 1.
    "sequential": ("up", "up", "down", "down", "lift-down", "lift-down", "lift-down", "lift-up",
                   "up"),
    "prnd": ("R", "N", "D", "N", "R", "P"),
}  # fmt: skip
"""The virtual hand's script per model (`--sequence`): gears, a sequential lever's moves, a
PRND's target positions."""
LEVER_BUTTONS = {"sequential": ("lift",), "prnd": ("button", "brake")}
"""The controls of each lever a real device's buttons may press (`--lever-buttons`): the
sequential knob's lift; the selector's lock button and the brake pedal."""
MAX_RATE_HZ = 10_000.0
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
    sequence: tuple[str, ...] | None = None
    """The virtual hand's script: the model's (`DEFAULT_SEQUENCES`) where None."""
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
    lever_buttons: tuple[tuple[str, str], ...] = ()
    """A real device's buttons pressing a lever's controls, (control, button) each: the
    control one of LEVER_BUTTONS[model], the button an evdev name or code (BTN_TRIGGER, 288) or
    an SDL button index (0, 1, ...)."""


def check_run(run: RealtimeRun) -> None:
    """Refuse a run whose options do not hold together (an `InputError`, exit 2), each
    check in turn: the first one failing names its flag."""
    _check_model_and_rate(run)
    _check_device_and_hand(run)
    _check_steering_model(run)
    _check_device_dynamics(run)
    _check_steps(run)
    _check_telemetry(run)
    _check_identify(run)
    _check_loop_and_clock(run)
    _check_lever_script(run)
    _check_lever_buttons(run)


def _check_model_and_rate(run: RealtimeRun) -> None:
    """The model, its rendering mode, the loop's rate and the car's speed."""
    if run.model not in MODELS:
        raise InputError(f"--model {run.model!r}: choose one of {', '.join(MODELS)}")
    if run.mode not in MODES:
        raise InputError(f"--mode {run.mode!r}: choose one of {', '.join(MODES)}")
    if run.model == "steering" and run.mode != "impedance":
        raise InputError(
            "--model steering renders the torque law straight onto a force-feedback wheel: "
            "use --mode impedance"
        )
    if run.model in LEVER_MODELS and run.mode != "impedance":
        raise InputError(
            f"--model {run.model} renders its lever behind the virtual coupling only: use "
            "--mode impedance"
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


def _check_device_and_hand(run: RealtimeRun) -> None:
    """A real device's declared limits, the synchronizer, the hand and the aligning torque."""
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


def _check_device_dynamics(run: RealtimeRun) -> None:
    """The device's delay, report rate and declared dynamics; the release angle."""
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


def _check_steps(run: RealtimeRun) -> None:
    """The model's steps per tick and the run's duration."""
    if run.substeps < 1 or run.rate_hz * run.substeps > MAX_RATE_HZ:
        raise InputError(
            f"--substeps {run.substeps}: the model may step at most {MAX_RATE_HZ:g} times a "
            f"second: at --rate-hz {run.rate_hz:g}, allowed 1 .. "
            f"{max(1, int(MAX_RATE_HZ // run.rate_hz))}"
        )
    if run.duration_s is not None and not 0.0 < run.duration_s <= 3600.0:
        raise InputError(f"--duration {run.duration_s:g}: allowed 0 < value <= 3600 s")


def _check_identify(run: RealtimeRun) -> None:
    """How the device is known, and its profile."""
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


def _check_loop_and_clock(run: RealtimeRun) -> None:
    """The core the loop is pinned to, and the clock."""
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
    if run.gear_output != "none" and run.model not in ("hpattern", *LEVER_MODELS):
        raise InputError(
            "--gear-output needs --model hpattern, sequential or prnd (the lever's gear or "
            "position is what the game is told)"
        )
    if run.model == "prnd" and run.gear_mapping != "buttons":
        raise InputError(
            f"--gear-mapping {run.gear_mapping}: a PRND selector holds one button per position "
            "(P, R, N, D ...): use buttons"
        )
    if run.model == "sequential" and run.gear_mapping == "range-splitter":
        raise InputError(
            "--gear-mapping range-splitter is a truck's: a sequential lever tells buttons (one a "
            "gear) or sequential (up and down pulses)"
        )
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
        if run.model == "shift":
            raise InputError(
                "--telemetry drives --model hpattern, sequential, prnd or steering (the single "
                "shift has no gears to take from a game)"
            )


def sequence_of(run: RealtimeRun) -> tuple[str, ...]:
    """The run's script: its own, or its model's default (none for shift and steering)."""
    if run.sequence is not None:
        return run.sequence
    return DEFAULT_SEQUENCES.get(run.model, ())


def parse_lever_buttons(text: str) -> tuple[tuple[str, str], ...]:
    """`lift=BTN_TRIGGER` or `button=0,brake=1` as (control, button) pairs; InputError on
    anything else (the controls and buttons are checked against the run by check_run)."""
    pairs = []
    for part in text.split(","):
        control, sep, button = (p.strip() for p in part.partition("="))
        if not sep or not control or not button:
            raise InputError(
                f"--lever-buttons {text!r}: expected CONTROL=BUTTON pairs separated by commas, "
                "e.g. lift=BTN_TRIGGER (evdev) or button=0,brake=1 (SDL)"
            )
        pairs.append((control, button))
    return tuple(pairs)


def _check_lever_buttons(run: RealtimeRun) -> None:
    """--lever-buttons: a lever's controls, each once, from a real evdev or SDL device's
    buttons (a virtual device's hand presses them itself)."""
    if not run.lever_buttons:
        return
    if run.model not in LEVER_MODELS:
        raise InputError(
            f"--lever-buttons presses a lever's controls (--model {' or '.join(LEVER_MODELS)}); "
            f"--model {run.model} has none"
        )
    allowed = LEVER_BUTTONS[run.model]
    controls = [c for c, _ in run.lever_buttons]
    for control in controls:
        if control not in allowed:
            raise InputError(
                f"--lever-buttons {control}=...: the {run.model} lever's controls are "
                f"{', '.join(allowed)}"
            )
    if len(set(controls)) != len(controls):
        raise InputError(f"--lever-buttons names a control twice: {', '.join(controls)}")
    backend = run.device.partition(":")[0]
    if backend not in ("evdev", "sdl"):
        raise InputError(
            f"--lever-buttons reads a real device's buttons (evdev:PATH or sdl:INDEX); "
            f"--device {run.device}'s virtual hand presses the controls itself"
        )
    for control, button in run.lever_buttons:
        if backend == "sdl" and not button.isdigit():
            raise InputError(
                f"--lever-buttons {control}={button}: SDL numbers a joystick's buttons 0, 1, ... "
                "(`carfeel devices` shows how many it has)"
            )
        if backend == "evdev" and not (button.isdigit() or button.replace("_", "").isalnum()):
            raise InputError(
                f"--lever-buttons {control}={button}: expected an EV_KEY name (BTN_TRIGGER) or "
                "its number"
            )


def device_buttons(run: RealtimeRun) -> tuple[int | str, ...]:
    """The buttons the run asks its device for, in the order of `run.lever_buttons` (numbers
    as ints, names as the backend's)."""
    return tuple(int(b) if b.isdigit() else b for _, b in run.lever_buttons)


def _check_lever_script(run: RealtimeRun) -> None:
    """A lever's --sequence read against its preset (its moves, or the selector's positions)
    before any device is opened."""
    if run.model not in LEVER_MODELS or run.sequence is None:
        return
    from carfeel.realtime.building import lever_moves, lever_preset

    params, _ = lever_preset(run.model, run.preset or DEFAULT_PRESETS[run.model])
    lever_moves(run.model, params, run.sequence)
