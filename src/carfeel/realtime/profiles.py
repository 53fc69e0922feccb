"""Device profiles: what an identification measured, stored per device, checked at each start.

A profile is a TOML file under the user's configuration folder (`profile_dir()`:
`CARFEEL_CONFIG_DIR/devices`, else the platform's, e.g. `~/.config/carfeel/devices` on Linux,
`%LOCALAPPDATA%\\carfeel\\devices` on Windows: platformdirs' local, not roaming, folder), one
per device, named after its `DeviceInfo.ident` (vendor and product ids, serial, backend path),
or a path the user names (`--device-profile`).
It holds each axis's estimates with their standard deviations, how they were measured and
when.

At a later start the profile is not trusted blindly (`check`): each axis gets one gentle probe
(a doublet sized from the profile's inertia) and the profile's model, driven by the same
commands, must predict the motion within CHECK_TOLERANCE of it; a changed polarity, delay or
inertia misses by far more. Then the device is identified again and the profile replaced.
"""

from __future__ import annotations

import datetime
import hashlib
import math
import os
import re
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.realtime.clock import Clock
from carfeel.realtime.devices.base import Device, DeviceInfo
from carfeel.realtime.identify import (
    CHECK_TOLERANCE,
    IDENTIFY_FRACTION,
    REST_S,
    WINDOW_FRACTION,
    AxisEstimate,
    Identification,
    _phase_s,
    _Session,
)
from carfeel.realtime.safety import SafetyLimits

PROFILE_VERSION = 1
MAX_PROFILE_BYTES = 64 * 1024
"""A profile is a few hundred bytes: anything larger is not one (checked before reading)."""
CHECK_PULSE_S = 0.015
CHECK_QUIET_S = 0.08
CHECK_SHIFT_TICKS = 0.3
"""A probe that answers more than this share of a tick later or sooner than the profile's
delay says the delay changed: the device is identified again (below it, the sizing takes the
shift found into its delay's range)."""
CHECK_GAIN = 0.1
"""A probe that moves more than this share farther or less far than predicted says the
inertia or the friction changed (below it, the sizing widens the inertia's range by it)."""
CHECK_GRID_TICKS = 0.125
"""The shifts tried, a share of a tick apart."""


def profile_dir() -> Path:
    """Where profiles live: `$CARFEEL_CONFIG_DIR/devices`, else the platform's user
    configuration folder for carfeel."""
    root = os.environ.get("CARFEEL_CONFIG_DIR")
    if root:
        return Path(root) / "devices"
    from platformdirs import user_config_dir

    return Path(user_config_dir("carfeel", appauthor=False)) / "devices"


def profile_path(info: DeviceInfo) -> Path:
    """The default profile file of a device: a readable slug of its identity and a hash of
    the whole (two devices of one model differ by serial or path)."""
    ident = info.ident or info.name
    slug = re.sub(r"[^A-Za-z0-9]+", "-", ident).strip("-")[:60] or "device"
    digest = hashlib.sha256(ident.encode("utf-8")).hexdigest()[:10]
    return profile_dir() / f"{slug}-{digest}.toml"


@dataclass(frozen=True, slots=True)
class DeviceProfile:
    """A device's stored identification."""

    ident: str
    name: str
    kind: str
    axes: int
    max_force: float
    """The force limit the identification ran under (device units)."""
    travel: float
    identification: Identification
    measured_at: str
    """ISO 8601, UTC."""
    carfeel_version: str = __version__

    def matches(self, info: DeviceInfo) -> str:
        """Empty when the profile is of this device; else why not."""
        for name, mine, theirs in (
            ("device", self.ident, info.ident or info.name),
            ("kind", self.kind, info.kind),
            ("axes", self.axes, info.axes),
        ):
            if mine != theirs:
                return f"the profile is of {name} {mine!r}, the device is {theirs!r}"
        if not math.isclose(self.max_force, info.max_force, rel_tol=1e-9):
            return (
                f"the profile was measured with a force limit of {self.max_force:g}, the device "
                f"now has {info.max_force:g}"
            )
        return ""

    def as_toml(self) -> dict[str, Any]:
        ident = self.identification
        return {
            "profile_version": PROFILE_VERSION,
            "carfeel_version": self.carfeel_version,
            "measured_at": self.measured_at,
            "device": {
                "ident": self.ident,
                "name": self.name,
                "kind": self.kind,
                "axes": self.axes,
                "max_force": self.max_force,
                "travel": self.travel,
            },
            "identification": {
                "rate_hz": ident.rate_hz,
                "duration_s": ident.duration_s,
                "peak_force": ident.peak_force,
                "notes": list(ident.notes),
            },
            "axis": [a.as_dict() for a in ident.axes],
        }


