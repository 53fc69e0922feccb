"""A preset's cross-checks: what depends on several of its fields, each field already in its
range (`carfeel.schema`): the stages' order along the slot, the car's axles, the steering
system's modes at the loop's step, the H-pattern's walls' passivity at 1 kHz, a truck's table.

Each returns its problems as sentences (empty: the preset holds); the loader reports them all in
one PresetError, and the sweep makes a case that fails them an `invalid` row.
"""

from __future__ import annotations

import itertools
import math
from typing import Any

from carfeel.models.gearshift.hpattern import WALL_DEPTH_M, Layout
from carfeel.models.gearshift.synchronizer import LOCATIONS
from carfeel.simulation.hpattern import HPatternSetup
from carfeel.simulation.shift import ShiftParams
from carfeel.simulation.steering import SteeringCar

__all__ = [
    "CHECKED_SPEED_M_S",
    "NOMINAL_RATE_HZ",
    "STEERING_STEP_S",
    "check_hpattern",
    "check_shift",
    "check_steering",
]


def check_shift(params: ShiftParams) -> list[str]:
    """Problems a shift preset can have across parameters (each field already in range)."""
    g, d = params.gearbox, params.driver
    problems = []
    order = [
        ("gearbox.synchronization_position_m", g.synchronization_position_m),
        ("gearbox.teeth_position_m", g.teeth_position_m),
        ("gearbox.teeth_end_position_m", g.teeth_end_position_m),
        ("gearbox.in_gear_position_m", g.in_gear_position_m),
    ]
    for (name_a, a), (name_b, b) in itertools.pairwise(order):
        if not a < b:
            problems.append(
                f"{name_a} = {a:g} m must lie before {name_b} = {b:g} m: along the slot the "
                "synchro ring comes first, then the teeth, then the stop"
            )
    for stage in (
        "neutral",
        "gate_open",
        "engagement",
        "free_travel",
        "stop",
        "in_gear",
        "returning",
    ):
        mech = getattr(g, stage)
        if mech.sliding_friction_N > mech.static_friction_N:
            problems.append(
                f"gearbox.{stage}.sliding_friction_N = {mech.sliding_friction_N:g} N exceeds "
                f"gearbox.{stage}.static_friction_N = {mech.static_friction_N:g} N: allowed "
                "0 <= sliding <= static"
            )
    for stage in ("stop", "in_gear"):
        if getattr(g, stage).stiffness_N_m <= 0.0:
            problems.append(
                f"gearbox.{stage}.stiffness_N_m = 0 N/m: the {stage} stage is a spring around the "
                "in-gear position; allowed 0 < value <= 1e+07 N/m"
            )
    if g.in_gear.stiffness_N_m > g.stop.stiffness_N_m:
        problems.append(
            f"gearbox.in_gear.stiffness_N_m = {g.in_gear.stiffness_N_m:g} N/m exceeds "
            f"gearbox.stop.stiffness_N_m = {g.stop.stiffness_N_m:g} N/m: the lever settles from "
            "the stop into the detent, which may be softer but not stiffer"
        )
    held = g.stop.static_friction_N / g.stop.stiffness_N_m if g.stop.stiffness_N_m > 0 else 0.0
    if g.settle_distance_m <= held:
        problems.append(
            f"gearbox.settle_distance_m = {g.settle_distance_m:g} m must exceed the distance the "
            f"stop's static friction can hold the lever off x_gear ({held:.3g} m = "
            "gearbox.stop.static_friction_N / gearbox.stop.stiffness_N_m), or the lever may "
            "never count as settled in gear"
        )
    f_ref = g.synchronization_force_N
    if 0.0 < f_ref <= g.hold_force_N:
        problems.append(
            f"gearbox.synchronization_force_N = {f_ref:g} N must exceed the force that pushes the "
            f"sleeve back at the ring ({g.hold_force_N:.3g} N, gearbox.hold_force_N), or 0 for "
            "the paper's timer whatever the push"
        )
    room = g.in_gear_position_m - g.teeth_end_position_m
    if g.detent_release_m >= room:
        problems.append(
            f"gearbox.detent_release_m = {g.detent_release_m:g} m must be shorter than the travel "
            f"from the teeth to the gear ({room:g} m)"
        )
    tooth_max = g.engagement.static_friction_N + g.tooth_force_spread_N
    if tooth_max >= d.push_force_N:
        problems.append(
            "gearbox.engagement.static_friction_N + gearbox.tooth_force_spread_N = "
            f"{tooth_max:g} N "
            f"must stay below driver.push_force_N = {d.push_force_N:g} N, or a driver could stall "
            "on the teeth; the tooth peak is lower than the synchronization force (about 1/3 of it "
            "by a synchronizer design guideline)"
        )
    if g.neutral.static_friction_N >= d.push_force_N:
        problems.append(
            f"gearbox.neutral.static_friction_N = {g.neutral.static_friction_N:g} N must stay "
            f"below driver.push_force_N = {d.push_force_N:g} N, or the lever never leaves neutral"
        )
    if not g.teeth_end_position_m < d.release_position_m <= g.in_gear_position_m:
        problems.append(
            f"driver.release_position_m = {d.release_position_m:g} m: allowed "
            f"{g.teeth_end_position_m:g} < value <= {g.in_gear_position_m:g} m (past the teeth, "
            "at most the in-gear position)"
        )
    if d.neutral_position_m >= g.synchronization_position_m:
        problems.append(
            f"driver.neutral_position_m = {d.neutral_position_m:g} m: allowed "
            f"0 <= value < {g.synchronization_position_m:g} m (before the synchro ring)"
        )
    return problems


