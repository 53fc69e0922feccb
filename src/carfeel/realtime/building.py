"""A run's model built for its device: the renderer sized for it, the virtual hand that drives
it (on a virtual device) and the run's length, for each of the shift, the H-pattern and the
steering wheel."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from carfeel.errors import InputError
from carfeel.realtime.devices.base import DeviceInfo
from carfeel.realtime.fitting import physical_renderer, refuse_soft, steering_scaling
from carfeel.realtime.loop import CALIBRATION_PULSE_S, CALIBRATION_SETTLE_S
from carfeel.realtime.rendering import (
    Gains,
    HPatternRenderer,
    Renderer,
    Scaling,
    ShiftRenderer,
    SteeringRenderer,
    SteeringRendering,
    default_scaling,
    ring_wall,
)
from carfeel.realtime.run_options import LEVER_MODELS, RealtimeRun, sequence_of
from carfeel.realtime.safety import SafetyLimits
from carfeel.realtime.stability import Sizing

MODEL_FORCE_N = 100.0
"""The lever forces the shift models reach (the paper's 8-10 kgf), scaled onto the device."""
WEAVE_CYCLES = 2
"""The virtual hands' weave on a wheel (0.2 Hz, 15 deg), then they hold it at centre."""


@dataclass(frozen=True, slots=True)
class Start:
    """When the virtual hand may start, from the loop's start: it waits for the calibration
    pulses (none where the polarity was measured) and the ramp-in."""

    loop_s: float
    """The loop's start on the device's clock (after the identification)."""
    calibration_s: float
    ready_s: float


def start_of(run: RealtimeRun, polarity: Any, loop_s: float) -> Start:
    """The hand's `Start` for a run whose device's polarity is `polarity` (None: unmeasured)."""
    pulses = run.calibrate and polarity is None
    calibration_s = 2 * (CALIBRATION_PULSE_S + CALIBRATION_SETTLE_S) if pulses else 0.0
    ready_s = calibration_s + SafetyLimits(1.0, 1.0).ramp_s if run.calibrate else 0.0
    return Start(loop_s, calibration_s, ready_s)


@dataclass(slots=True)
class Built:
    """A model's renderer on the device, the virtual hand for it and the run's length."""

    renderer: Renderer
    scaling: Scaling
    hand: Any
    duration_s: float
    physical_figure: dict[str, float] = field(default_factory=dict)
    """The physical steering's coupling as sized (`fitting.physical_renderer`), else empty."""


def build(
    run: RealtimeRun,
    preset_name: str,
    info: DeviceInfo,
    sizing: Sizing,
    start: Start,
    telemetry: bool,
    notes: list[str],
) -> Built:
    """The run's model built for a known device (or the reason it cannot be: exit 2); `notes`
    gathers what the user should know of it."""
    if run.model == "shift":
        return _build_shift(run, preset_name, info, sizing, start)
    if run.model == "hpattern":
        return _build_hpattern(run, preset_name, info, sizing, start)
    if run.model in LEVER_MODELS:
        return _build_lever(run, preset_name, info, sizing, start)
    return _build_steering(run, preset_name, info, sizing, start, telemetry, notes)


def _build_shift(
    run: RealtimeRun, preset_name: str, info: DeviceInfo, sizing: Sizing, start: Start
) -> Built:
    """The single shift (`ShiftRenderer`), the preset's driver pushing it."""
    from carfeel.io.presets import load_shift
    from carfeel.realtime import hands

    t0, ready_s = start.loop_s, start.ready_s
    refuse_soft(info, sizing, run)
    shift = load_shift(preset_name).params
    scaling = default_scaling(MODEL_FORCE_N, shift.gearbox.in_gear_position_m + 0.005, info)
    hand: Any = hands.ShiftHand(shift.driver, scaling.force_scale, scaling.position_scale,
                                t0 + ready_s)  # fmt: skip
    if run.hand == "release":
        pushing = hand
        # Lets go once the driver has pushed the lever home and relaxed its push.
        hand = hands.ReleasingHand(
            pushing,
            lambda t: pushing.state.phase.value == "release" and pushing.state.activation < 0.05,
        )
    # The ring blocks only while the hand pushes: sized for the preset's hand on it.
    wall = ring_wall(info, run.rate_hz, scaling, shift.driver)
    renderer = ShiftRenderer(shift.gearbox, run.mode, scaling, run.rate_hz,
                             Gains.sized(sizing, scaling), seed=run.seed,
                             wall=wall)  # fmt: skip
    return Built(renderer, scaling, hand, run.duration_s or 2.0 + ready_s)


def _build_hpattern(
    run: RealtimeRun, preset_name: str, info: DeviceInfo, sizing: Sizing, start: Start
) -> Built:
    """The H-pattern (`HPatternRenderer`), the scripted driver shifting through `run.sequence`."""
    from carfeel.io.presets import load_hpattern
    from carfeel.models.drivers.hpattern import Script
    from carfeel.realtime import hands

    t0, ready_s = start.loop_s, start.ready_s
    virtual = run.device.startswith("virtual")
    refuse_soft(info, sizing, run)
    preset = load_hpattern(preset_name)
    layout = preset.setup.layout
    names = {*layout.gear_names(), "N"}
    sequence = sequence_of(run)
    unknown = [g for g in sequence if g not in names]
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
    script = Script(sequence, layout, preset.shift.driver, preset.setup.driver,
                    outer_push_m=reach)  # fmt: skip
    hand: Any = hands.HPatternHand(script, scaling.force_scale, scaling.position_scale,
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
    return Built(renderer, scaling, hand, run.duration_s or 1.2 * len(sequence) + 1.0 + ready_s)


LEVER_FORCE_SHARE = 1.5
"""A lever's model force (what 90 % of the device's force renders) over its preset's hand: the
hand's push and the mechanism's peaks it meets fit, with room for a firmer hand."""


def _build_lever(
    run: RealtimeRun, preset_name: str, info: DeviceInfo, sizing: Sizing, start: Start
) -> Built:
    """The sequential lever or the PRND selector (`levers.LeverRenderer`), the preset's driver
    making `run.sequence`'s moves; the position scale leaves room for the coupling's stretch."""
    from carfeel.realtime import hands, levers

    refuse_soft(info, sizing, run)
    params, driver = lever_preset(run.model, preset_name)
    lever = levers.lever_for(run.model, params)
    try:
        scaling = levers.lever_scaling(lever, driver.hand_N, LEVER_FORCE_SHARE * driver.hand_N,
                                       info, sizing)  # fmt: skip
    except ValueError as exc:
        raise InputError(f"{info.name} cannot hold the {run.model} lever: {exc}") from None
    gains = Gains.sized(sizing, scaling)
    controls = levers.Controls()
    renderer = levers.LeverRenderer(lever, scaling, run.rate_hz, gains, controls)
    renderer.buttons = tuple(control for control, _ in run.lever_buttons)
    moves = lever_moves(run.model, params, sequence_of(run))
    hand: Any = levers.LeverHand(
        moves, driver.hand_N, driver.hold_s, driver.rest_s, scaling.force_scale,
        scaling.position_scale, controls, start.loop_s + start.ready_s,
        registered=lambda: renderer.gear, order=getattr(params, "positions", ()),
    )  # fmt: skip
    if run.hand == "release":
        scripted = hand
        hand = hands.ReleasingHand(scripted, lambda t: scripted.done)
    length = len(moves) * (driver.hold_s + driver.rest_s) + 1.0 + start.ready_s
    return Built(renderer, scaling, hand, run.duration_s or length)


def lever_preset(model: str, preset_name: str) -> tuple[Any, Any]:
    """A lever preset's (model parameters, scripted driver): the sequential lever's or the
    PRND selector's."""
    from carfeel.io.presets import load_prnd, load_sequential

    if model == "sequential":
        sequential = load_sequential(preset_name).params
        return sequential.lever, sequential.driver
    prnd = load_prnd(preset_name).params
    return prnd.selector, prnd.driver


def lever_moves(model: str, params: Any, sequence: tuple[str, ...]) -> tuple[Any, ...]:
    """`--sequence` for a lever: the sequential's moves (up, down, lift-down, lift-up) or the
    PRND's target positions (P, R, N, D ...), as `simulate sequential` / `simulate prnd`
    read them; InputError naming a bad one."""
    from carfeel.realtime import levers
    from carfeel.simulation import prnd, sequential

    text = ",".join(sequence)
    try:
        if model == "sequential":
            return levers.sequential_moves(params, sequential.parse_moves(text.lower()))
        return levers.prnd_moves(params, prnd.parse_moves(text.upper(), params.positions))
    except InputError as exc:
        raise InputError(str(exc).replace("--moves", "--sequence", 1)) from None


def _build_steering(
    run: RealtimeRun,
    preset_name: str,
    info: DeviceInfo,
    sizing: Sizing,
    start: Start,
    telemetry: bool,
    notes: list[str],
) -> Built:
    """The steering wheel: the paper's torque law (`SteeringRenderer`) or the physical model
    behind a virtual coupling; the hands weave it, or hold it turned and let go."""
    from carfeel.io.presets import load_steering
    from carfeel.realtime import hands

    t0, calibration_s, ready_s = start.loop_s, start.calibration_s, start.ready_s
    car = load_steering(preset_name).params
    hand: Any
    if run.hand == "release":
        hand = hands.holding_wheel(
            math.radians(run.release_angle_deg), t0 + calibration_s,
            1.0 + ready_s - calibration_s,
        )  # fmt: skip
    else:
        weave = hands.weave_target(math.radians(15.0), 0.2, t0 + ready_s, WEAVE_CYCLES)
        hand = hands.WheelHand(weave, start_s=t0 + calibration_s)
    duration = run.duration_s or ready_s + WEAVE_CYCLES / 0.2 + 2.0
    if run.steering_model == "physical":
        renderer, scaling, physical_figure = physical_renderer(
            car, preset_name, run, info, sizing, telemetry, notes
        )
        return Built(renderer, scaling, hand, duration, physical_figure)
    scaling = steering_scaling(car, run, info, sizing, notes)
    renderer = SteeringRenderer(car, run.speed_kmh / 3.6, scaling, run.rate_hz, sizing,
                                info, SteeringRendering(aligning=run.aligning))  # fmt: skip
    return Built(renderer, scaling, hand, duration)
