"""The physical steering model (issue 13) on a force-feedback wheel, through a virtual coupling.

    device rim --K_c, B_c (coupling)-- model rim J_v --torsion bar-- pinion, rack, EPS, car ...
        ^ reading (delayed)                 `physical.step`, hands off, hand torque = coupling

The model's on-centre stiffness (torsion bar plus the column's stick spring, 215 Nm/rad for the
B-segment car) is beyond what a wheel holds with a few ms of delay (the dd-wheel 94 Nm/rad at
4 ms each way), so the device's angle does not impose the model's rim: the rim is a state of the
model (integrated hands off) and the coupling's torque is the hand's torque on it. The device
renders that torque, scaled (device Nm per model Nm), plus a speed-scheduled damper and, where
the car's lock lies beyond the device's travel, a passive wall inside the travel:

    c       = K_c * (angle_device / ps - rim) + B_c * (rate_device / ps - rim_rate)   (model Nm)
    command = -fs * c - b(speed) * rate_device - wall                               (device Nm)

At low frequency the rim follows the device and c is the model's torque at the rim; at high
frequency the device meets the coupling and the model's rim inertia in series, not the torsion
bar. The model's rim keeps the inertia the device does not already have (the car's rim less the
device's, in model units, but at least MIN_RIM_SHARE of the car's), since the user holds the
device's own rim.

Sizing (`size_physical`, once at start-up, numpy): the model is linearized (central differences
of `physical.step`, exact for its piecewise-linear elements away from their switches) at each
speed the run can reach, on centre and at the torsion-bar torque where the EPS assist's gain is
largest, with the frictions stuck and sliding; with the device, its delays, report rate and the
renderers' velocity filter (`stability.closed_loop`), the least damping ratio of each is
computed, leaving out the car's own modes that the rim does not take part in (those of the
model with its rim held still). The stiffest coupling (a share of the device's spring budget)
is taken for which a scheduled damping within the device's velocity cap gives every
linearization at least its goal: ZETA_MIN, or the car's own released damping ratio there if
that is lower (the rendering must not be less damped than the car released offline), but never
less than ZETA_FLOOR. Where no share reaches every speed, the one that reaches the highest (the
model's speed is held there), or the reason. DESIGN.md, "The physical steering in the loop".
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from dataclasses import dataclass
from typing import Any

from carfeel.models.steering import physical
from carfeel.models.steering.physical import PhysicalInputs, PhysicalParams, PhysicalState
from carfeel.realtime.devices.base import DeviceInfo, DeviceSample
from carfeel.realtime.filters import butterworth
from carfeel.realtime.rendering import DISPLAY_CUTOFF_HZ, Reading, Scaling
from carfeel.realtime.stability import ZETA_MIN, Sections, Sizing
from carfeel.simulation.steering import physical_start

POSE = ("x_m", "y_m", "yaw_rad")
"""State the rendering's stability does not depend on (the car's place on the road)."""
KEPT = tuple(i for i, name in enumerate(PhysicalState._fields) if name not in POSE)
SPEEDS_M_S = (0.0, 1.0, 2.5, 5.0, 10.0, 20.0, 30.0, 42.0, 55.0, 70.0)
"""Where the rendering is sized, 0 .. 252 km/h (the schedule is linear in between)."""
COUPLING_SHARES = (1.0, 0.7, 0.5, 0.35, 0.25, 0.18, 0.12)
"""Shares of the device's spring budget (and its damper) tried for the coupling, stiffest first."""
ZETA_FLOOR = 0.05
"""The least damping ratio a rendering keeps where the car itself is less damped (or unstable,
as the B-segment car's released wheel is near 250 km/h with its friction sliding)."""
GRID = 8
"""The scheduled damping is searched on this many steps of the room under the cap..."""
REFINE = 6
"""...then refined by this many bisections below the first step that passes."""
MODEL_STEP_S = 1e-3
"""The longest step the physical model takes (the presets check it is accurate at 1 ms)."""
MIN_RIM_SHARE = 0.2
"""The model's rim keeps at least this share of the car's rim inertia (a massless rim would be
a stiff mode the 1 ms step cannot integrate)."""