def check_steering(car: SteeringCar) -> list[str]:
    """Problems a steering preset can have across parameters (each field already in range)."""
    v = car.vehicle
    problems = []
    if v.cg_to_front_axle_m >= v.wheelbase_m:
        problems.append(
            f"vehicle.cg_to_front_axle_m = {v.cg_to_front_axle_m:g} m must be shorter than "
            f"vehicle.wheelbase_m = {v.wheelbase_m:g} m (the centre of gravity lies between the "
            "axles)"
        )
    elif v.understeer_gradient_rad_s2_m < 0.0:
        problems.append(
            f"the vehicle oversteers (understeer gradient {v.understeer_gradient_deg_per_g:.2f} "
            "deg/g): a linear oversteering car is unstable above its critical speed; raise "
            "vehicle.rear_cornering_stiffness_N_rad or move the centre of gravity forward"
        )
    # The tyres' lag at the slowest speed the tyre model runs: the trapezoidal rule rings on
    # modes much faster than its step, so they must stay slower than a millisecond.
    lateral = (
        v.mass_kg
        * v.kinematic_speed_m_s
        / (v.front_cornering_stiffness_N_rad + v.rear_cornering_stiffness_N_rad)
    )
    yaw = (
        v.yaw_inertia_kg_m2
        * v.kinematic_speed_m_s
        / (
            v.cg_to_front_axle_m**2 * v.front_cornering_stiffness_N_rad
            + v.cg_to_rear_axle_m**2 * v.rear_cornering_stiffness_N_rad
        )
        if v.cg_to_front_axle_m < v.wheelbase_m
        else 1.0
    )
    if min(lateral, yaw) < 1e-3:
        problems.append(
            f"at vehicle.kinematic_speed_m_s = {v.kinematic_speed_m_s:g} m/s the tyres' time "
            f"constant is {min(lateral, yaw) * 1e3:.3g} ms, under the 1 ms the model steps with; "
            "raise kinematic_speed_m_s or check the mass, inertia and cornering stiffnesses"
        )
    if (car.tyres is None) != (car.steering_system is None):
        problems.append(
            "the physical steering model needs both tables [tyres] and [steering_system] (or "
            "neither: the car then runs the paper's law only)"
        )
    elif car.steering_system is not None:
        problems.extend(_check_steering_system(car.steering_system))
    return problems


STEERING_STEP_S = 1e-3
"""The step the physical steering model must be accurate at (the 1 kHz loop)."""

CHECKED_SPEED_M_S = 100.0
"""The speed (360 km/h) up to which the EPS damping's rise with speed is checked at that step."""


