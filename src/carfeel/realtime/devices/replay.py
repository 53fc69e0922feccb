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
    def __init__(self, path: Path, max_force: float = 10.0) -> None:
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
        travel = max((abs(v) for row in self._positions for v in row), default=0.0) or 1.0
        self.info = DeviceInfo(
            f"replay of {path.name}", kind, len(columns), max_force, 1.5 * travel, 1000.0, False
        )
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
        i = max(0, bisect.bisect_right(self._times, time_s) - 1)
        return DeviceSample(time_s, self._positions[i], None)

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        self.commands.append((time_s, forces))