def new_profile(info: DeviceInfo, identification: Identification) -> DeviceProfile:
    return DeviceProfile(
        info.ident or info.name, info.name, info.kind, info.axes, info.max_force, info.travel,
        identification, datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
    )  # fmt: skip


def save(profile: DeviceProfile, path: Path | None = None) -> Path:
    """Write the profile (to `path`, or its device's default), whole or not at all."""
    import tomli_w

    target = path or profile_dir() / profile_path_name(profile)
    target.parent.mkdir(parents=True, exist_ok=True)
    staged = target.with_name(target.name + ".part")
    staged.write_text(tomli_w.dumps(profile.as_toml()), encoding="utf-8")
    os.replace(staged, target)
    return target


def profile_path_name(profile: DeviceProfile) -> str:
    info = DeviceInfo(profile.name, profile.kind, profile.axes, profile.max_force,
                      profile.travel, 1000.0, False, ident=profile.ident)  # fmt: skip
    return profile_path(info).name


def load(path: Path) -> DeviceProfile:
    """Read and check a profile; a bad one raises InputError naming the file and what is
    wrong (delete it, or give another with --device-profile)."""
    where = f"device profile {path}"
    try:
        size = path.stat().st_size
    except OSError as exc:
        raise InputError(f"{where}: cannot be read ({exc.strerror})") from None
    if size > MAX_PROFILE_BYTES:
        raise InputError(f"{where}: {size} bytes, more than a profile's {MAX_PROFILE_BYTES}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(
            f"{where}: not a readable TOML file ({exc}); delete it to measure the device again"
        ) from None
    try:
        return _from_toml(data)
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(
            f"{where}: {exc}; delete it (or run `carfeel calibrate`) to measure the device again"
        ) from None


def _number(table: dict[str, Any], key: str, low: float, high: float) -> float:
    if key not in table:
        raise KeyError(f"{key} is missing")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise TypeError(f"{key} = {value!r} is not a number")
    if not (math.isfinite(value) and low <= value <= high):
        raise ValueError(f"{key} = {value!r}: allowed {low:g} <= value <= {high:g}")
    return float(value)


def _text(table: dict[str, Any], key: str, longest: int = 500) -> str:
    value = table.get(key)
    if not isinstance(value, str) or len(value) > longest:
        raise TypeError(f"{key} must be text of at most {longest} characters")
    return value


ESTIMATE_RANGES = {
    "polarity": (-1.0, 1.0), "mass": (1e-9, 1e3), "mass_sigma": (0.0, 1e6),
    "damping": (-1e6, 1e6), "damping_sigma": (0.0, 1e9), "friction": (-1e6, 1e6),
    "friction_sigma": (0.0, 1e9), "stiffness": (-1e9, 1e9), "stiffness_sigma": (0.0, 1e12),
    "round_trip_s": (0.0, 1.0), "round_trip_sigma_s": (0.0, 1.0), "report_hz": (1.0, 1e6),
    "noise": (0.0, 1e3), "r2": (-1e9, 1.0),
}  # fmt: skip


