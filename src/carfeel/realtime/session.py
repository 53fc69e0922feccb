"""A real-time run as one call (`run_realtime`): open and know the device, build the renderer, run
the loop through the safety chain, record and summarize.

Kept apart from `loop.py` so that the loop itself imports no model, preset or file code. The
steps live beside it: `run_options` (the options and their checks), `opening` (the device),
`fitting` and `building` (the renderer sized for the device), `telemetry_link` (a game driving
it), `signals`, `report` (the sidecar and the summary) and `calibration` (`carfeel calibrate`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any, Protocol

from carfeel.errors import InputError
from carfeel.realtime.building import MODEL_FORCE_N, WEAVE_CYCLES, build, start_of
from carfeel.realtime.calibration import Calibration, calibrate_device
from carfeel.realtime.clock import Clock, SimulatedClock, WallClock
from carfeel.realtime.devices.base import Device, DeviceInfo
from carfeel.realtime.fitting import MIN_FELT_SHARE, MODEL_TORQUE_NM
from carfeel.realtime.loop import LoopConfig, LoopObserver, LoopSummary, run_loop
from carfeel.realtime.opening import (
    DEVICE_DEFAULTS,
    REAL_DELAY_S,
    REAL_DYNAMICS,
    REAL_REPORT_HZ,
    ShiftedDevice,
    declared_info,
    open_device,
)
from carfeel.realtime.recording import Recorder
from carfeel.realtime.rendering import Renderer, Scaling, velocity_sections
from carfeel.realtime.report import RealtimeResult, run_metadata, stability_figure
from carfeel.realtime.run_options import (
    DEFAULT_PRESETS,
    DEVICE_DAMPING_MAX,
    DEVICE_MASS_MAX,
    DEVICE_MASS_MIN,
    MAX_RATE_HZ,
    MIN_RATE_HZ,
    MODELS,
    RealtimeRun,
    check_run,
    device_buttons,
)
from carfeel.realtime.safety import SafetyLimits
from carfeel.realtime.signals import stop_on_signals
from carfeel.realtime.stability import Sizing
from carfeel.realtime.telemetry_link import drive_by_telemetry, preset_for_car, telemetry_notes

__all__ = [
    "DEFAULT_PRESETS",
    "DEVICE_DAMPING_MAX",
    "DEVICE_DEFAULTS",
    "DEVICE_MASS_MAX",
    "DEVICE_MASS_MIN",
    "MAX_RATE_HZ",
    "MIN_FELT_SHARE",
    "MIN_RATE_HZ",
    "MODELS",
    "MODEL_FORCE_N",
    "MODEL_TORQUE_NM",
    "REAL_DELAY_S",
    "REAL_DYNAMICS",
    "REAL_REPORT_HZ",
    "WEAVE_CYCLES",
    "Calibration",
    "LoopConfig",
    "RealtimeResult",
    "RealtimeRun",
    "RunParts",
    "SessionObserver",
    "calibrate_device",
    "open_device",
    "run_realtime",
    "stability_figure",
]
"""This module's names, and those it keeps importable from where they moved."""


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


@dataclass(slots=True)
class _Prepared:
    """A run built and checked on its device, ready for the loop."""

    parts: RunParts
    """The renderer the loop ticks (wrapped by `driven`, if a game drives it) and the rest."""
    config: LoopConfig
    driven: Any
    """The telemetry-driven renderer (`telemetry.driving.TelemetryDriven`), or None."""
    figure: dict[str, float]
    """What the rendering was sized to (`stability_figure`, with the physical coupling's)."""
    notes: list[str]
    """What the user should know of the run, for the summary."""


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
    check_run(run)
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
    """Open the device, claim the core, catch the signals and know the device; then render."""
    from carfeel.realtime.knowledge import know_device, real_max_force
    from carfeel.realtime.scheduling import claimed

    if receiver is not None:
        preset_name = preset_for_car(run, receiver, preset_name)
    device = _open_device(run, kind, delay)
    clock: Clock = SimulatedClock() if run.clock == "simulated" else WallClock()
    origin = clock.now_ns()
    # The device is opened before anything is recorded: a device that cannot be opened leaves
    # no recording behind.
    wall = run.clock == "wall"
    with claimed(run.loop_cpu, wanted=wall) as taken, stop_on_signals() as stop, device:
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
                         started_s, stop, observer)  # fmt: skip
        if wall:
            result.summary.notes.insert(0, taken.text())
        return result


def _open_device(run: RealtimeRun, kind: str, delay: float | None) -> Device:
    """The run's device, of the model's kind, with a real one's dynamics as declared. (Opened
    through this module's `open_device`, which tests and benchmarks wrap.)"""
    wheel = run.model == "steering"
    # The device first: the scales come from its limits (its hand, if virtual, comes after).
    device = open_device(
        run.device, None, run.seed, kind, run.device_max_force, run.device_travel, delay,
        run.device_report_hz, device_buttons(run),
    )  # fmt: skip
    if device.info.kind != kind or device.info.axes < (1 if wheel else 2):
        raise InputError(
            f"--model {run.model} needs a {kind} with {1 if wheel else 2} axes; "
            f"{device.info.name} is a {device.info.kind} with {device.info.axes}"
        )
    device.info = declared_info(device, run, kind)
    return device


