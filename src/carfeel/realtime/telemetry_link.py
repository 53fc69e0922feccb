"""A run driven by a game (`--telemetry`): the car's presets from the car profile, the renderer
wrapped so the game's vehicle state drives it (`carfeel.telemetry.driving`), and what the
receiver saw, for the summary's notes."""

from __future__ import annotations

from typing import Any

from carfeel.realtime.devices.base import DeviceInfo
from carfeel.realtime.run_options import LEVER_MODELS, RealtimeRun


def preset_for_car(run: RealtimeRun, receiver: Any, preset_name: str) -> str:
    """The preset the car profile (`--car-presets`) gives the game's car, else `preset_name`;
    the profile's note and torque scale go on the receiver."""
    from carfeel.telemetry.carmap import profile_for_car

    profile = profile_for_car(run.car_presets, receiver)
    if profile is not None:
        preset_name = profile.presets.get(run.model) or preset_name
        receiver.notes.append(profile.describe(run.model))
        receiver.torque_scale_Nm = profile.torque_scale_Nm
    return preset_name


def drive_by_telemetry(
    run: RealtimeRun, renderer: Any, receiver: Any, info: DeviceInfo, hand: Any
) -> Any:
    """The renderer wrapped so the game's vehicle state drives it (`carfeel.telemetry.driving`)."""
    from carfeel.telemetry import driving
    from carfeel.telemetry.cues import LeverCues
    from carfeel.telemetry.gearout import GearDriver, button_count, open_gear_output
    from carfeel.telemetry.source import VehicleSource

    if run.model in LEVER_MODELS:
        return _drive_lever(run, renderer, receiver)
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


def _drive_lever(run: RealtimeRun, renderer: Any, receiver: Any) -> Any:
    """A sequential lever or a PRND selector driven by the game (`telemetry.lever_driving`)."""
    from carfeel.telemetry.gearout import GearFollower, open_gear_output
    from carfeel.telemetry.lever_driving import LeverDriven, PositionFollower, lever_needs
    from carfeel.telemetry.source import VehicleSource

    source = VehicleSource(receiver, lever_needs)
    follower: Any = None
    params = renderer.lever.params
    if run.model == "sequential":
        forward = params.forward_gears
        output = open_gear_output(run.gear_output, forward + 1)
        if output is not None:
            follower = GearFollower(output, run.gear_mapping, forward)
    else:
        output = open_gear_output(run.gear_output, len(params.positions))
        if output is not None:
            follower = PositionFollower(output, params.positions)
    return LeverDriven(renderer, source, run.model, follower)


def telemetry_notes(driven: Any) -> list[str]:
    """What the telemetry source and its receiver saw during the run, for the summary."""
    r = driven.source.receiver
    notes: list[str] = driven.source.events + r.notes
    notes.append(
        f"telemetry {r.format.name} on {r.where}: {r.packets} good packets, "
        f"{r.bad} bad, {r.ignored} "
        f"ignored{'; car ' + r.latest.car if r.latest.car else ''}"
    )
    return notes
