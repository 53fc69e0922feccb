"""The protocol every device follows, used as a context manager.

    with open_device("virtual") as device:
        sample = device.read(t_s)           # positions (and a force estimate if it has one)
        device.command((force_x, ...), t_s) # force (N) or torque (Nm) per axis, device units

Units are the device's own, in SI: positions in m (joystick handle at the knob) or rad (wheel),
forces in N or torques in Nm. Signs: a positive command pushes toward positive positions.
A device that fails (unplugged, an I/O error) raises DeviceLost from read or command; the loop
then fades the force to zero and stops.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import TracebackType
from typing import Protocol

from carfeel.contracts import DeviceSample as DeviceSample  # where the devices take it from
from carfeel.errors import CarfeelError


class DeviceError(CarfeelError, RuntimeError):
    """A device cannot be opened, or a backend library is missing."""


class DeviceLost(DeviceError):
    """A device stopped answering during a run."""


@dataclass(frozen=True, slots=True)
class DeviceInfo:
    name: str
    kind: str
    """"joystick" (axes in m, forces in N) or "wheel" (one axis in rad, torque in Nm)."""
    axes: int
    max_force: float
    """Largest force (N) or torque (Nm) per axis the device can render."""
    travel: float
    """Half-range of each axis from centre, m or rad."""
    update_hz: float
    """Fastest rate at which the device takes new force commands."""
    measures_force: bool
    """Whether `read` returns a force estimate (the paper's admittance display needs one)."""
    mass: float = 0.0
    """Moving mass (kg) or inertia (kg m^2) of each axis at the handle, motor included."""
    damping: float = 0.0
    """Physical damping of each axis, N*s/m or Nm*s/rad: what dissipates a rendering's energy."""
    command_delay_s: float = 0.0
    """Transport delay of the commands (USB, driver, the device's own filtering)."""
    reading_delay_s: float = 0.0
    """Age of a reading when it reaches the loop."""
    report_hz: float = 1000.0
    """How often the device reports its position (readings are held in between)."""
    resolution: float = 0.0
    """Smallest step of a reading (its quantum), m or rad."""
    noise: float = 0.0
    """Standard deviation of a reading's noise, m or rad."""
    ident: str = ""
    """What tells this device from others of its name (vendor and product ids, a serial, the
    backend's path or GUID): the key of its stored profile (`realtime.profiles`)."""
    stiffness: float = 0.0
    """A centring spring of the device's own, N/m or Nm/rad (measured; 0 unless identified)."""
    mass_range: tuple[float, float] | None = None
    """Where the true moving mass (or inertia) may lie, least and largest: the sizing holds
    for every plant of the set (`stability.plant_set`). None: exactly `mass`."""
    damping_range: tuple[float, float] | None = None
    """Where the true damping may lie; None: exactly `damping`."""
    delay_range_s: tuple[float, float] | None = None
    """Where the true round trip (command delay plus reading delay, the report's hold aside)
    may lie, s; None: exactly `command_delay_s + reading_delay_s`."""

    @property
    def round_trip_s(self) -> float:
        """Command delay plus reading delay (the report's hold aside), s."""
        return self.command_delay_s + self.reading_delay_s

    @property
    def latency_s(self) -> float:
        """Round trip from a movement to the force that answers it: both delays and, on
        average, half a report period."""
        return self.command_delay_s + self.reading_delay_s + 0.5 / self.report_hz


class Device(Protocol):
    info: DeviceInfo

    def __enter__(self) -> Device: ...

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None: ...

    def read(self, time_s: float) -> DeviceSample:
        """The device's state now (`time_s` is the loop's clock, for simulated devices)."""
        ...

    def command(self, forces: tuple[float, ...], time_s: float) -> None:
        """Render these forces (N) or torques (Nm) per axis until the next command.

        A device that is not commanded again within its hold time fades to zero by itself
        (the evdev and SDL2 effects have a finite length): the deadman against a stalled loop.
        """
        ...
