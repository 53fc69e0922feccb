"""What a run reports: the recording's sidecar (`run_metadata`), the stability figure, and the
summary as text and as JSON (`RealtimeResult`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.realtime.devices.base import DeviceInfo
from carfeel.realtime.loop import LoopSummary
from carfeel.realtime.rendering import Scaling
from carfeel.realtime.run_options import RealtimeRun, sequence_of
from carfeel.realtime.safety import SafetyLimits
from carfeel.realtime.stability import Sizing


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


def run_metadata(
    run: RealtimeRun,
    preset_name: str,
    info: DeviceInfo,
    duration_s: float,
    scaling: Scaling,
    limits: SafetyLimits,
    figure: dict[str, float],
    knowledge: Any,
) -> dict[str, Any]:
    """A recording's sidecar (and what a `SessionObserver` is shown): the run as it was built."""
    metadata: dict[str, Any] = {
        "carfeel_version": __version__,
        "model": run.model,
        "preset": preset_name,
        "mode": run.mode,
        "device": info.name,
        "device_spec": run.device,
        "rate_hz": run.rate_hz,
        "substeps": run.substeps,
        "duration_s": duration_s,
        "clock": run.clock,
        "hand": run.hand,
        "force_scale": scaling.force_scale,
        "position_scale": scaling.position_scale,
        "sequence": ",".join(sequence_of(run)) or None,
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
    if run.model == "steering":
        metadata["steering_model"] = run.steering_model
        if run.steering_model == "physical":
            metadata["road"] = run.road or "the preset's"
        else:
            metadata["aligning"] = run.aligning
    return metadata
