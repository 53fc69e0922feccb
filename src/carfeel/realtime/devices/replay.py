"""A device that plays a recording back through the loop: the positions as they were recorded.

Reads the device columns of a carfeel recording (x_device and y_device, or angle_device_rad)
and returns them at the loop's times (the sample at or before each time); commands are kept in
`commands` for comparison with the recorded ones.
"""

from __future__ import annotations

import bisect
from pathlib import Path
from types import TracebackType

from carfeel.realtime.devices.base import DeviceError, DeviceInfo, DeviceSample
from carfeel.simulation.result import Result

JOYSTICK_COLUMNS = ("x_device", "y_device")
WHEEL_COLUMNS = ("angle_device_rad",)


class ReplayDevice:
    def __init__(self, path: Path, max_force: float | None = None) -> None:
        self.path = path
        result = Result.from_csv(path, drop_partial_last_line=True)
        names = result.names
        columns: tuple[str, ...]
        if all(c in names for c in JOYSTICK_COLUMNS):
            columns, kind = JOYSTICK_COLUMNS, "joystick"
        elif all(c in names for c in WHEEL_COLUMNS):
            columns, kind = WHEEL_COLUMNS, "wheel"
        else:
            raise DeviceError(
                f"{path}: not a carfeel recording; expected the columns "
                f"{', '.join(JOYSTICK_COLUMNS)} or {', '.join(WHEEL_COLUMNS)}"
            )
        self._times = [float(t) for t in result.time_s]
        self._positions = [tuple(float(result[c][i]) for c in columns) for i in range(len(result))]
        if len(self._times) < 2:
            raise DeviceError(
                f"{path}: {len(self._times)} recorded sample(s); a replay needs at least two "
                "(record a longer run)"
            )
        # The recorded device's limits and dynamics come from the sidecar the recording was
        # written with: without them the scales of the replay would silently differ.
        meta = _sidecar(path)
        force = max_force or _number(meta, "max_force")
        travel = _number(meta, "travel")
        if force is None or travel is None:
            raise DeviceError(
                f"{path}: its sidecar {path.with_suffix('.json').name} is missing, unreadable or "
                "has no max_force and travel; a replay needs the sidecar written with the "
                "recording (copy it beside the CSV)"
            )
        # The recorded device's dynamics (for the rendering's sizing), else the virtual one's.
        from carfeel.realtime.devices.virtual import PLANTS

        plant = PLANTS["joystick" if kind == "joystick" else "wheel"][0]
        self.info = DeviceInfo(
            f"replay of {path.name}", kind, len(columns), force, travel, 1000.0, False,
            mass=_number(meta, "device_mass") or plant.mass,
            damping=_number(meta, "device_damping") or plant.damping,
            command_delay_s=_number(meta, "command_delay_s") or 0.0,
            reading_delay_s=_number(meta, "reading_delay_s") or 0.0,
            report_hz=_number(meta, "report_hz") or 1000.0,
            resolution=_number(meta, "resolution") or 0.0,
            noise=_number(meta, "noise") or 0.0,
        )  # fmt: skip
        self.info = _with_knowledge(self.info, meta)
        self.commands: list[tuple[float, tuple[float, ...]]] = []

    def __enter__(self) -> ReplayDevice:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        return None

    @property
    def duration_s(self) -> float:
        return self._times[-1] if self._times else 0.0

    def read(self, time_s: float) -> DeviceSample:
        # The sample at or before the time (a nanosecond of slack: times are shifted floats).
        i = max(0, bisect.bisect_right(self._times, time_s + 1e-9) - 1)
        return DeviceSample(time_s, self._positions[i], None)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        self.commands.append((time_s, forces))


def _sidecar(path: Path) -> dict[str, object]:
    import json

    try:
        meta = json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    return meta if isinstance(meta, dict) else {}


def _with_knowledge(info: DeviceInfo, meta: dict[str, object]) -> DeviceInfo:
    """What the recorded run knew of its device beyond its figures (the ranges its sizing
    covered, a measured spring), so that the replay sizes its rendering alike."""
    import dataclasses

    known = meta.get("device_knowledge")
    if not isinstance(known, dict):
        return info

    def pair(key: str) -> tuple[float, float] | None:
        value = known.get(key)
        if (
            isinstance(value, list) and len(value) == 2
            and all(isinstance(v, int | float) and v >= 0 for v in value)
        ):  # fmt: skip
            return float(value[0]), float(value[1])
        return None

    stiffness = known.get("stiffness")
    return dataclasses.replace(
        info,
        mass_range=pair("mass_range"),
        damping_range=pair("damping_range"),
        delay_range_s=pair("delay_range_s"),
        stiffness=float(stiffness) if isinstance(stiffness, int | float) and stiffness > 0 else 0.0,
    )


def _number(meta: dict[str, object], key: str) -> float | None:
    value = meta.get(key)
    return float(value) if isinstance(value, int | float) and value > 0 else None
