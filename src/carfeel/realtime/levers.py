"""One-axis levers on a device: the sequential lever and the PRND selector.

Both models integrate the knob's force with implicit Euler, walls and end stops included (passive
at any step), so they sit behind the virtual coupling as the engagement does in impedance mode:
the handle's stretch from the model lever is the hand's force on it, and the device renders the
coupling's reaction. The coupling is the device's sized spring and damper (`stability.size`):
what the lever's own stiff walls hold beyond it, the handle feels through the coupling, as the
gate's end stop of the engagement.

What the hand does besides pushing (the sequential knob's lift button, the PRND's brake pedal
and lock button, the car's speed) comes from `controls`: the scripted hand sets them as the
offline drivers do; a person's run keeps them at rest (no lift: a sequential lever stays in the
forward gears; the brake pressed, the button released, standing still).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from carfeel.models.gearshift import prnd as pr
from carfeel.models.gearshift import sequential as sq
from carfeel.realtime.devices.base import DeviceInfo, DeviceSample
from carfeel.realtime.filters import butterworth
from carfeel.realtime.rendering import DISPLAY_CUTOFF_HZ, Gains, Reading, Scaling
from carfeel.realtime.stability import Sizing

__all__ = [
    "TRAVEL_SHARE",
    "Controls",
    "LeverHand",
    "LeverMove",
    "LeverRenderer",
    "PrndLever",
    "SequentialLever",
    "lever_for",
    "lever_scaling",
    "prnd_moves",
    "sequential_moves",
]

TRAVEL_SHARE = 0.9
"""Of the device's travel, what the lever and the coupling's stretch may use (the rest keeps
the handle off the device's own stop and the watchdog's travel check)."""


@dataclass(slots=True)
class Controls:
    """The hand's other inputs to a lever: buttons, pedals, the car's speed."""

    lift: bool = False
    """The sequential knob's lift button (neutral and reverse)."""
    brake: bool = True
    """The PRND's brake pedal (out of P needs it)."""
    button: bool = False
    """The PRND knob's lock button (into R needs it)."""
    speed_m_s: float = 0.0
    """The car's road speed, m/s (R is locked above the preset's speed)."""
    locked_up: bool = False
    locked_down: bool = False
    """A game's refusal of a sequential shift (up past the top gear, a lockout)."""


class Lever(Protocol):
    """A one-axis lever model as the renderer steps it."""

    travel_m: float
    """How far the knob goes either way from its rest, m (for the position scale)."""
    params: Any
    """The model's parameters (`SequentialParams`, `PrndParams`); a tuning replaces them."""
    state: Any
    """The model's state (`SequentialState`, `PrndState`)."""
    marks: tuple[tuple[float, str], ...]
    """Positions (m) and names of what the lever has along its travel, along + x."""

    @property
    def position_m(self) -> float: ...

    @property
    def velocity_m_s(self) -> float: ...

    def step(self, hand_N: float, controls: Controls, dt_s: float) -> tuple[float, float, str]:
        """Advance by dt_s with the hand's force (N, + along x): (the mechanism's force on the
        knob N, the depth into a lock's wall m, the gear or position now)."""
        ...


class _Knob:
    """The knob's position and speed of a lever model's state (`x_m`, `v_m_s`)."""

    state: Any

    @property
    def position_m(self) -> float:
        return float(self.state.x_m)

    @property
    def velocity_m_s(self) -> float:
        return float(self.state.v_m_s)


class SequentialLever(_Knob):
    """`models.gearshift.sequential` as a `Lever`."""

    def __init__(self, params: sq.SequentialParams) -> None:
        self.params = params
        self.state: Any = sq.SequentialState()
        self.travel_m = params.end_m
        up, p = params.up_direction, params
        self.marks: tuple[tuple[float, str], ...] = tuple(sorted((
            (-p.end_m, "end"), (-up * p.click_m, "down"), (0.0, "rest"), (up * p.click_m, "up"),
            (p.end_m, "end"),
        )))  # fmt: skip
        """Positions (m) and names of what the lever has along its travel, along + x."""

    def step(self, hand_N: float, controls: Controls, dt_s: float) -> tuple[float, float, str]:
        inputs = sq.SequentialInputs(hand_N, controls.lift, controls.locked_up,
                                     controls.locked_down)  # fmt: skip
        self.state, out = sq.step(self.params, self.state, inputs, dt_s)
        return out.lever_N, out.wall_depth_m, sq.gear_name(out.gear)


