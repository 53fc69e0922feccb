"""A game driving a one-axis lever (`realtime.levers`): its lockouts from the game's gear, the PRND
lock from the game's speed, and the lever's gear or position told to the game as buttons.

- Sequential: an upshift from the game's top gear and a downshift from R are locked
  (`cues.sequential_locked`), a wall, while the game's state is fresh; stale, nothing is locked
  (the lever's own rules remain: the lift for N and R).
- PRND: the game's road speed locks R above the preset's speed; stale or unknown, the speed is
  NaN, which keeps R locked (the safe side).
- Gear output: the sequential lever's gear through `--gear-mapping` (`buttons`: a button per
  gear, R after the forward ones; `sequential`: an up and a down pulse per step), the
  selector's position as its own button (`gearout.prnd_buttons`: P, R, N, D ... each one).
"""

from __future__ import annotations

import math
from typing import Any

from carfeel.contracts import DeviceSample
from carfeel.telemetry.cues import sequential_locked
from carfeel.telemetry.driving import Wrapping
from carfeel.telemetry.gearout import prnd_buttons
from carfeel.telemetry.source import VehicleSource
from carfeel.telemetry.state import VehicleState

__all__ = ["LeverDriven", "PositionFollower", "gear_number", "lever_needs"]


def lever_needs(state: VehicleState) -> bool:
    """A lever takes the game's gear (sequential) or speed (PRND): a state with either is used."""
    return not math.isnan(state.speed_m_s) or state.gear != 0 or state.forward_gears > 0


def gear_number(name: str) -> int:
    """The games' gear ints of a sequential lever's gear name: R -1, N 0, 1 ..."""
    return -1 if name == "R" else 0 if name in ("N", "") else int(name)


class PositionFollower:
    """Holds the button of the selector's position (`prnd_buttons`): P, R, N, D ... each its
    own, so a game bound to them sees every position."""

    def __init__(self, output: Any, positions: tuple[str, ...]) -> None:
        self.output, self.positions = output, positions
        self.held: str | None = None

    def update(self, position: str) -> None:
        if position == self.held or position not in self.positions:
            return
        for name, value in prnd_buttons(self.positions.index(position), len(self.positions)):
            if name == "press":
                self.output.press(value)
        self.held = position

    def release(self) -> None:
        self.output.release_all()
        self.held = None


class LeverDriven(Wrapping):
    """A `LeverRenderer` driven by a game (see the module); the `Renderer` protocol, passed
    through. `follower`: a `GearFollower` (sequential lever) or a `PositionFollower` (PRND), or
    None (no gear output)."""

    EXTRA = ("telemetry_weight", "game_speed_m_s", "game_gear", "locked_up", "locked_down")

    def __init__(self, inner: Any, source: VehicleSource, model: str, follower: Any = None) -> None:
        self.inner, self.source, self.model, self.follower = inner, source, model, follower
        self.axes: int = inner.axes
        self.columns: tuple[str, ...] = (*inner.columns, *self.EXTRA)
        self.effect = 0.0

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        state, w = self.source.update(sample.time_s)
        controls = self.inner.controls
        fresh = w > 0.0
        if self.model == "sequential":
            controls.locked_up = fresh and sequential_locked(1, state)
            controls.locked_down = fresh and sequential_locked(-1, state)
        else:
            speed = state.speed_m_s if fresh else math.nan
            controls.speed_m_s = speed if math.isfinite(speed) else math.nan
        commands, row = self.inner.tick(sample, dt_s)
        self.effect = self.inner.effect
        if self.follower is not None:
            gear = self.inner.gear
            if self.model == "sequential":
                self.follower.update(gear_number(gear), sample.time_s)
            else:
                self.follower.update(gear)
        extra = (w, state.speed_m_s, state.gear, int(controls.locked_up),
                 int(controls.locked_down))  # fmt: skip
        return commands, (*row, *extra)

    def commanded(self, now_ns: int) -> None:
        """The loop sent this tick's commands at `now_ns` (`VehicleSource.commanded`)."""
        self.source.commanded(now_ns)

    def close(self) -> None:
        """Release the gear output's buttons and the source (stop, fault or exit)."""
        try:
            if self.follower is not None:
                self.follower.release()
                self.follower.output.close()
        finally:
            self.source.close()