@dataclass(frozen=True, slots=True)
class PhysicalSizing:
    """How the physical model is put on this device (device units unless said)."""

    coupling_stiffness: float
    """K_c at the device, Nm/rad (in model units: K_c / fs * ps)."""
    coupling_damping: float
    schedule: tuple[tuple[float, float], ...]
    """(speed m/s, added damping Nm*s/rad at the device), rising speeds."""
    zeta: tuple[float, ...]
    """Per speed of the schedule, the least damping ratio of the loop over its linearizations
    (the car's own modes, those of the rim-clamped model, left out)."""
    goal: tuple[float, ...]
    """Per speed, what that ratio had to reach."""
    rim_inertia_kg_m2: float
    """The model's rim inertia in the loop (model units)."""
    share: float
    """The coupling's share of the device's spring budget."""
    wall_stiffness: float = 0.0
    """The wall inside the device's travel (where the car's lock lies beyond it), Nm/rad."""
    wall_damping: float = 0.0

    @property
    def top_speed_m_s(self) -> float:
        """The highest speed sized (the model's speed is held at it above)."""
        return self.schedule[-1][0]


def rendered_params(
    params: PhysicalParams,
    info: DeviceInfo,
    scaling: Scaling,
    sizing: Sizing,
    dt_s: float = MODEL_STEP_S,
) -> PhysicalParams:
    """The model with the rim inertia the device does not already have: the car's less the
    device's (model units), at least MIN_RIM_SHARE of the car's, and at least what keeps the
    rim's stiffest mode and its dampers (the torsion bar, the column's stick spring and damper,
    the stiffest coupling the device holds) within w*h, c*h/J <= 0.5 at the model's step, the
    presets' rule for the physical model (`io.preset_checks._check_steering_system`)."""
    system = params.system
    fs, ps = scaling.force_scale, scaling.position_scale
    car_rim = system.hand_wheel_inertia_kg_m2
    device_rim = info.mass * ps * ps / fs
    springs = (
        system.torsion_bar_stiffness_Nm_rad
        + system.friction_stiffness_Nm_rad
        + sizing.stiffness * ps / fs
    )
    dampers = (
        system.compensation_damping_Nm_s_rad
        + system.presliding_damping_Nm_s_rad
        + sizing.damping * ps / fs
    )
    step = max(springs * (dt_s / 0.5) ** 2, dampers * dt_s / 0.5)
    rim = max(MIN_RIM_SHARE * car_rim, car_rim - device_rim, step)
    return dataclasses.replace(
        params, system=dataclasses.replace(system, hand_wheel_inertia_kg_m2=rim)
    )


# ------------------------------------------------------------------ sizing (start-up, numpy)


def _sliding(params: PhysicalParams) -> PhysicalParams:
    """The model with its frictions sliding (a sliding friction is a constant torque: no
    spring, no damping), the park patches too."""
    return dataclasses.replace(
        params,
        system=dataclasses.replace(params.system, column_friction_Nm=0.0, rack_friction_Nm=0.0),
        tyres=dataclasses.replace(params.tyres, patch_radius_m=0.0),
    )


def assist_peak_torque(params: PhysicalParams, speed_m_s: float, ceiling_Nm: float) -> float:
    """The torsion-bar torque (up to `ceiling_Nm`) where the assist's gain d(boost)/dT is
    largest: just below the motor's limit, Nm; 0 where the assist cannot act."""
    s = params.system
    fade = speed_m_s / s.assist_fade_speed_m_s
    low = 1.0 / (1.0 + fade * fade)
    gain = (
        s.assist_gain_high_speed_1_Nm
        + (s.assist_gain_standstill_1_Nm - s.assist_gain_high_speed_1_Nm) * low
    )
    if gain <= 0.0:
        return 0.0
    saturates = s.assist_deadband_Nm + math.sqrt(s.max_assist_Nm / gain)
    top = min(0.98 * saturates, ceiling_Nm)
    return top if top > s.assist_deadband_Nm else 0.0


