"""Live tuning: which parameters a panel may change, how a change is checked, and how it ramps.

A change is checked in the panel's process, never in the loop's: each value against its preset
range, then the whole preset through the loader's cross-checks (`check_shift`,
`check_hpattern`, `check_steering`: the walls' sampled-data passivity among them), then what the
device renders. The gearbox's walls, detents and synchronizer live behind the virtual coupling
(or the admittance servo), which is sized from the device alone, so the preset's checks are its
whole check. The steering law is rendered straight onto the wheel: a new K1 changes the on-centre
spring the wheel feels, K4..K9 its velocity gains; the change is refused when start-up would
have lowered the torque scale for it (the spring beyond the device's budget) or when the
released wheel's damping ratio, on the exact discrete-time loop with the device's delays, would
fall below the sizing's 0.2 (and below what it is now) at any speed of the schedule. Its damping
schedule is recomputed for the new law by the same code as at start-up. The physical steering
model sits behind a virtual coupling sized at start-up: a tuning keeps that coupling (its
tunables leave the model's rim inertia in the loop as it is) and is refused unless, on it, a
damping schedule within the device's cap keeps every linearization of the new model damped at
every speed the session reaches and the coupling still lets through the share of the car's
stiffness start-up asks (`physical_steering.resize_physical`, about a second, off the panel's
event loop); its schedule and wall ramp with the parameters.

In the loop a change waits for a safe point and then ramps (`Ramp`): the gearbox's parameters
change only with the lever in neutral (no engagement under way, no stage holding values drawn
from the old ones), a sequential lever's with it centred and at rest, a selector's with it at
rest in a position (no shift under way), the steering's at any time; over RAMP_S the changed
values are blended linearly from old to new. Every blend of two parameter sets that pass the
(linear) cross-checks passes them too.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from carfeel.errors import InputError, PresetError
from carfeel.schema import describe_range, range_key, range_of, unit_of

RAMP_S = 0.2
"""A tuned value goes from old to new over this long (a step in a rendered force is a knock)."""


@dataclass(frozen=True, slots=True)
class Tunable:
    path: str
    """Where it is in the preset's tables (as in its TOML file)."""
    label: str
    group: str
    models: tuple[str, ...]
    note: str = ""

    @property
    def unit(self) -> str:
        return unit_of(self.path.split(".")[-1])

    @property
    def bounds(self) -> tuple[float, float, bool, bool]:
        allowed = range_of(self.path)
        assert allowed is not None, f"{self.path}: a tunable without a range in the schema"
        return allowed

    def as_dict(self) -> dict[str, Any]:
        low, high, low_in, high_in = self.bounds
        return {
            "path": self.path,
            "label": self.label,
            "group": self.group,
            "unit": self.unit,
            "min": low,
            "max": high,
            "min_included": low_in,
            "max_included": high_in,
            "note": self.note,
        }