def _check_steering_system(s: Any) -> list[str]:
    """Its semi-implicit Euler step must resolve the stiffest and most damped modes at 1 ms."""
    problems = []
    h = STEERING_STEP_S
    stiff = s.stop_stiffness_Nm_rad + s.torsion_bar_stiffness_Nm_rad + s.friction_stiffness_Nm_rad
    for name, inertia, stiffness, damping in (
        ("rack_inertia_kg_m2", s.rack_inertia_kg_m2, stiff,
         s.compensation_damping_Nm_s_rad + s.rack_damping_Nm_s_rad + s.stop_damping_Nm_s_rad
         + max(s.eps_damping_Nm_s_rad, s.eps_damping_high_speed_Nm_s_rad)
         + s.eps_damping_rise_Nm_s3_rad_m2 * CHECKED_SPEED_M_S**2
         + s.presliding_damping_Nm_s_rad),
        ("hand_wheel_inertia_kg_m2", s.hand_wheel_inertia_kg_m2,
         s.torsion_bar_stiffness_Nm_rad + s.friction_stiffness_Nm_rad,
         s.compensation_damping_Nm_s_rad + s.presliding_damping_Nm_s_rad),
    ):  # fmt: skip
        if math.sqrt(stiffness / inertia) * h > 0.5 or damping * h / inertia > 0.5:
            problems.append(
                f"steering_system.{name} = {inertia:g} kg*m^2 is too light for its springs "
                f"({stiffness:g} Nm/rad) and dampers ({damping:g} Nm*s/rad) at 1 ms steps: "
                "w*h and c*h/J must stay under 0.5; raise the inertia or soften the springs"
            )
    return problems


NOMINAL_RATE_HZ = 1000.0
"""Rate at which the walls must stay passive when a device renders them (the paper's 1 kHz)."""