def operating_state(params: PhysicalParams, bar_torque_Nm: float) -> PhysicalState:
    """Straight ahead, still, with the torsion bar twisted to `bar_torque_Nm` (the frictions'
    anchors where their elements are relaxed)."""
    twist = bar_torque_Nm / params.system.torsion_bar_stiffness_Nm_rad
    start = physical.initial_state(params)
    return start._replace(hand_angle_rad=twist, column_anchor_rad=twist)


def linearize(
    params: PhysicalParams, speed_m_s: float, around: PhysicalState, dt_s: float
) -> tuple[Any, Any]:
    """(A, B) of the model hands off over one step around a state: x' = A x + B tau, x the
    state less the pose (`KEPT`), tau the hand's torque. Central differences."""
    import numpy as np

    def f(x: Any, torque: float) -> Any:
        full = list(around)
        for j, i in enumerate(KEPT):
            full[i] = float(x[j])
        new, _ = physical.step(
            PhysicalState(*full), PhysicalInputs(speed_m_s, 0.0, 0.0, torque, 0.0), params, dt_s
        )
        return np.array([new[i] for i in KEPT])

    x0 = np.array([around[i] for i in KEPT])
    n = len(KEPT)
    a = np.zeros((n, n))
    eps = 1e-7
    for j in range(n):
        e = np.zeros(n)
        e[j] = eps
        a[:, j] = (f(x0 + e, 0.0) - f(x0 - e, 0.0)) / (2 * eps)
    b = (f(x0, eps) - f(x0, -eps)) / (2 * eps)
    return a, b


RIM, RIM_RATE = KEPT.index(0), KEPT.index(1)


def coupled_environment(
    a: Any,
    b: Any,
    stiffness: float,
    damping: float,
    force_scale: float,
    position_scale: float,
    added: float,
    substeps: int,
    wall: tuple[float, float] = (0.0, 0.0),
) -> Any:
    """The linearized `coupled_step` as the sizing's environment (device units in and out)."""
    import numpy as np

    n = len(KEPT)

    def environment(state: Any, y: float, v: float) -> tuple[Any, float]:
        s = np.zeros(n) if state is None else np.asarray(state, dtype=float)
        angle, rate = y / position_scale, v / position_scale
        total = 0.0
        for _ in range(substeps):
            c = stiffness * (angle - s[RIM]) + damping * (rate - s[RIM_RATE])
            total += c
            s = a @ s + b * c
        return s, -force_scale * total / substeps - added * v - wall[0] * y - wall[1] * v

    return environment


def clamped_modes(a: Any, rate_hz: float) -> Any:
    """The s-plane poles of the model with its rim held still: modes of the car the rim does
    not take part in (the car's own low-speed lateral mode), which a rendering acting on the
    rim cannot damp."""
    import numpy as np

    keep = [i for i in range(a.shape[0]) if i not in (RIM, RIM_RATE)]
    poles = np.linalg.eigvals(a[np.ix_(keep, keep)])
    poles = poles[np.abs(poles) > 1e-9]
    return np.log(poles.astype(complex)) * rate_hz


def least_rim_damping(matrix: Any, rate_hz: float, clamped: Any) -> float:
    """The least damping ratio of the loop's poles, leaving out the pure delays, the free rest
    and the car's own modes: a pole within 5 % of one of the rim-clamped model's and no less
    damped than it (within 0.01; a rendering that makes such a mode worse is counted)."""
    import numpy as np

    worst = 1.0
    for z in np.linalg.eigvals(matrix):
        if abs(z) < 1e-9:
            continue
        s = complex(np.log(complex(z))) * rate_hz
        if abs(s) < 1e-6:
            continue
        zeta = -s.real / abs(s)
        if any(abs(c - s) < 0.05 * abs(s) and zeta >= -c.real / abs(c) - 0.01 for c in clamped):
            continue
        worst = min(worst, zeta)
    return worst