GEARBOX = ("shift", "hpattern")
LEVERS = ("sequential", "prnd")
"""The one-axis levers: their parameters change only with the lever at rest in a position."""
PHYSICAL = "steering:physical"
"""The tunables' model key of --model steering --steering-model physical."""
TUNABLES = (
    Tunable("gearbox.synchronization_duration_s", "synchronization time", "synchronization",
            GEARBOX, "how long the ring holds the lever while pushed (fixed synchronizer)"),
    Tunable("gearbox.ring_release_force_N", "synchronization: push to hold the ring",
            "synchronization", GEARBOX,
            "the ring lets go below the neutral spring's and detent's push-back plus this"),
    Tunable("synchronizer.cone_friction", "cone friction (physics synchronizer)",
            "synchronization", ("hpattern",),
            "lower: more push for the same synchronization time (a heavier synchro)"),
    Tunable("gearbox.neutral_detent.seat_force_N", "neutral detent", "detents", GEARBOX),
    Tunable("gearbox.gear_detent.seat_force_N", "gear detent: suck-in", "detents", GEARBOX),
    Tunable("gearbox.gear_detent.far_force_N", "gear detent: crest", "detents", GEARBOX),
    Tunable("select.detent_stiffness_N_m", "plane detents (select)", "detents", ("hpattern",)),
    Tunable("feel.latch_force_N", "slot latch", "detents", ("hpattern",)),
    Tunable("walls.stiffness_N_m", "wall stiffness", "walls", ("hpattern",),
            "within K*T/2 + B < the lever's damping at 1 kHz (checked)"),
    Tunable("walls.damping_N_s_m", "wall damping", "walls", ("hpattern",)),
    Tunable("select.slot_stiffness_N_m", "slot hold stiffness", "walls", ("hpattern",)),
    Tunable("gearbox.stop.stiffness_N_m", "end stop stiffness", "walls", GEARBOX),
    Tunable("lever.click_N", "shift click", "detents", ("sequential",),
            "the click's peak with the centring spring stays within the device's force"),
    Tunable("lever.centring_N_m", "centring spring", "detents", ("sequential",)),
    Tunable("lever.drum_N", "gear drum detent", "detents", ("sequential",)),
    Tunable("lever.damping_N_s_m", "lever damping", "damping", ("sequential",)),
    Tunable("lever.wall_N_m", "lock wall stiffness", "walls", ("sequential",),
            "the lever's implicit step keeps any wall passive"),
    Tunable("selector.detent_N", "position detents", "detents", ("prnd",),
            "within the device's force"),
    Tunable("selector.damping_N_s_m", "selector damping", "damping", ("prnd",)),
    Tunable("selector.wall_N_m", "lock wall stiffness", "walls", ("prnd",),
            "the selector's implicit step keeps any wall passive"),
    Tunable("torque.k1_Nm_s2_m", "K1 aligning gain", "torque law", ("steering",),
            "the on-centre spring: checked against the wheel's stiffness budget"),
    Tunable("torque.k2", "K2 aligning saturation", "torque law", ("steering",)),
    Tunable("torque.k3", "K3 saturation exponent", "torque law", ("steering",)),
    Tunable("torque.k4_1_Nm", "K4 tire spin at standstill", "torque law", ("steering",)),
    Tunable("torque.k5_s_m_Nm", "K5 tire spin fall with speed", "torque law", ("steering",)),
    Tunable("torque.k6_rad_s", "K6 tire spin rate scale", "torque law", ("steering",)),
    Tunable("torque.k7_Nm", "K7 friction", "torque law", ("steering",)),
    Tunable("torque.k8_rad_s", "K8 friction rate scale", "torque law", ("steering",),
            "offline only: on a device the friction is a stick element"),
    Tunable("torque.k9_Nm_s_rad", "K9 damping", "damping", ("steering",),
            "checked: the released wheel keeps its damping ratio"),
    Tunable("steering_system.assist_gain_standstill_1_Nm", "assist gain at standstill",
            "assist", (PHYSICAL,), "higher: a lighter wheel when parking"),
    Tunable("steering_system.assist_gain_high_speed_1_Nm", "assist gain at speed", "assist",
            (PHYSICAL,), "higher: a lighter wheel in a fast bend"),
    Tunable("steering_system.active_return_Nm_rad", "active return", "assist", (PHYSICAL,),
            "the motor's pull back to centre at low speed"),
    Tunable("steering_system.eps_damping_Nm_s_rad", "EPS damping at standstill", "damping",
            (PHYSICAL,)),
    Tunable("steering_system.eps_damping_high_speed_Nm_s_rad", "EPS damping at speed",
            "damping", (PHYSICAL,), "checked: the released wheel keeps its damping ratio"),
    Tunable("steering_system.column_friction_Nm", "column friction", "friction", (PHYSICAL,)),
    Tunable("steering_system.rack_friction_Nm", "rack friction", "friction", (PHYSICAL,)),
    Tunable("tyres.pneumatic_trail_m", "pneumatic trail", "tyres", (PHYSICAL,),
            "the on-centre weight of the wheel (the tyres' aligning torque)"),
)  # fmt: skip
"""The physical model's: none of them changes the model's rim inertia in the loop (the torsion
bar, the stick elements' spring and damper and the compensation do), so a running session keeps
its coupling (`physical_steering.resize_physical`)."""
BY_PATH = {t.path: t for t in TUNABLES}


def tunables_for(model: str) -> list[Tunable]:
    """`model`: shift, hpattern, steering (the paper's law) or PHYSICAL."""
    return [t for t in TUNABLES if model in t.models]


