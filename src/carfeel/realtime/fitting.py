"""Whether and how a model fits a device: the steering's torque scale, the physical steering's
coupling, and the refusals (an `InputError`, exit 2) of what the device cannot render stably."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from carfeel.errors import InputError
from carfeel.realtime.devices.base import DeviceInfo
from carfeel.realtime.rendering import Scaling, SteeringRendering, velocity_sections
from carfeel.realtime.run_options import RealtimeRun
from carfeel.realtime.stability import Sizing

if TYPE_CHECKING:
    from carfeel.realtime.physical_steering import PhysicalSizing

MODEL_TORQUE_NM = 10.0
MIN_FELT_SHARE = 0.5
"""The share of the car's on-centre stiffness the coupling must let through (in series, a
coupling as stiff as the car passes half): below it the wheel feels the coupling."""


def delay_text(info: DeviceInfo) -> str:
    """The round trip the sizing covered, as a refusal names it."""
    short, long = info.delay_range_s or (info.round_trip_s, info.round_trip_s)
    text = f"{info.round_trip_s * 1e3:.3g} ms of round-trip delay"
    if long > short:
        text += f" (sized for {short * 1e3:.3g} to {long * 1e3:.3g} ms)"
    return text


def refuse_soft(info: DeviceInfo, sizing: Sizing, run: RealtimeRun) -> None:
    """A coupling softer than the force limit over the whole travel cannot render a gearbox."""
    need = info.max_force / info.travel
    if sizing.stiffness < need:
        raise InputError(
            f"{info.name} cannot render --model {run.model} stably at {run.rate_hz:g} Hz with "
            f"{delay_text(info)} and "
            f"{info.report_hz:g} reports a second: hands off, it stays stable only up to "
            f"{sizing.stiffness:.3g} (device units per m) of coupling, and a gearbox needs at "
            f"least {need:.3g} (its force limit over its travel). Lower the delay, raise the rate "
            "or use a device with more damping"
        )


def steering_scaling(
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
                f"{delay_text(info)} at {run.rate_hz:g} Hz: "
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


def physical_renderer(
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
        f"{delay_text(info)}"
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
    return renderer, scaling, _physical_figure(sized, share)


def _physical_figure(sized: PhysicalSizing, share: float) -> dict[str, float]:
    """The coupling as sized, for the stability figure."""
    return {
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