@dataclass(frozen=True)
class _Case:
    """One linearization of the rendered model, and what its loop must reach."""

    a: Any
    b: Any
    goal: float
    clamped: Any
    torque: float
    """The torsion-bar torque it is linearized at, Nm."""
    released: float
    """The car's own least damping ratio there (released offline, its own rim)."""


class _Sizer:
    """The loops of one device and model at the speeds a run can reach (see `size_physical`)."""

    def __init__(
        self,
        info: DeviceInfo,
        rate_hz: float,
        sections: Sections,
        params: PhysicalParams,
        scaling: Scaling,
        sizing: Sizing,
        substeps: int,
        speeds_m_s: tuple[float, ...],
    ) -> None:
        from carfeel.realtime import stability

        self.stability = stability
        self.plants = stability.plant_set(info, rate_hz, sections)
        """The device's uncertainty set: every linearization must hold on each of them."""
        self.device_goals = [stability.goal_of(p, ZETA_MIN) for p in self.plants]
        """Per plant, the most its loop can be asked for (less where the device alone rings:
        a stiff grip's mode, which no rendering damps through the delay)."""
        self.rate_hz, self.scaling, self.sizing, self.substeps = rate_hz, scaling, sizing, substeps
        self.speeds = speeds_m_s
        dt = 1.0 / rate_hz / substeps
        self.model = rendered_params(params, info, scaling, sizing, dt)
        ceiling = info.max_force / scaling.force_scale  # the most the device renders, model Nm
        self.cases: list[list[_Case]] = []
        for speed in speeds_m_s:
            per_speed = []
            for car, rendered in ((params, self.model), (_sliding(params), _sliding(self.model))):
                torques = [0.0]
                peak = assist_peak_torque(car, speed, ceiling)
                if peak > 0.0:
                    torques.append(peak)
                for torque in torques:
                    own, _ = linearize(car, speed, operating_state(car, torque), 1.0 / rate_hz)
                    clamped = clamped_modes(own, rate_hz)
                    released = least_rim_damping(own, rate_hz, clamped)
                    goal = max(ZETA_FLOOR, min(ZETA_MIN, released - 0.01))
                    a, b = linearize(rendered, speed, operating_state(rendered, torque), dt)
                    per_speed.append(_Case(a, b, goal, clamped, torque, released))
            self.cases.append(per_speed)

    def least(
        self,
        share: float,
        per_speed: list[_Case],
        added: float,
        wall: tuple[float, float] = (0.0, 0.0),
    ) -> tuple[float, float]:
        """(least margin zeta - goal, least zeta) over one speed's linearizations, with the
        coupling at `share` of the budget, `added` damping and a wall (device units)."""
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        k = share * self.sizing.stiffness * ps / fs  # model units
        c = share * self.sizing.damping * ps / fs
        worst = lowest = math.inf
        for case in per_speed:
            env = coupled_environment(case.a, case.b, k, c, fs, ps, added, self.substeps, wall)
            for plant, most in zip(self.plants, self.device_goals, strict=True):
                matrix = self.stability.closed_loop(plant, env, len(KEPT))
                zeta = least_rim_damping(matrix, self.rate_hz, case.clamped)
                worst, lowest = min(worst, zeta - min(case.goal, most)), min(lowest, zeta)
        return worst, lowest

    def added_damping(self, share: float, per_speed: list[_Case]) -> float | None:
        """The least added damping within the cap (less the coupling's) that gives every
        linearization its goal, or None. The margin need not grow with the damping (too much
        of it, delayed, rings the coupling's mode): the least passing value on a grid, then
        refined below it."""
        room = max(0.0, self.sizing.damping_cap - share * self.sizing.damping)
        grid = [room * i / GRID for i in range(GRID + 1)]
        passing = next(
            (i for i, b in enumerate(grid) if self.least(share, per_speed, b)[0] >= 0.0), None
        )
        if passing is None:
            return None
        if passing == 0:
            return 0.0
        low, high = grid[passing - 1], grid[passing]
        for _ in range(REFINE):
            middle = 0.5 * (low + high)
            ok = self.least(share, per_speed, middle)[0] >= 0.0
            low, high = (low, middle) if ok else (middle, high)
        return high

    def wall(self, share: float, schedule: list[tuple[float, float]]) -> tuple[float, float]:
        """The wall inside the device's travel: the device's spring budget (in parallel with
        the coupling there), halved until the loop pressed into it keeps ZETA_FLOOR at every
        speed (a safety stop; the on-centre goal does not describe a rim at the end of its
        travel)."""
        wall = (self.sizing.stiffness, self.sizing.damping)
        for _ in range(8):
            if all(
                self.least(share, per_speed, added, wall)[1] >= ZETA_FLOOR
                for (_, added), per_speed in zip(schedule, self.cases, strict=False)
            ):
                return wall
            wall = (0.5 * wall[0], 0.5 * wall[1])
        return (0.0, 0.0)

    def try_share(self, share: float, needs_wall: bool) -> tuple[PhysicalSizing | None, str]:
        """The sizing with the coupling at `share`, up to the first speed it cannot damp."""
        schedule, zetas, goals = [], [], []
        why = ""
        for speed, per_speed in zip(self.speeds, self.cases, strict=True):
            added = self.added_damping(share, per_speed)
            if added is None:
                why = (
                    f"a coupling of {share * self.sizing.stiffness:.3g} Nm/rad is not damped at "
                    f"{speed * 3.6:.0f} km/h"
                )
                break
            schedule.append((speed, added))
            goals.append(min(case.goal for case in per_speed))
            zetas.append(self.least(share, per_speed, added)[1])
        if not schedule:
            return None, why
        wall = self.wall(share, schedule) if needs_wall else (0.0, 0.0)
        sized = PhysicalSizing(
            share * self.sizing.stiffness, share * self.sizing.damping, tuple(schedule),
            tuple(zetas), tuple(goals), self.model.system.hand_wheel_inertia_kg_m2, share, *wall,
        )  # fmt: skip
        return sized, why