class PrndLever(_Knob):
    """`models.gearshift.prnd` as a `Lever`: x from P's centre toward D."""

    def __init__(self, params: pr.PrndParams) -> None:
        self.params = params
        self.state: Any = pr.PrndState()
        self.travel_m = params.centre_m(len(params.positions) - 1) + params.end_m
        last = params.centre_m(len(params.positions) - 1)
        self.marks: tuple[tuple[float, str], ...] = (
            (-params.end_m, "end"),
            *((params.centre_m(i), name) for i, name in enumerate(params.positions)),
            (last + params.end_m, "end"),
        )
        """Positions (m) and names of what the lever has along its travel, along + x."""

    def step(self, hand_N: float, controls: Controls, dt_s: float) -> tuple[float, float, str]:
        inputs = pr.PrndInputs(hand_N, controls.brake, controls.button, controls.speed_m_s)
        self.state, out = pr.step(self.params, self.state, inputs, dt_s)
        return out.lever_N, out.wall_depth_m, self.params.positions[out.position]


def lever_for(kind: str, params: sq.SequentialParams | pr.PrndParams) -> Lever:
    """The lever model of a preset kind ("sequential" or "prnd")."""
    if kind == "sequential" and isinstance(params, sq.SequentialParams):
        return SequentialLever(params)
    if kind == "prnd" and isinstance(params, pr.PrndParams):
        return PrndLever(params)
    raise ValueError(f"no lever of kind {kind!r} for {type(params).__name__}")


def lever_scaling(
    lever: Lever, hand_N: float, model_force_N: float, info: DeviceInfo, sizing: Sizing
) -> Scaling:
    """The scales of a lever on a device: forces so that `model_force_N` is 90 % of the
    device's; positions so that the lever's whole travel plus the coupling's stretch under the
    hand's `hand_N` (at the sized stiffness, device units: independent of the position scale)
    stays within TRAVEL_SHARE of the device's travel. ValueError if the stretch alone fills it."""
    force_scale = 0.9 * info.max_force / model_force_N
    stretch = hand_N * force_scale / sizing.stiffness
    room = TRAVEL_SHARE * info.travel - stretch
    if room <= 0.0:
        raise ValueError(
            f"the coupling's stretch under the hand ({stretch * 1e3:.1f} mm at "
            f"{sizing.stiffness:.0f} N/m) leaves none of the device's travel for the lever"
        )
    return Scaling(force_scale, room / lever.travel_m)


class LeverRenderer:
    """A one-axis lever on the first axis behind the impedance coupling; the second axis is
    held at zero. `gears` lists the gears (or positions) as they register."""

    axes: int = 2
    columns: tuple[str, ...] = (
        "x_device", "y_device", "position_m", "velocity_m_s", "force_N", "force_filtered_N",
        "lever_N", "wall_depth_m", "gear",
    )  # fmt: skip

    def __init__(
        self, lever: Lever, scaling: Scaling, rate_hz: float, gains: Gains,
        controls: Controls | None = None,
    ) -> None:  # fmt: skip
        self.lever, self.scaling, self.g = lever, scaling, gains
        self.controls = controls if controls is not None else Controls()
        self.mode = "impedance"
        self.effect = 0.0
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.rx, self.ry = Reading(rate_hz), Reading(rate_hz)
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick."""
        self.buttons: tuple[str, ...] = ()
        """The controls (`Controls` fields: lift, button, brake) the device's buttons press, in
        the order of the sample's `buttons`."""
        self._gear = ""

    @property
    def gear(self) -> str:
        """The gear (or position) the lever is in now."""
        return self._gear

    def retune(self, params: Any) -> None:
        """New lever parameters (a tuning's blend, `panel.tuning.Ramp`): the lever keeps its
        state; its marks stay (the tunables move no position)."""
        self.lever.params = params

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        g, lever = self.g, self.lever
        if self.buttons and sample.buttons is not None:  # a person's hand on a real device
            for control, pressed in zip(self.buttons, sample.buttons, strict=True):
                setattr(self.controls, control, pressed)
        x_dev, vx_dev = self.rx.step(sample.positions[0], dt_s)
        y_dev, vy_dev = self.ry.step(sample.positions[1], dt_s)
        h = dt_s / self.substeps
        x_handle, v_handle = x_dev / ps, vx_dev / ps

        def coupling_N() -> float:
            """The coupling's pull on the lever toward the handle, model N."""
            stretch = x_handle - lever.position_m
            return g.coupling_stiffness * stretch + g.coupling_damping * (
                v_handle - lever.velocity_m_s
            )

        hand = coupling = coupling_N()  # what the hand applies through it at the tick's start
        lever_N = depth = 0.0
        gear = self._gear
        for _ in range(self.substeps):  # the handle is held, the lever moves
            lever_N, depth, gear = lever.step(coupling, self.controls, h)
            coupling = coupling_N()
        if gear != self._gear:
            if self._gear:  # the rest position at the start is not a shift
                self.gears.append(gear)
            self._gear = gear
        command_x = -coupling * fs
        command_y = -g.hold_stiffness * y_dev - g.hold_damping * vy_dev
        row = (
            x_dev, y_dev, lever.position_m, lever.velocity_m_s, hand, self.display.step(hand),
            lever_N, depth, gear,
        )  # fmt: skip
        return (command_x, command_y), row