def kind_of(model: str, steering_model: str = "paper") -> str:
    """The tunables' model key of a session."""
    return PHYSICAL if model == "steering" and steering_model == "physical" else model


def get_path(obj: Any, path: str) -> Any:
    for name in path.split("."):
        obj = getattr(obj, name)
    return obj


def set_path(obj: Any, path: str, value: Any) -> Any:
    """A copy of the frozen dataclass tree `obj` with the field at `path` set."""
    head, _, rest = path.partition(".")
    if not rest:
        return dataclasses.replace(obj, **{head: value})
    return dataclasses.replace(obj, **{head: set_path(getattr(obj, head), rest, value)})


def preset_path(model: str, path: str) -> str:
    """A tunable's path in the loaded preset object (ShiftParams, HPatternPreset, SteeringCar)."""
    if model == "hpattern":
        return f"shift.{path}" if path.startswith("gearbox.") else f"setup.{path}"
    return path


def renderer_path(model: str, path: str) -> str:
    """A tunable's path in the renderer's parameters (EngagementParams, HPatternParams,
    SteeringCar, PhysicalParams)."""
    table, _, rest = path.partition(".")
    if model == "shift":
        return rest
    if model == PHYSICAL:  # PhysicalParams
        return f"system.{rest}" if table == "steering_system" else path
    if model == "hpattern" and table == "gearbox":
        return f"engagement.{rest}"
    if model in LEVERS:  # the lever's own parameters (SequentialParams, PrndParams)
        return rest
    return path


def values_of(model: str, preset: Any) -> dict[str, float]:
    return {
        t.path: float(get_path(preset, preset_path(model, t.path))) for t in tunables_for(model)
    }


def checked_value(path: str, value: object) -> float:
    """A tuned value as a float within its preset range, or InputError naming the range."""
    tunable = BY_PATH[path]
    allowed = describe_range(range_key(path))
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"{path} = {_said(value)}: expected a number, {allowed}")
    try:
        number = float(value)
    except OverflowError:  # a whole number of 401 digits: beyond any float, not a crash
        raise InputError(
            f"{path} = a whole number of {int(int(value).bit_length() * math.log10(2)) + 1} digits "
            f"{tunable.unit} is out of "
            f"range: allowed {allowed}"
        ) from None
    low, high, low_in, high_in = tunable.bounds
    inside = (
        math.isfinite(number)
        and (number >= low if low_in else number > low)
        and (number <= high if high_in else number < high)
    )
    if not inside:
        raise InputError(
            f"{path} = {_said(value)} {tunable.unit} is out of range: allowed {allowed}"
        )
    return number


def _said(value: object) -> str:
    """A value as a refusal quotes it: at most 60 characters of its repr."""
    text = repr(value) if not isinstance(value, str) or len(value) < 100 else repr(value[:60])
    return text if len(text) <= 60 else f"{text[:48]}...{text[-9:]}"


@dataclass(frozen=True, slots=True)
class Session:
    """What the panel's process knows of a running session, for checking a tuning."""

    model: str
    preset: Any
    """The current parameters as a loaded preset (ShiftParams, HPatternPreset, SteeringCar)."""
    physics: bool | None
    """hpattern: the run's synchronizer choice (None: the preset's)."""
    parts: Mapping[str, Any]
    """From the loop's ready event: info, sizing, scaling, rate_hz, speed_m_s, aligning (and
    for the physical steering: physical, its PhysicalSizing, and substeps)."""
    steering_model: str = "paper"
    road: str | None = None
    """The physical model's road, or None: the preset's own mu."""
    speed_m_s: float | None = None
    """The model's speed now, m/s, where telemetry moves it (None: the run's)."""

    @property
    def kind(self) -> str:
        return kind_of(self.model, self.steering_model)


@dataclass(frozen=True, slots=True)
class Proposal:
    preset: Any
    """The new parameters as a preset (what `save` writes and the next tuning starts from)."""
    command: tuple[Any, ...]
    """What the loop is sent: ("retune", moves, target, schedule, changes)."""
    changes: dict[str, tuple[float, float]]
    """Tunable path -> (old, new)."""
    note: str = ""
    """What the user should know of an accepted change (the physical model's top speed)."""