@functools.lru_cache(maxsize=32)
def size_physical(
    info: DeviceInfo,
    rate_hz: float,
    sections: Sections,
    params: PhysicalParams,
    scaling: Scaling,
    sizing: Sizing,
    substeps: int = 1,
    speeds_m_s: tuple[float, ...] = SPEEDS_M_S,
) -> PhysicalSizing | str:
    """The stiffest coupling, and the least scheduled damping, that keep the loop damped at
    every speed of `speeds_m_s` (see the module); where no share does, the one that reaches
    the highest speed (its `top_speed_m_s` says which), or the reason none reaches any."""
    sizer = _Sizer(info, rate_hz, sections, params, scaling, sizing, substeps, speeds_m_s)
    needs_wall = params.vehicle.steering_lock_rad * scaling.position_scale > 0.95 * info.travel
    best: PhysicalSizing | None = None
    reasons = []
    for share in COUPLING_SHARES:
        sized, why = sizer.try_share(share, needs_wall)
        if why:
            reasons.append(why)
        if sized is None:
            continue
        if len(sized.schedule) == len(speeds_m_s):
            return sized
        if best is None or len(sized.schedule) > len(best.schedule):
            best = sized
    return best if best is not None else "; ".join(reasons)


def resize_physical(
    info: DeviceInfo,
    rate_hz: float,
    sections: Sections,
    params: PhysicalParams,
    scaling: Scaling,
    sizing: Sizing,
    current: PhysicalSizing,
    substeps: int = 1,
) -> PhysicalSizing | str:
    """A tuned model's sizing on the running session's coupling: the same share of the spring
    budget and rim inertia (a running loop keeps its coupling; only the scheduled damping and
    the wall move, ramped), at the speeds `current` reaches up to the first it cannot damp (as
    start-up, its `top_speed_m_s` says where); or the reason it damps none."""
    speeds = tuple(v for v, _ in current.schedule)
    sizer = _Sizer(info, rate_hz, sections, params, scaling, sizing, substeps, speeds)
    rim = sizer.model.system.hand_wheel_inertia_kg_m2
    if not math.isclose(rim, current.rim_inertia_kg_m2, rel_tol=1e-9):
        return (
            f"the model's rim would need {rim:.3g} kg*m^2 (now {current.rim_inertia_kg_m2:.3g}): "
            "the coupling cannot change while the session runs"
        )
    sized, why = sizer.try_share(current.share, current.wall_stiffness > 0.0)
    if sized is None:
        return why or "the released wheel would not stay damped"
    return sized