def check_hpattern(setup: HPatternSetup, shift: ShiftParams) -> list[str]:
    """Problems of an H-pattern preset across parameters (each field already in range)."""
    layout, problems = setup.layout, []
    planes = layout.planes_y_m
    if not planes:
        return ["layout.planes_y_m is empty; give the y of each plane, m"]
    for a, b in itertools.pairwise(planes):
        if not b > a:
            problems.append(f"layout.planes_y_m must increase: {a:g} m then {b:g} m")
        elif b - a <= layout.slot_width_m:
            problems.append(
                f"layout: planes at {a:g} m and {b:g} m are closer than the slot width "
                f"{layout.slot_width_m:g} m: their slots overlap"
            )
    last = len(planes) - 1
    if layout.centre_plane > last:
        problems.append(
            f"layout.centre_plane = {layout.centre_plane}: the layout has planes 0..{last}"
        )
    seen: dict[tuple[int, int], str] = {}
    names: set[str] = set()
    for gear in layout.gears:
        if gear.name in names:
            problems.append(f"layout.gears: gear {gear.name!r} appears twice")
        names.add(gear.name)
        if gear.name == "N":
            problems.append("layout.gears: 'N' is neutral, not a gear name")
        if gear.direction not in (-1, 1):
            problems.append(
                f"layout.gears: gear {gear.name} has direction = {gear.direction}; "
                "allowed 1 (forward) or -1 (back)"
            )
        if gear.plane > last:
            problems.append(
                f"layout.gears: gear {gear.name} is on plane {gear.plane}, but the layout has "
                f"planes 0..{last}: no such plane"
            )
        where = (gear.plane, gear.direction)
        if where in seen:
            problems.append(
                f"layout.gears: gears {seen[where]} and {gear.name} share a slot (plane "
                f"{gear.plane}, direction {gear.direction}): slots overlap"
            )
        seen[where] = gear.name
        if gear.synchronizer not in LOCATIONS:
            problems.append(
                f"layout.gears: gear {gear.name} has synchronizer = {gear.synchronizer!r}; "
                f"allowed {', '.join(repr(x) for x in LOCATIONS)} (the shaft it sits on, or none)"
            )
        if gear.ratio == 0.0 or (gear.name == "R") != (gear.ratio < 0.0):
            problems.append(
                f"layout.gears: gear {gear.name} has ratio {gear.ratio:g}; reverse takes a "
                "negative ratio, forward gears a positive one"
            )
    if not layout.gears:
        problems.append("layout.gears is empty; give at least one [[layout.gears]]")
    if layout.reverse_lockout_N > 0.0:
        reverse = [g for g in layout.gears if g.name == "R"]
        shared = reverse and any(
            g.plane == reverse[0].plane and g.name != "R" for g in layout.gears
        )
        if not reverse or shared or reverse[0].plane not in (0, last) or last == 0:
            problems.append(
                f"layout.reverse_lockout_N = {layout.reverse_lockout_N:g} N needs reverse alone "
                "on an outer plane (as 6+R with R beyond 6); set it to 0 for this layout"
            )
    problems += _check_truck(layout) + _check_double_h(layout)
    g = shift.gearbox
    if layout.corridor_width_m / 2 + WALL_DEPTH_M >= g.synchronization_position_m:
        problems.append(
            f"layout.corridor_width_m = {layout.corridor_width_m:g} m: half of it, plus the "
            f"{WALL_DEPTH_M:g} m a wall gives, must stay short of the synchro ring at "
            f"{g.synchronization_position_m:g} m"
        )
    # The driver must be able to hold the farthest plane against the select spring (and the
    # lockout), with a fifth to spare for friction and the detents.
    if 0 <= layout.centre_plane <= last:
        centre = planes[layout.centre_plane]
        reach = max(abs(p - centre) for p in planes)
        boundary = layout.range_boundary_m() if 0 < layout.range_plane <= last else math.inf
        high = planes[min(layout.high_centre_plane, last)]
        if boundary < math.inf:  # a double-H: each half from its own neutral
            reach = max(abs(p - (centre if p < boundary else high)) for p in planes)
        needed = setup.select.centring_stiffness_N_m * reach + setup.select.static_friction_N
        lock = layout.lockout_plane if last > 0 else None
        if lock is not None:
            neighbour = lock - 1 if lock > 0 else lock + 1
            half_gap = abs(planes[lock] - planes[neighbour]) / 2
            needed += layout.reverse_lockout_N + setup.select.lockout_stiffness_N_m * half_gap
        if setup.driver.select_force_N < 1.2 * needed:
            problems.append(
                f"driver.select_force_N = {setup.driver.select_force_N:g} N cannot hold the "
                f"farthest plane: the select spring{' and the lockout' if lock is not None else ''}"
                f" need {needed:.1f} N there (with a fifth to spare: {1.2 * needed:.1f} N)"
            )
        if boundary < math.inf:
            cross = (
                layout.range_detent_N
                + setup.select.centring_stiffness_N_m * abs(boundary - centre)
                + setup.select.static_friction_N
            )
            if setup.driver.select_force_N < 1.2 * cross:
                problems.append(
                    f"driver.select_force_N = {setup.driver.select_force_N:g} N cannot cross "
                    f"the range detent: it and the select spring need {cross:.1f} N there "
                    f"(with a fifth to spare: {1.2 * cross:.1f} N)"
                )
            if not math.isclose(boundary - centre, high - boundary, abs_tol=1e-6):
                problems.append(
                    f"layout: the double-H's neutrals lie {1e3 * (boundary - centre):g} mm and "
                    f"{1e3 * (high - boundary):g} mm from the range detent; they must be equally "
                    "far (else the select spring's energy jumps as the knob crosses)"
                )
    feel = setup.feel
    first, last_latch = (
        feel.latch_position_m - feel.latch_width_m,
        feel.latch_position_m + feel.latch_width_m,
    )
    if not (layout.corridor_width_m / 2 < first and last_latch < g.synchronization_position_m):
        problems.append(
            f"feel.latch_position_m = {feel.latch_position_m:g} m +- latch_width_m = "
            f"{feel.latch_width_m:g} m must lie in the slot before the synchro ring: between "
            f"{layout.corridor_width_m / 2:g} m and {g.synchronization_position_m:g} m"
        )
    spacing = min((b - a for a, b in itertools.pairwise(planes)), default=math.inf)
    if setup.select.detent_width_m >= spacing / 2:
        problems.append(
            f"select.detent_width_m = {setup.select.detent_width_m:g} m must be under half the "
            f"plane spacing ({spacing / 2:g} m)"
        )
    # Sampled-wall passivity (Colgate & Schenkel): K*T/2 + B < b, b the lever's own damping.
    period = 1.0 / NOMINAL_RATE_HZ
    lever_damping = min(
        [getattr(g, s).damping_N_s_m for s in ("neutral", "gate_open", "engagement",
                                                "free_travel", "returning")]
        + [setup.select.damping_N_s_m]
    )  # fmt: skip
    for label, k, b in (
        ("walls", setup.walls.stiffness_N_m, setup.walls.damping_N_s_m),
        ("select.slot", setup.select.slot_stiffness_N_m, setup.select.slot_damping_N_s_m),
    ):
        need = k * period / 2 + b
        if need >= lever_damping:
            problems.append(
                f"{label}: stiffness {k:g} N/m and damping {b:g} N*s/m need a lever damping "
                f"above K*T/2 + B = {need:g} N*s/m at {NOMINAL_RATE_HZ:g} Hz to stay passive "
                f"when rendered, but the lever's least damping is {lever_damping:g} N*s/m"
            )
    return problems