def propose(session: Session, values: Mapping[str, object]) -> Proposal:
    """Check a tuning and build the loop's command; InputError with every reason otherwise."""
    model = session.kind
    allowed = {t.path for t in tunables_for(model)}
    if not values:
        raise InputError("a tuning names at least one parameter: {path: value}")
    if len(values) > len(TUNABLES):
        raise InputError(f"a tuning names {len(values)} parameters; there are {len(TUNABLES)}")
    problems = []
    checked: dict[str, float] = {}
    for path, value in values.items():
        if path not in allowed:
            problems.append(
                f"{_said(path)}: not a tunable parameter of --model {model}; it has "
                f"{', '.join(sorted(allowed))}"
            )
            continue
        try:
            checked[path] = checked_value(path, value)
        except InputError as exc:
            problems.append(str(exc))
    if problems:
        raise InputError("; ".join(problems))
    preset = session.preset
    changes: dict[str, tuple[float, float]] = {}
    for path, value in checked.items():
        where = preset_path(model, path)
        old = float(get_path(preset, where))
        changes[path] = (old, value)
        kind = type(get_path(preset, where))
        try:  # (a lever checks itself as it is built)
            preset = set_path(preset, where, kind(value) if kind is int else value)
        except PresetError as exc:
            raise InputError(f"this tuning would make the preset invalid: {exc}") from None
    cross = _cross_checks(model, preset)
    if model in LEVERS:
        cross += _lever_force_checks(session, preset)
    if cross:
        raise InputError("this tuning would make the preset invalid: " + "; ".join(cross))
    schedule: Any = None
    if model == PHYSICAL:
        schedule = _physical_sized(session, preset, changes)
        target: Any = preset.physical(session.road)
    elif model == "steering":
        schedule = _steering_sized(session, preset)
        target = preset
    elif model == "hpattern":
        target = preset.pattern(session.physics)
    elif model in LEVERS:
        target = preset.lever if model == "sequential" else preset.selector
    else:
        target = preset.gearbox
    moves = tuple((renderer_path(model, p), old, new) for p, (old, new) in changes.items())
    note = ""
    if model == PHYSICAL:
        was, now = session.parts["physical"].top_speed_m_s, schedule.top_speed_m_s
        if now != was:
            note = (
                f"the model is now rendered up to {now * 3.6:.0f} km/h (was {was * 3.6:.0f}): "
                "above, its speed is held there"
            )
    return Proposal(preset, ("retune", moves, target, schedule, changes), changes, note)


def _cross_checks(model: str, preset: Any) -> list[str]:
    from carfeel.io.presets import check_hpattern, check_shift, check_steering

    if model == "shift":
        return check_shift(preset)
    if model == "hpattern":
        return check_shift(preset.shift) + check_hpattern(preset.setup, preset.shift)
    if model in LEVERS:
        return []  # the lever's own checks ran as it was built
    return check_steering(preset)


def _lever_force_checks(session: Session, preset: Any) -> list[str]:
    """A lever's largest resistance must stay within what the device renders at its force
    limit (model N, through the session's scale): a click or detent beyond it is clipped by the
    limiter, so the lever would feel softer than tuned and a hand could not feel it."""
    limits, scaling = session.parts["limits"], session.parts["scaling"]
    top_N = limits.max_force / scaling.force_scale
    if session.model == "sequential":
        p = preset.lever
        resist = p.centring_preload_N + p.centring_N_m * p.click_m + p.click_N
        what = "the click's peak with the centring spring"
    else:
        resist = preset.selector.detent_N
        what = "the detents' peak"
    if resist > top_N:
        return [
            f"{what} would be {resist:.1f} N, over the {top_N:.1f} N the device renders at its "
            "force limit"
        ]
    return []


