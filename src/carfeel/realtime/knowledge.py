"""What a run relies on about its device, and how it came to know it.

Three ways, in the order a session tries them (`know_device`):

- **identified** (`--identify auto`, the default, or `full`): the device is measured at start-up,
  hands off (`realtime.identify`), and the profile stored (`realtime.profiles`); the sizing
  takes the measured figures and their uncertainty.
- **its profile, checked** (`auto`, a profile exists): one gentle probe per axis confirms the
  stored profile in a fraction of a second; where it disagrees, the device is identified again.
- **declared** (`--identify off`, and a replayed device): what the device, the catalogue or
  the command line tells, which no real device matches: the sizing then holds over the set
  DECLARED_SET around it (inertia x0.5..2, damping x0.3..1, delay x1..2), and whatever that set
  cannot make stable is refused at start-up.

A real device (evdev, SDL2) renders only under a force limit someone declared: its own maximum,
from `--device-max-force` or its stored profile (the command is a share of the device's full
scale, so the limit means something only if the maximum is the device's).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.realtime.clock import Clock
from carfeel.realtime.devices.base import Device, DeviceInfo
from carfeel.realtime.safety import SafetyLimits

IDENTIFY_MODES = ("auto", "full", "off")
"""--identify: a stored profile checked (else identified), always identified, or neither."""
DECLARED_SET = {"mass": (0.5, 2.0), "damping": (0.3, 1.0), "delay": (1.0, 2.0)}
"""Factors of a declared (or default) inertia, damping and round trip the sizing covers."""


@dataclass
class Knowledge:
    """The device as the run knows it."""

    info: DeviceInfo
    """With the figures the sizing rests on and their ranges."""
    how: str
    """"identified", "profile" (checked), "declared" or "recorded" (a replay)."""
    polarity: tuple[float, ...] | None = None
    """Measured per axis (None: the loop's pulses find it)."""
    identification: Any = None
    """The `identify.Identification` used (measured now or stored), if any."""
    profile: Path | None = None
    notes: list[str] = field(default_factory=list)
    duration_s: float = 0.0
    """How long identifying or checking took (simulated or wall time)."""

    def as_dict(self) -> dict[str, Any]:
        """For the run's JSON and the panel: how it knows, and what it measured."""
        info = self.info
        out: dict[str, Any] = {
            "how": self.how,
            "profile": str(self.profile) if self.profile else None,
            "duration_s": self.duration_s,
            "mass": info.mass,
            "damping": info.damping,
            "stiffness": info.stiffness,
            "round_trip_s": info.round_trip_s,
            "report_hz": info.report_hz,
            "mass_range": list(info.mass_range) if info.mass_range else None,
            "damping_range": list(info.damping_range) if info.damping_range else None,
            "delay_range_s": list(info.delay_range_s) if info.delay_range_s else None,
            "max_force": info.max_force,
        }
        if self.identification is not None:
            out["identification"] = self.identification.as_dict()
        return out


def declared_set(info: DeviceInfo) -> DeviceInfo:
    """`info` with the ranges of DECLARED_SET around what it declares."""
    m, b, d = DECLARED_SET["mass"], DECLARED_SET["damping"], DECLARED_SET["delay"]
    trip = info.round_trip_s
    return replace(
        info,
        mass_range=(m[0] * info.mass, m[1] * info.mass),
        damping_range=(b[0] * info.damping, b[1] * info.damping),
        delay_range_s=(d[0] * trip, d[1] * trip),
    )


def real_max_force(device: Device, declared: float | None) -> float:
    """The force limit of a real device: the declared one, else its stored profile's; without
    either it renders nothing (InputError)."""
    if declared is not None:
        return declared
    from carfeel.realtime import profiles

    stored = profiles.find_any(device.info)
    if stored is not None:
        return stored.max_force
    raise InputError(
        f"{device.info.name}: its maximum force is not known, so no force limit would mean "
        "anything (a command is a share of the device's own full scale). Give the device's "
        "rated maximum with --device-max-force (N at a knob, Nm at a rim: 2.5 for a Logitech "
        "G29, 8 for a Fanatec CSL DD); `carfeel calibrate` stores it in the device's profile"
    )


def know_device(
    device: Device,
    clock: Clock,
    rate_hz: float,
    origin_ns: int,
    mode: str,
    profile_path: Path | None,
    say: Callable[[str], None] | None = None,
    recorded: bool = False,
) -> Knowledge:
    """Identify the open device, check its profile, or take what it declares (see the
    module); the device is left with no force on it."""
    from carfeel.realtime import identify, profiles

    info = device.info
    if recorded:
        return Knowledge(info, "recorded")
    if mode == "off":
        return Knowledge(declared_set(info), "declared")
    limits = SafetyLimits(info.max_force, max(info.max_force / 0.05, 200.0 * info.max_force))
    start = clock.now_ns()
    notes: list[str] = []
    path = profile_path or profiles.profile_path(info)
    if mode == "auto":
        stored = None
        if profile_path is not None and profile_path.is_file():
            stored = profiles.load(profile_path)
            mismatch = stored.matches(info)
            if mismatch:
                raise InputError(f"--device-profile {profile_path}: {mismatch}")
        elif profile_path is None:
            stored = profiles.find(info)
        if stored is not None:
            if say is not None:
                say(f"checking {info.name} against its profile {path}: hands off")
            checked = profiles.check(device, clock, rate_hz, origin_ns, limits, stored)
            if not checked.reason:
                known = stored.identification
                return Knowledge(
                    known.info(info, checked.shift_s, checked.gain), "profile", known.polarity,
                    known, path,
                    [f"device profile {path} (measured {stored.measured_at}) checked: its probes "
                     f"{checked.shift_s * 1e3:.2g} ms off its delay, {checked.gain:.3f} of its "
                     "reach"],
                    (clock.now_ns() - start) / 1e9,
                )  # fmt: skip
            why = checked.reason
            notes.append(f"the device differs from its profile ({why}): identified again")
            if say is not None:
                say(f"{info.name} differs from its profile ({why}): identifying it again")
    result = identify.identify(device, clock, rate_hz, origin_ns, limits, say)
    saved: Path | None = None
    try:
        saved = profiles.save(profiles.new_profile(info, result), path)
        notes.append(f"device profile written to {saved}")
    except OSError as exc:
        notes.append(f"the device profile could not be written to {path} ({exc.strerror})")
    notes += list(result.notes)
    return Knowledge(
        result.info(info), "identified", result.polarity, result, saved, notes,
        (clock.now_ns() - start) / 1e9,
    )  # fmt: skip


def describe(knowledge: Knowledge) -> str:
    """One line for the run's summary: how the device is known, and what it is."""
    info = knowledge.info
    unit = "kg m^2" if info.kind == "wheel" else "kg"
    damping_unit = "Nm*s/rad" if info.kind == "wheel" else "N*s/m"
    low, high = info.mass_range or (info.mass, info.mass)
    short, long = info.delay_range_s or (info.round_trip_s, info.round_trip_s)
    how = {
        "identified": f"identified in {knowledge.duration_s:.1f} s",
        "profile": f"known by its profile (checked in {knowledge.duration_s:.2f} s)",
        "declared": "as declared (not measured)",
        "recorded": "as recorded",
    }[knowledge.how]
    text = (
        f"device {how}: inertia {info.mass:.3g} {unit} (sized for {low:.3g}..{high:.3g}), "
        f"damping {info.damping:.3g} {damping_unit}, round trip {info.round_trip_s * 1e3:.3g} ms "
        f"(sized for {short * 1e3:.3g}..{long * 1e3:.3g}), {info.report_hz:.0f} reports/s"
    )
    if info.stiffness > 0.0:
        text += f", a centring spring of {info.stiffness:.3g}"
    if math.isfinite(info.noise) and info.noise > 0.0:
        text += f", reading noise {info.noise:.2g}"
    return text