def holds(
    info: DeviceInfo,
    rate_hz: float,
    sections: Sections,
    params: PhysicalParams,
    scaling: Scaling,
    sizing: Sizing,
    sized: PhysicalSizing,
    substeps: int = 1,
    floor: float = ZETA_FLOOR,
) -> str:
    """Empty when `sized` (its coupling and schedule, as given) keeps every linearization of
    `params` at least `floor` damped at every speed of its schedule; else where it does not.
    (For a passing moment, such as a tuning's ramp: the sizing's goals are for the feel.)"""
    speeds = tuple(v for v, _ in sized.schedule)
    sizer = _Sizer(info, rate_hz, sections, params, scaling, sizing, substeps, speeds)
    for (speed, added), per_speed in zip(sized.schedule, sizer.cases, strict=True):
        lowest = sizer.least(sized.share, per_speed, added)[1]
        if lowest < floor:
            return f"damping ratio {lowest:.2f} at {speed * 3.6:.0f} km/h, under {floor:g}"
    return ""


def car_stiffness(params: PhysicalParams, speed_m_s: float) -> float:
    """The car's on-centre torque per rim angle in steady state, Nm/rad at the rim (0 if it
    does not centre): the static gain of the model linearized with its rim imposed (hands on)
    and its frictions sliding, so their band is left out."""
    import numpy as np

    sliding = _sliding(params)
    around = operating_state(sliding, 0.0)
    n, eps = len(KEPT), 1e-7

    def f(x: Any, angle: float) -> tuple[Any, float]:
        full = list(around)
        for j, i in enumerate(KEPT):
            full[i] = float(x[j])
        inputs = PhysicalInputs(speed_m_s, angle, 0.0, 0.0, 1.0)
        new, out = physical.step(PhysicalState(*full), inputs, sliding, 1e-3)
        return np.array([new[i] for i in KEPT]), out.torque_Nm

    x0 = np.zeros(n)
    a, c = np.zeros((n, n)), np.zeros(n)
    for j in range(n):
        e = np.zeros(n)
        e[j] = eps
        (up, t_up), (down, t_down) = f(x0 + e, 0.0), f(x0 - e, 0.0)
        a[:, j], c[j] = (up - down) / (2 * eps), (t_up - t_down) / (2 * eps)
    (up, t_up), (down, t_down) = f(x0, eps), f(x0, -eps)
    b, d = (up - down) / (2 * eps), (t_up - t_down) / (2 * eps)
    # Held by the hands the rim cannot float: I - A is regular (the torsion bar ties the rack
    # to it, the anchors follow it).
    steady = np.linalg.solve(np.eye(n) - a, b)
    return max(0.0, float(c @ steady + d))


def felt_share(
    params: PhysicalParams, sized: PhysicalSizing, scaling: Scaling, speed_m_s: float
) -> float:
    """The share of the car's on-centre stiffness the coupling in series lets through."""
    k = sized.coupling_stiffness * scaling.position_scale / scaling.force_scale
    car = car_stiffness(params, speed_m_s)
    return k / (k + car)