def _steering_sized(session: Session, car: Any) -> tuple[tuple[float, float], ...]:
    """The new law's damping schedule, or InputError when the wheel cannot render it stably."""
    from carfeel.realtime.fitting import steering_scaling
    from carfeel.realtime.rendering import (
        SCHEDULE_SPEEDS_M_S,
        SteeringRenderer,
        SteeringRendering,
    )
    from carfeel.realtime.session import RealtimeRun

    p = session.parts
    info, sizing, scaling, rate = p["info"], p["sizing"], p["scaling"], p["rate_hz"]
    speed = p["speed_m_s"]
    rendering = SteeringRendering(aligning=p["aligning"])
    run = RealtimeRun(model="steering", rate_hz=rate, speed_kmh=speed * 3.6)
    notes: list[str] = []
    try:
        wanted = steering_scaling(car, run, info, sizing, notes)
    except InputError as exc:
        raise InputError(f"refused: {exc}") from None
    if wanted.force_scale < scaling.force_scale * (1.0 - 1e-9):
        raise InputError(
            f"refused: at {speed * 3.6:g} km/h this law's on-centre spring would be stiffer "
            f"than {info.name} holds hands off at the session's torque scale "
            f"({scaling.force_scale:.3g} Nm per model Nm); start-up would lower the scale to "
            f"{wanted.force_scale:.3g}. Lower K1, or stop and start the session with it"
        )
    old = SteeringRenderer(session.preset, speed, scaling, rate, sizing, info, rendering)
    new = SteeringRenderer(car, speed, scaling, rate, sizing, info, rendering)
    for v in sorted({*SCHEDULE_SPEEDS_M_S, speed}):
        before = released_zeta(old, v, info, rate)
        after = released_zeta(new, v, info, rate)
        if after < sizing.zeta and after < before - 0.01:
            raise InputError(
                f"refused: released at {v * 3.6:.0f} km/h the wheel would ring: its damping "
                f"ratio would fall to {after:.2f} (now {before:.2f}; the sizing keeps at least "
                f"{sizing.zeta:.2f}) with {info.name}'s delays. Lower K9 or K1, or raise K6"
            )
    return new.schedule


def _physical_sized(session: Session, car: Any, changes: Mapping[str, object]) -> Any:
    """The tuned physical model's PhysicalSizing on the session's coupling, or InputError when
    the wheel cannot render it stably or faithfully (as start-up would refuse it)."""
    from carfeel.realtime.physical_steering import (
        ZETA_FLOOR,
        felt_share,
        holds,
        resize_physical,
    )
    from carfeel.realtime.rendering import velocity_sections
    from carfeel.realtime.session import MIN_FELT_SHARE

    p = session.parts
    info, sizing, scaling, rate = p["info"], p["sizing"], p["scaling"], p["rate_hz"]
    speed_now = session.speed_m_s if session.speed_m_s is not None else p["speed_m_s"]
    params = car.physical(session.road)
    sized = resize_physical(
        info, rate, velocity_sections(rate), params, scaling, sizing, p["physical"],
        p.get("substeps", 1),
    )  # fmt: skip
    current = p["physical"]
    if isinstance(sized, str) or sized.top_speed_m_s < min(current.top_speed_m_s, speed_now):
        reason = sized if isinstance(sized, str) else (
            f"it would be damped only up to {sized.top_speed_m_s * 3.6:.0f} km/h, the car is "
            f"at {speed_now * 3.6:.0f} km/h")  # fmt: skip
        raise InputError(
            f"refused: {info.name} could not keep the released wheel damped with this model on "
            f"the session's coupling ({reason}). Undo the change, or stop and start the "
            "session with it"
        )
    # Halfway through the ramp (parameters and schedule blended) the loop stays damped too:
    # at half ZETA_FLOOR, for the ramp's 0.2 s (the end points' schedules are the least that
    # reach their goals, ZETA_FLOOR among them, so a blend may fall a little short of them).
    now = session.preset.physical(session.road)
    half = params
    for path in changes:
        where = renderer_path(PHYSICAL, path)
        half = set_path(half, where, 0.5 * (get_path(now, where) + get_path(params, where)))
    blend = dataclasses.replace(sized, schedule=tuple(
        (v, 0.5 * (b0 + b1)) for (v, b0), (_, b1) in
        zip(current.schedule, sized.schedule, strict=False)))  # fmt: skip
    midway = holds(info, rate, velocity_sections(rate), half, scaling, sizing, blend,
                   p.get("substeps", 1), 0.5 * ZETA_FLOOR)  # fmt: skip
    if midway:
        raise InputError(
            f"refused: halfway through the {RAMP_S:g} s ramp the released wheel would not stay "
            f"damped ({midway}): make the change in smaller steps"
        )
    speed = max(speed_now, 1.0)
    share = felt_share(params, sized, scaling, speed)
    if share < MIN_FELT_SHARE:
        raise InputError(
            f"refused: the coupling would let through only {share:.0%} of this car's on-centre "
            f"stiffness at {speed * 3.6:.0f} km/h (start-up needs {MIN_FELT_SHARE:.0%})"
        )
    return sized