MUSCLE_V0_M_S = 1.5
"""The pushing hand's force falls with the knob's speed as eq. (10)'s muscle does, F (1 - v/V0),
with this V0 (a brisk hand; assumed): a damping of F/V0 while it pushes, none when it lets go."""


@dataclass(frozen=True, slots=True)
class LeverMove:
    """One move of a scripted hand: push along `sense` (+1: + x) for the hold, or toward the
    position `target` until the lever registers it (the hold at most); with these controls."""

    sense: int
    target: str = ""
    lift: bool = False
    brake: bool = True
    button: bool = False


def sequential_moves(params: sq.SequentialParams, moves: tuple[str, ...]) -> tuple[LeverMove, ...]:
    """The moves of `simulate sequential` (up, down, lift-down, lift-up) as a hand's pushes."""
    up = params.up_direction
    return tuple(
        LeverMove((1 if m.endswith("up") else -1) * up, lift=m.startswith("lift-")) for m in moves
    )


def prnd_moves(params: pr.PrndParams, targets: tuple[int, ...]) -> tuple[LeverMove, ...]:
    """Target positions (indices, as `simulate prnd`'s) as a hand's pushes toward each, with the
    brake pressed and the lock button held (P and R need them)."""
    return tuple(LeverMove(0, params.positions[t], button=True) for t in targets)


class LeverHand:
    """A scripted hand on a one-axis lever, as the offline drivers: each move pushes with
    `hand_N` (model N) for `hold_s`, or toward its target until the lever registers it, then
    lets go for `rest_s`; it sets the lever's controls as it goes. Forces and positions through
    the scales, as the other scripted hands (`realtime.hands`).

    Toward a target the hand goes by what it feels, the registered position (`registered`,
    along `order`, + x onward), not by where the handle is: on a device the handle leads the
    lever by the coupling's stretch, which on a weak one is a whole detent's pitch."""

    def __init__(
        self, moves: tuple[LeverMove, ...], hand_N: float, hold_s: float, rest_s: float,
        force_scale: float, position_scale: float, controls: Controls, start_s: float = 0.0,
        registered: Callable[[], str] = lambda: "", order: tuple[str, ...] = (),
    ) -> None:  # fmt: skip
        self.moves, self.hand_N, self.hold_s, self.rest_s = moves, hand_N, hold_s, rest_s
        self.force_scale, self.position_scale = force_scale, position_scale
        self.controls, self.start_s, self.registered = controls, start_s, registered
        self.order = order
        self.done_s = start_s + len(moves) * (hold_s + rest_s)
        """When the last move's rest ends."""
        self._done = False

    @property
    def done(self) -> bool:
        """Set by the loop's clock through `forces`: the script has run out."""
        return self._done

    def forces(
        self, time_s: float, positions: tuple[float, ...], velocities: tuple[float, ...]
    ) -> tuple[float, ...]:
        rest = (0.0,) * (len(positions) - 1)
        if time_s >= self.done_s:
            self._done = True
        if time_s < self.start_s or time_s >= self.done_s:
            return (0.0, *rest)
        k, into = divmod(time_s - self.start_s, self.hold_s + self.rest_s)
        move = self.moves[int(k)]
        c = self.controls
        c.lift, c.brake, c.button = move.lift, move.brake, move.button
        if into >= self.hold_s:
            return (0.0, *rest)
        v = velocities[0] / self.position_scale
        sense = move.sense
        if move.target:
            now = self.registered()
            if now == move.target or now not in self.order:
                return (0.0, *rest)
            sense = 1 if self.order.index(move.target) > self.order.index(now) else -1
        force = sense * self.hand_N * max(0.0, 1.0 - sense * v / MUSCLE_V0_M_S)
        return (force * self.force_scale, *rest)