def _from_toml(data: dict[str, Any]) -> DeviceProfile:
    version = data.get("profile_version")
    if version != PROFILE_VERSION:
        raise ValueError(f"profile_version {version!r}: this carfeel reads {PROFILE_VERSION}")
    device = data.get("device")
    ident = data.get("identification")
    axes_data = data.get("axis")
    if not isinstance(device, dict) or not isinstance(ident, dict):
        raise KeyError("the [device] and [identification] tables are missing")
    axes = int(_number(device, "axes", 1, 8))
    if not isinstance(axes_data, list) or len(axes_data) != axes:
        raise ValueError(f"[[axis]] must hold one table per axis ({axes})")
    estimates = []
    for table in axes_data:
        if not isinstance(table, dict):
            raise TypeError("each [[axis]] must be a table")
        values = {f.name: _number(table, f.name, *ESTIMATE_RANGES[f.name])
                  for f in fields(AxisEstimate)}  # fmt: skip
        if abs(values["polarity"]) != 1.0:
            raise ValueError(f"polarity = {values['polarity']:g}: +1 or -1")
        estimates.append(AxisEstimate(**values))
    notes = ident.get("notes", [])
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise TypeError("identification.notes must be a list of text")
    max_force = _number(device, "max_force", 1e-9, 1e4)
    identification = Identification(
        tuple(estimates), _number(ident, "rate_hz", 1.0, 1e5),
        _number(ident, "duration_s", 0.0, 1e4), _number(ident, "peak_force", 0.0, 1e4),
        max_force, tuple(notes[:20]),
    )  # fmt: skip
    return DeviceProfile(
        _text(device, "ident"), _text(device, "name"), _text(device, "kind", 20), axes,
        max_force, _number(device, "travel", 1e-9, 1e3), identification,
        _text(data, "measured_at", 40), _text(data, "carfeel_version", 40),
    )  # fmt: skip


def find(info: DeviceInfo) -> DeviceProfile | None:
    """The stored profile of this device under its force limit, or None (none, or a bad or
    foreign file, which is left alone: a new identification replaces it)."""
    profile = find_any(info)
    return profile if profile is not None and not profile.matches(info) else None


def find_any(info: DeviceInfo) -> DeviceProfile | None:
    """The stored profile of this device, whatever force limit it was measured under."""
    path = profile_path(info)
    if not path.is_file():
        return None
    try:
        profile = load(path)
    except InputError:
        return None
    if profile.ident != (info.ident or info.name) or profile.kind != info.kind:
        return None
    return profile


# ------------------------------------------------------------------ the check at start-up


@dataclass(frozen=True, slots=True)
class Check:
    """What a start-up check found: why the profile no longer holds (empty: it holds), and
    the largest timing shift and the reach (gain) furthest from 1 of its probes."""

    reason: str
    shift_s: float = 0.0
    gain: float = 1.0


def check(
    device: Device,
    clock: Clock,
    rate_hz: float,
    origin_ns: int,
    limits: SafetyLimits,
    profile: DeviceProfile,
) -> Check:
    """Probe each axis (hands off, through the safety chain: a doublet out, its mirror back)
    and compare its motion with what the profile's model predicts for the same commands."""
    info = device.info
    session = _Session(device, clock, rate_hz, origin_ns, limits)
    reasons = []
    shift, gain = 0.0, 1.0
    try:
        session.tick((0.0,) * info.axes)
        for axis, estimate in enumerate(profile.identification.axes):
            session.resume()  # the comparison of the axis before took time: no stall
            for _ in range(round(0.5 * REST_S * rate_hz)):
                session.tick((0.0,) * info.axes)
            if session.faulted():
                break
            window = WINDOW_FRACTION * info.travel
            force = min(
                IDENTIFY_FRACTION * info.max_force,
                estimate.mass * 0.5 * window / CHECK_PULSE_S**2,
            )
            sent: list[float] = []
            moved: list[float] = []
            start = session.positions[axis]
            # Out and back: a doublet, then its mirror, so the axis ends near where it began.
            for push, duration in ((force, CHECK_PULSE_S), (-force, CHECK_PULSE_S),
                                   (0.0, CHECK_QUIET_S), (-force, CHECK_PULSE_S),
                                   (force, CHECK_PULSE_S), (0.0, CHECK_QUIET_S)):  # fmt: skip
                for _ in range(round(duration * rate_hz)):
                    forces = [0.0] * info.axes
                    forces[axis] = push * estimate.polarity
                    out, positions = session.tick(tuple(forces))
                    sent.append(out[axis] * estimate.polarity)
                    moved.append(positions[axis] - start)
            if session.faulted():
                break
            why, found_shift, found_gain = compare(estimate, sent, moved, rate_hz)
            if why:
                reasons.append(f"axis {axis} {why}")
            shift = max(shift, abs(found_shift))
            gain = found_gain if abs(found_gain - 1.0) > abs(gain - 1.0) else gain
    finally:
        session.fade()
    if session.faulted():
        reasons.append(f"the check stopped: {session.watchdog.faults[0]}")
    return Check("; ".join(reasons), shift, gain)