def scheduled(table: tuple[tuple[float, float], ...], speed_m_s: float) -> float:
    """The schedule's value at a speed (linear between its speeds, held beyond)."""
    if speed_m_s <= table[0][0]:
        return table[0][1]
    for (v0, b0), (v1, b1) in itertools.pairwise(table):
        if speed_m_s <= v1:
            return b0 + (b1 - b0) * (speed_m_s - v0) / (v1 - v0)
    return table[-1][1]


TERMS = (
    "torque_aligning_Nm", "torque_jacking_Nm", "torque_park_Nm", "torque_friction_Nm",
    "torque_damping_Nm", "torque_inertia_Nm", "torque_stop_Nm", "torque_assist_Nm",
)  # fmt: skip
"""The model's contributions to `torque_Nm` (they sum to it), as offline."""


class PhysicalSteeringRenderer:
    """The physical steering model on a force-feedback wheel (see the module).

    Records, in model units (Nm at the car's rim): the model's rim angle and rate, Ay,
    `torque_Nm` (the coupling's torque: what the hand gives the model's rim; its terms sum to
    it), its terms, the torsion bar's torque, the road wheels' angle, the grip used per axle,
    yaw rate and sideslip, and the rendering's own: the coupling's stretch, the scheduled
    damping and the wall (divided by the torque scale), so that the command before the safety
    chain is -fs * (torque_Nm + rendering_damping_Nm + rendering_wall_Nm).
    """

    axes: int = 1
    columns: tuple[str, ...] = (
        "angle_device_rad", "steering_angle_rad", "steering_rate_rad_s", "lateral_accel_m_s2",
        "torque_Nm", "torque_filtered_Nm", *TERMS, "torsion_bar_torque_Nm",
        "front_wheel_angle_rad", "front_grip_used", "rear_grip_used", "yaw_rate_rad_s",
        "sideslip_rad", "coupling_stretch_rad", "rendering_damping_Nm", "rendering_wall_Nm",
    )  # fmt: skip
    takes_lateral_accel = False
    """Telemetry gives it the game's speed only (its Ay is its own tyres')."""

    def __init__(
        self,
        params: PhysicalParams,
        speed_m_s: float,
        scaling: Scaling,
        rate_hz: float,
        sized: PhysicalSizing,
        info: DeviceInfo,
    ) -> None:
        self.scaling, self.sized = scaling, sized
        fs, ps = scaling.force_scale, scaling.position_scale
        self.params = dataclasses.replace(
            params,
            system=dataclasses.replace(
                params.system, hand_wheel_inertia_kg_m2=sized.rim_inertia_kg_m2
            ),
        )
        self.top_speed = sized.top_speed_m_s
        self._speed = 0.0
        self.speed = speed_m_s
        self.state: PhysicalState | None = None
        """None until the first tick, which starts the model where the device is (after the
        calibration pulses the rim is a few degrees off centre: a model at 0 would meet it
        with the coupling's whole stiffness), the car in steady cornering at that angle."""
        self.reading = Reading(rate_hz)
        self.display = butterworth(DISPLAY_CUTOFF_HZ, rate_hz)
        self.gears: list[str] = []
        self.substeps = 1
        """Model steps per tick (the loop at 1 kHz, the model up to 10 kHz)."""
        self.effect = 0.0
        self.stiffness = sized.coupling_stiffness * ps / fs
        """The coupling in model units, Nm/rad (and Nm*s/rad below)."""
        self.damping = sized.coupling_damping * ps / fs
        self.wall_angle = 0.95 * info.travel
        """Device rad: where the wall starts (only where the car's lock lies beyond it)."""
        self.wall_stiffness = sized.wall_stiffness
        self.wall_damping = sized.wall_damping
        self._scheduled_for = math.nan
        self._added = 0.0

    @property
    def schedule(self) -> tuple[tuple[float, float], ...]:
        """(speed m/s, added damping Nm*s/rad at the device), as sized or retuned."""
        return self.sized.schedule

    @property
    def wall(self) -> tuple[float, float]:
        """The wall inside the travel: stiffness Nm/rad, damping Nm*s/rad (device units)."""
        return self.wall_stiffness, self.wall_damping

    def retune(
        self,
        params: PhysicalParams,
        schedule: tuple[tuple[float, float], ...],
        wall: tuple[float, float] | None = None,
    ) -> None:
        """New model parameters (the car's rim inertia is replaced by the loop's, as at
        start-up), damping schedule (its last speed the new top speed) and wall; the coupling
        and the model's state are kept.
        Between ticks (the panel's `Ramp`)."""
        self.params = dataclasses.replace(
            params,
            system=dataclasses.replace(
                params.system, hand_wheel_inertia_kg_m2=self.sized.rim_inertia_kg_m2
            ),
        )
        if wall is not None:
            self.wall_stiffness, self.wall_damping = wall
        self.top_speed = schedule[-1][0]  # a re-sizing may reach less far: held there
        self.speed = self._speed
        self.sized = dataclasses.replace(
            self.sized, schedule=schedule, wall_stiffness=self.wall_stiffness,
            wall_damping=self.wall_damping,
        )  # fmt: skip
        self._scheduled_for = math.nan

    @property
    def speed(self) -> float:
        """The model's speed, m/s: as set (the run's, or the game's), held at the highest
        speed the rendering was sized for."""
        return self._speed

    @speed.setter
    def speed(self, value: float) -> None:
        self._speed = max(0.0, min(value, self.top_speed))

    def tick(
        self, sample: DeviceSample, dt_s: float
    ) -> tuple[tuple[float, ...], tuple[object, ...]]:
        fs, ps = self.scaling.force_scale, self.scaling.position_scale
        speed = self._speed
        position, velocity = self.reading.step(sample.positions[0], dt_s)
        angle, rate = position / ps, velocity / ps
        k, c = self.stiffness, self.damping
        substeps = self.substeps
        state = self.state
        if state is None:
            state = physical_start(self.params, speed, angle)
        if substeps == 1:
            torque = k * (angle - state.hand_angle_rad) + c * (rate - state.hand_rate_rad_s)
            state, out = physical.step(
                state, PhysicalInputs(speed, 0.0, 0.0, torque, 0.0), self.params, dt_s
            )
            terms: tuple[float, ...] = out[4:12]
        else:  # the mean of each term over the tick (they still sum to the mean torque)
            h = dt_s / substeps
            sums = [0.0] * 8
            torque = 0.0
            for _ in range(substeps):
                applied = k * (angle - state.hand_angle_rad) + c * (rate - state.hand_rate_rad_s)
                torque += applied
                state, out = physical.step(
                    state, PhysicalInputs(speed, 0.0, 0.0, applied, 0.0), self.params, h
                )
                for i in range(8):
                    sums[i] += out[4 + i]
            torque /= substeps
            terms = tuple(v / substeps for v in sums)
        self.state = state
        if speed != self._scheduled_for:  # the schedule only changes with the speed
            self._scheduled_for = speed
            self._added = scheduled(self.sized.schedule, speed)
        added = self._added * velocity / fs
        wall = 0.0
        over = abs(position) - self.wall_angle
        if over > 0.0 and self.wall_stiffness > 0.0:
            outward = max(0.0, math.copysign(1.0, position) * velocity)
            wall = (
                math.copysign(self.wall_stiffness * over + self.wall_damping * outward, position)
                / fs
            )
        row = (
            sample.positions[0], out.steering_angle_rad, out.steering_rate_rad_s,
            out.lateral_accel_m_s2, torque, self.display.step(torque), *terms,
            out.torsion_bar_torque_Nm, out.front_wheel_angle_rad, out.front_grip_used,
            out.rear_grip_used, out.yaw_rate_rad_s, out.sideslip_rad,
            angle - out.steering_angle_rad, added, wall,
        )  # fmt: skip
        return (-(torque + added + wall) * fs,), row