def _render(
    run: RealtimeRun,
    announce: Callable[[], None] | None,
    receiver: Any,
    preset_name: str,
    device: Device,
    info: DeviceInfo,
    knowledge: Any,
    clock: Clock,
    started_s: float,
    stop: list[str],
    observer: SessionObserver | None,
) -> RealtimeResult:
    """Size, build and run the rendering on a known, open device (the loop starts at
    `started_s` on the device's clock, after the identification)."""
    from carfeel.realtime.knowledge import describe

    prepared = _prepare(run, receiver, preset_name, device, info, knowledge, started_s)
    summary = _run_recorded(run, prepared, device, started_s, clock, stop, announce, observer)
    notes = prepared.notes
    if prepared.driven is not None:
        notes += telemetry_notes(prepared.driven)
    summary.notes[:0] = [describe(knowledge), *knowledge.notes]
    summary.notes.extend(notes)
    unit = "Nm" if run.model == "steering" else "N"
    return RealtimeResult(summary, prepared.parts.scaling, info.name, run.record, prepared.figure,
                          unit, knowledge.as_dict())  # fmt: skip


def _prepare(
    run: RealtimeRun,
    receiver: Any,
    preset_name: str,
    device: Device,
    info: DeviceInfo,
    knowledge: Any,
    started_s: float,
) -> _Prepared:
    """Size the rendering for the device, build the model (a game driving it, a virtual hand on
    a virtual device), set the safety limits and the loop, and describe the run (its sidecar)."""
    from carfeel.realtime import stability

    start = start_of(run, knowledge.polarity, started_s)
    sizing = stability.size(info, run.rate_hz, velocity_sections(run.rate_hz))
    notes: list[str] = []
    built = build(run, preset_name, info, sizing, start, receiver is not None, notes)
    renderer: Renderer = built.renderer
    renderer.substeps = run.substeps
    virtual = run.device.startswith("virtual")
    driven = None
    if receiver is not None:
        driven = drive_by_telemetry(run, renderer, receiver, info, built.hand if virtual else None)
        renderer = driven
    if virtual and run.hand != "none":
        device.hand = built.hand  # type: ignore[attr-defined]
    duration = built.duration_s
    if run.device.startswith("replay"):
        recorded = getattr(device, "duration_s", duration)
        duration = min(duration, recorded - (start.ready_s - SafetyLimits(1.0, 1.0).ramp_s))
    limits = SafetyLimits(
        max_force=info.max_force,
        max_slew_per_s=max(info.max_force / 0.05, 200.0 * info.max_force),
    )
    figure = stability_figure(sizing, info, run.rate_hz)
    figure.update(built.physical_figure)
    metadata = run_metadata(run, preset_name, info, duration, built.scaling, limits, figure,
                            knowledge)  # fmt: skip
    columns = ("time_s", "overrun", *(f"command_{i}" for i in range(info.axes)), "fault",
               *renderer.columns)  # fmt: skip
    config = LoopConfig(
        run.rate_hz, duration, run.calibrate,
        passivity=run.passivity_controller, polarity=knowledge.polarity,
    )  # fmt: skip
    parts = RunParts(renderer, info, sizing, built.scaling, limits, columns, metadata)
    return _Prepared(parts, config, driven, figure, notes)


def _run_recorded(
    run: RealtimeRun,
    prepared: _Prepared,
    device: Device,
    started_s: float,
    clock: Clock,
    stop: list[str],
    announce: Callable[[], None] | None,
    observer: SessionObserver | None,
) -> LoopSummary:
    """Announce the run, show the observer its parts, and run the loop, recording its rows; the
    recording and the telemetry are closed whatever happens in the loop."""
    parts = prepared.parts
    summary = None
    if announce is not None:
        announce()
    if observer is not None:
        observer.prepare(parts)
    recorder = Recorder(run.record, parts.columns, parts.metadata) if run.record else None
    try:
        # The loop's times (the recording's, the renderer's) count from its start; the device
        # (and a virtual device's hand) lives on in its own time, after the identification.
        summary = run_loop(
            parts.renderer, ShiftedDevice(device, started_s), clock, prepared.config,
            parts.limits, recorder, should_stop=lambda: bool(stop), observer=observer,
        )  # fmt: skip
        if stop and summary.stopped == "stopped":
            summary.stopped = stop[0]
    finally:
        if recorder is not None:
            recorder.close(summary.as_dict() if summary else {"stopped": "error"})
        if prepared.driven is not None:
            prepared.driven.close()
    return summary