def compare(
    estimate: AxisEstimate, forces: list[float], moved: list[float], rate_hz: float
) -> tuple[str, float, float]:
    """(why not, shift, gain): a probe's motion against the profile's prediction shifted in
    time by the least-squares best shift (on a grid of CHECK_GRID_TICKS) and scaled by the best
    gain. It holds when it matches within CHECK_TOLERANCE of its largest excursion with a shift
    within a report period and CHECK_SHIFT_TICKS of a tick (or three of the delay's sigmas),
    and a gain within
    CHECK_GAIN of 1."""
    period = 1.0 / rate_hz
    peak = max(abs(m) for m in moved) or 1e-12
    best: tuple[float, float, float, float] | None = None  # (squares, shift, gain, misfit)
    step = CHECK_GRID_TICKS * period
    for i in range(round(-4.0 / CHECK_GRID_TICKS), round(6.0 / CHECK_GRID_TICKS) + 1):
        shift = i * step
        trial = replace_delay(estimate, estimate.round_trip_s + shift)
        predicted = predict(trial, forces, rate_hz)
        energy = sum(p * p for p in predicted) or 1e-30
        gain = sum(m * p for m, p in zip(moved, predicted, strict=True)) / energy
        errors = [m - gain * p for m, p in zip(moved, predicted, strict=True)]
        squares = sum(e * e for e in errors)
        if best is None or squares < best[0]:
            best = (squares, shift, gain, max(abs(e) for e in errors))
    assert best is not None
    _, shift, gain, misfit = best
    if gain < 0.0:
        return "moved against its profile's polarity (the device's force is reversed)", shift, gain
    # The reports' phase moves between runs (a device's clock is not the host's): a shift
    # within a report period is the same device.
    allowed = max(
        CHECK_SHIFT_TICKS * period + _phase_s(estimate.report_hz, rate_hz),
        3.0 * estimate.round_trip_sigma_s,
    )
    if abs(shift) > allowed:
        return (
            f"answered {abs(shift) * 1e3:.2g} ms {'later' if shift > 0 else 'sooner'} than its "
            f"profile (its delay changed; at most {allowed * 1e3:.2g} ms)",
            shift,
            gain,
        )
    if abs(gain - 1.0) > CHECK_GAIN:
        return (
            f"moved {gain:.2f} times as far as its profile predicts (its inertia or friction "
            f"changed; at most {CHECK_GAIN:.0%} off)",
            shift,
            gain,
        )
    if misfit > CHECK_TOLERANCE * peak:
        return (
            f"moved unlike its profile predicts ({misfit / peak:.0%} of its motion; at most "
            f"{CHECK_TOLERANCE:.0%})",
            shift,
            gain,
        )
    return "", shift, gain


def replace_delay(estimate: AxisEstimate, round_trip_s: float) -> AxisEstimate:
    import dataclasses

    return dataclasses.replace(estimate, round_trip_s=max(0.0, round_trip_s))


def predict(estimate: AxisEstimate, forces: list[float], rate_hz: float) -> list[float]:
    """The displacement the profile's model of an axis makes under these commands (one per
    tick, from rest), as its readings would show it: its delay, inertia, damping, friction and
    spring, integrated at a tenth of a tick."""
    period = 1.0 / rate_hz
    h = period / 10.0
    m = estimate.mass
    b = max(0.0, estimate.damping)
    k = max(0.0, estimate.stiffness)
    friction = max(0.0, estimate.friction)
    # The round trip, and on average half a report's hold where reports are slower than ticks.
    delay = estimate.round_trip_s + max(0.0, 0.5 / estimate.report_hz - 0.5 * period)
    grip = h * friction / m / (1.0 + h * b / m)
    x = v = 0.0
    out = []
    steps = 0
    for tick in range(len(forces)):
        # The reading at this tick shows the axis `delay` ago.
        until = tick * period - delay
        while steps * h < until:
            t = steps * h
            index = math.floor(t / period - 1e-9)  # the command acting then
            u = forces[index] if 0 <= index < len(forces) else 0.0
            v = (v + h * (u - k * x) / m) / (1.0 + h * b / m)
            v = 0.0 if abs(v) <= grip else v - math.copysign(grip, v)
            x += h * v
            steps += 1
        out.append(x)
    return out