def released_zeta(renderer: Any, speed_m_s: float, info: Any, rate_hz: float) -> float:
    """The least damping ratio of the released wheel on `renderer` at a speed: the law
    linearized on centre, its added damping and the friction's stick spring, on the device's
    exact discrete-time loop, over its uncertainty set (as the schedule is sized)."""
    from carfeel.realtime import stability
    from carfeel.realtime.rendering import steering_environment, velocity_sections

    plants = stability.plant_set(info, rate_hz, velocity_sections(rate_hz))
    law = steering_environment(
        renderer.car, renderer.scaling, speed_m_s, renderer.rendering, 1.0 / rate_hz,
        renderer.tire_spin_rate(speed_m_s),
    )  # fmt: skip
    b, k = renderer.added_damping(speed_m_s), renderer.friction_stiffness

    def environment(state: object, y: float, v: float) -> tuple[object, float]:
        state, u = law(state, y, v)
        return state, u - b * v - k * y

    return float(stability.least_over(plants, environment, 3 if law.stateful else 0))


class Ramp:
    """A retune as the loop applies it: it waits for a safe point, then blends over RAMP_S."""

    def __init__(self, renderer: Any, model: str, command: tuple[Any, ...], rate_hz: float):
        _, moves, target, schedule, changes = command
        self.changes: dict[str, tuple[float, float]] = changes
        self.renderer, self.model = renderer, model
        self.walls: tuple[tuple[float, float], tuple[float, float]] | None = None
        if hasattr(schedule, "schedule"):  # the physical steering's PhysicalSizing
            self.walls = (renderer.wall, (schedule.wall_stiffness, schedule.wall_damping))
            schedule = schedule.schedule
        self.moves, self.target, self.schedule = moves, target, schedule
        self.old_schedule = getattr(renderer, "schedule", None)
        self.ticks = max(1, round(RAMP_S * rate_hz))
        self.k = 0

    def safe(self) -> bool:
        """May the change start now? The gearbox: only with the lever in neutral."""
        r = self.renderer
        if self.model == "shift":
            return bool(r.state.stage.value == "neutral")
        if self.model == "hpattern":
            return bool(r.state.lever.stage.value == "neutral")
        if self.model in LEVERS:  # at rest in its position: no shift under way
            lever = r.lever
            p, state = lever.params, lever.state
            if self.model == "sequential":
                return bool(state.armed and abs(state.x_m) < p.rearm_m and abs(state.v_m_s) < 0.01)
            centre = p.centre_m(state.position)
            return bool(abs(state.x_m - centre) < p.register_m and abs(state.v_m_s) < 0.01)
        return True

    @property
    def started(self) -> bool:
        return self.k > 0

    def step(self) -> bool:
        """Apply one tick's blend (call between ticks); True when the target is reached."""
        if self.k == 0 and not self.safe():
            return False
        self.k += 1
        s = min(1.0, self.k / self.ticks)
        params = self.target
        if s < 1.0:
            for path, old, new in self.moves:
                value = old + (new - old) * s
                params = set_path(params, path, round(value) if isinstance(old, int) else value)
        r = self.renderer
        if self.model == "steering":
            table = self.schedule
            if s < 1.0 and self.old_schedule is not None:
                table = tuple(
                    (v, b0 + (b1 - b0) * s)
                    # (a physical model's re-sizing may reach fewer speeds: the first of the old)
                    for (v, b0), (_, b1) in zip(
                        self.old_schedule[: len(self.schedule)], self.schedule, strict=True
                    )
                )
            if self.walls is None:
                r.retune(params, table)
            else:
                (k0, b0), (k1, b1) = self.walls
                r.retune(params, table, (k0 + (k1 - k0) * s, b0 + (b1 - b0) * s))
        else:
            r.retune(params)
        return s >= 1.0