def _check_truck(layout: Layout) -> list[str]:
    """A range/splitter table: every row on a slot of the layout, each slot's combination once,
    the signs of its gear and ratio the slot's, one handle position per slot."""
    problems: list[str] = []
    slots = {g.name: g for g in layout.gears}
    seen: set[tuple[str, bool, bool]] = set()
    handles: dict[str, int] = {}
    for row in layout.truck:
        where = f"layout.truck: slot {row.slot!r} (range {'high' if row.range_high else 'low'}, "
        where += f"splitter {'high' if row.splitter_high else 'low'})"
        slot = slots.get(row.slot)
        if slot is None:
            problems.append(f"{where}: no such slot; the layout has {', '.join(slots)}")
            continue
        key = (row.slot, row.range_high, row.splitter_high)
        if key in seen:
            problems.append(f"{where} appears twice")
        seen.add(key)
        if (
            row.gear == 0
            or row.ratio == 0.0
            or (row.gear < 0) != (slot.ratio < 0.0)
            or (row.ratio < 0.0) != (slot.ratio < 0.0)
        ):
            problems.append(
                f"{where}: gear {row.gear}, ratio {row.ratio:g}: a reverse slot takes a "
                "negative gear and ratio, a forward slot positive ones"
            )
        if handles.setdefault(row.slot, row.handle_position) != row.handle_position:
            problems.append(
                f"{where}: handle_position {row.handle_position}, but another row of the slot "
                f"has {handles[row.slot]}: one handle position per slot"
            )
    missing = [name for name in slots if layout.truck and name not in handles]
    if missing:
        problems.append(f"layout.truck: no row for slot {', '.join(missing)}: the lever could "
                        "not engage it in any range")  # fmt: skip
    return problems


def _check_double_h(layout: Layout) -> list[str]:
    """A double-H: the high half's first plane, its neutral in it, the low neutral below it."""
    last = len(layout.planes_y_m) - 1
    if layout.range_plane == 0:
        if layout.range_detent_N > 0.0 or layout.high_centre_plane:
            return ["layout.range_detent_N and high_centre_plane need layout.range_plane (the "
                    "first plane of a double-H's high half)"]  # fmt: skip
        return []
    if not 0 < layout.range_plane <= last:
        return [f"layout.range_plane = {layout.range_plane}: a double-H's high half starts on "
                f"plane 1..{last}"]  # fmt: skip
    problems = []
    if not layout.range_plane <= layout.high_centre_plane <= last:
        problems.append(
            f"layout.high_centre_plane = {layout.high_centre_plane}: the high half's neutral "
            f"is one of its planes, {layout.range_plane}..{last}"
        )
    if layout.centre_plane >= layout.range_plane:
        problems.append(
            f"layout.centre_plane = {layout.centre_plane}: the low half's neutral is one of "
            f"its planes, 0..{layout.range_plane - 1}"
        )
    return problems
