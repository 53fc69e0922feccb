"""Synchronizer, clutch and gearbox input shaft: when may the synchro gate open?

Two modes (`SynchronizerParams.physics`):
- fixed (the paper's, the default): the engagement model's own timer opens the gate after its
  synchronization duration of pushing, provided the clutch is pressed past `clutch_open_above`;
  with the clutch less pressed the gate never opens.
- physics: the gate opens when the cone has matched the speeds. The input shaft (clutch disc,
  input shaft and the gears it drives, inertia J at the input shaft, speed w_in) is acted on by

      J * dw_in/dt = T_clutch + T_cone / |r| - T_drag
      T_clutch = C * clamp((p_open - pedal) / p_open, 0, 1)   toward the engine speed
      T_cone   = mu * F_axial * R_cone / sin(alpha),  F_axial = lever_ratio * F_knob
                                                              toward w_out * r (the target gear)
      T_drag                                                  toward 0 (bearings, oil)

  each a Coulomb torque that does not overshoot its own target within a step. The gate opens when
  |w_in - w_out * r| < `speed_tolerance_rad_s`, w_out = V / wheel_radius * final_drive. So the
  time is J * |dw| * |r| / T_cone: pushing harder shortens it; a downshift (larger target r, larger
  speed step) takes longer than an upshift at the same speed; a clutch not pressed far enough
  drags the shaft toward the engine harder than the cone can pull it: no synchronization (balk).

Where the synchronizer sits (per gear, `SynchronizerInputs.location`): on the output shaft (the
gear idles on it, driven by the input shaft: the cone torque reaches the input shaft divided by
the ratio, as above) or on the input shaft (front-drive transaxles often put 3-4 and 5 there: the
cone acts on the input shaft directly, T_cone instead of T_cone / |r|, so the time changes by
the ratio), or none. Reverse (a negative ratio) has no synchronizer, as in most manual boxes: it
goes in only when the input shaft and the car have (nearly) stopped; in the fixed mode, only at
standstill. The knob force reaches the sleeve through the linkage: F_axial = lever_ratio *
linkage_efficiency * F_knob.

Grinding (both modes) means the blocking condition has failed: the gear has no synchronizer, or
the ring has no blocking margin left (`blocking_margin` <= 0: a worn ring, low friction; the
margin is the cone torque over the indexing torque of the blocker chamfers, less one, and does
not depend on the force). A sound ring balks silently, whatever the clutch does. While the speeds
differ and the driver pushes harder than `grind_force_N`, the sleeve's dog teeth then chatter on
the gear's: a vibration of amplitude `grind_amplitude_N` at the tooth-passing frequency
n_teeth * |w_in / r - w_out| / (2 pi), rendered up to a quarter of the step rate (beyond, a
sampled vibration would alias), felt on top of the balk. The ring itself still blocks: a balk is
a wall, the grinding only a vibration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

OUTPUT = "output"
INPUT = "input"
NONE = "none"
LOCATIONS = (OUTPUT, INPUT, NONE)
"""Where a gear's synchronizer sits: on the output shaft, the input shaft, or none."""


@dataclass(frozen=True, slots=True)
class SynchronizerParams:
    physics: bool
    """true: the gate opens when the cone has matched the speeds; false: the engagement's own timer
    (the paper's)."""
    input_inertia_kg_m2: float
    """Inertia J at the input shaft: the clutch disc, the input shaft and the gears it drives."""
    cone_friction: float
    """Friction coefficient mu of the synchronizer cone."""
    cone_radius_m: float
    """Mean radius R_cone of the synchronizer cone."""
    cone_half_angle_rad: float
    """Half-angle alpha of the cone: T_cone = mu * F_axial * R_cone / sin(alpha)."""
    lever_ratio: float
    """Knob travel per unit of sleeve travel (the ideal force ratio)."""
    linkage_efficiency: float
    """Share of the knob's work the linkage passes to the sleeve (0.7-0.9, SAE 932996)."""
    blocking_margin: float
    """Cone torque over the blocker's indexing torque, less one; <= 0: the ring cannot block."""
    clutch_capacity_Nm: float
    """Torque the clutch transmits with the pedal released."""
    clutch_open_above: float
    """Pedal position (0 released .. 1 pressed) beyond which the clutch transmits nothing."""
    drag_torque_Nm: float
    """Drag torque T_drag slowing the input shaft toward 0 (bearings, oil)."""
    speed_tolerance_rad_s: float
    """Speeds count as matched when |w_in - w_out * r| is below this (the gate opens in physics
    mode)."""
    grind_force_N: float
    """A push beyond this grinds while the speeds differ and the blocking has failed (no
    synchronizer, or no margin)."""
    grind_amplitude_N: float
    """Amplitude of the grinding vibration at the knob."""
    dog_teeth: int
    """Number of dog teeth: the grinding's frequency is this times the gear's speed difference
    over 2 pi."""
    final_drive_ratio: float
    """Final drive ratio: the output shaft turns at w_out = V / wheel_radius_m * this."""
    wheel_radius_m: float
    """Rolling radius of the driven wheels (for the output shaft speed w_out)."""


class SynchronizerState(NamedTuple):
    input_speed_rad_s: float
    grind_phase_rad: float


class SynchronizerInputs(NamedTuple):
    vehicle_speed_m_s: float
    engine_speed_rad_s: float
    clutch_pedal: float
    """0 released .. 1 pressed to the floor."""
    ratio: float | None
    """Ratio of the gear whose slot the lever is in (None: none selected)."""
    locked: bool
    """The gear is in mesh: the input shaft turns with the output through `ratio`."""
    axial_force_N: float
    """Knob force pressing the synchronizer ring (0 unless the ring blocks the lever)."""
    location: str = OUTPUT
    """Where the selected gear's synchronizer sits: OUTPUT, INPUT or NONE."""
    cone_scale: float = 1.0
    """The selected gear's cone torque relative to `cone_torque_Nm` (more or larger cones)."""


class SynchronizerOutputs(NamedTuple):
    gate_open: bool | None
    """For the engagement model: None (fixed mode, clutch pressed: its own timer), True or False."""
    speed_difference_rad_s: float
    """w_in - w_out * ratio at the input shaft (0 without a selected gear)."""
    grind_N: float


def initial_state(input_speed_rad_s: float = 0.0) -> SynchronizerState:
    return SynchronizerState(input_speed_rad_s, 0.0)


def output_speed_rad_s(vehicle_speed_m_s: float, params: SynchronizerParams) -> float:
    """Gearbox output shaft speed for a vehicle speed, rad/s."""
    return vehicle_speed_m_s / params.wheel_radius_m * params.final_drive_ratio


def cone_torque_Nm(axial_force_N: float, params: SynchronizerParams) -> float:
    """Friction torque of the cone for a knob force (positive), Nm."""
    return (
        params.cone_friction
        * params.lever_ratio
        * params.linkage_efficiency
        * max(axial_force_N, 0.0)
        * params.cone_radius_m
        / math.sin(params.cone_half_angle_rad)
    )


def _toward(speed: float, target: float, change: float) -> float:
    """Move `speed` toward `target` by at most `change` (a Coulomb torque's step)."""
    if speed < target:
        return min(target, speed + change)
    return max(target, speed - change)


def step(
    state: SynchronizerState,
    inputs: SynchronizerInputs,
    params: SynchronizerParams,
    dt_s: float,
) -> tuple[SynchronizerState, SynchronizerOutputs]:
    p = params
    w_out = output_speed_rad_s(inputs.vehicle_speed_m_s, p)
    w_in = state.input_speed_rad_s
    ratio = inputs.ratio
    j = p.input_inertia_kg_m2
    engaged = (p.clutch_open_above - inputs.clutch_pedal) / p.clutch_open_above
    clutch = p.clutch_capacity_Nm * min(1.0, max(0.0, engaged))
    # Reverse (a negative ratio) has no synchronizer, as in most manual boxes: no cone.
    location = inputs.location
    synchronized_gear = ratio is not None and ratio > 0.0 and location != NONE
    cone = 0.0
    if synchronized_gear and inputs.axial_force_N > 0.0:
        cone = cone_torque_Nm(inputs.axial_force_N, p) * inputs.cone_scale
        if location == OUTPUT:  # the gear turns at w_in / r: its torque reaches w_in / r
            cone /= abs(ratio)  # type: ignore[arg-type]
    if ratio is not None and inputs.locked:
        w_in = w_out * ratio
    else:
        w_in = _toward(w_in, inputs.engine_speed_rad_s, clutch * dt_s / j)
        if cone > 0.0:
            w_in = _toward(w_in, w_out * ratio, cone * dt_s / j)  # type: ignore[operator]
        w_in = _toward(w_in, 0.0, p.drag_torque_Nm * dt_s / j)
    if ratio is None:
        return SynchronizerState(w_in, 0.0), SynchronizerOutputs(False, 0.0, 0.0)
    difference = w_in - w_out * ratio
    matched = -p.speed_tolerance_rad_s < difference < p.speed_tolerance_rad_s
    clutch_open = inputs.clutch_pedal >= p.clutch_open_above
    gate: bool | None
    if p.physics:
        gate = matched
    elif not clutch_open:
        gate = False  # the paper's timer runs only with the clutch pressed far enough
    elif not synchronized_gear and abs(w_out) * abs(ratio) > p.speed_tolerance_rad_s:
        gate = False  # reverse without a synchronizer: only at standstill
    else:
        gate = None
    # Grinding needs a blocking condition that has failed: no synchronizer, or no margin left.
    # A sound ring blocks silently, also while the clutch drags harder than the cone pulls.
    failed = not synchronized_gear or p.blocking_margin <= 0.0
    balked = failed and (not matched if p.physics else gate is False)
    phase = state.grind_phase_rad
    grind = 0.0
    if balked and inputs.axial_force_N > p.grind_force_N:
        # The dog teeth pass at n * |dw| at the gear; rendered at most at a quarter of the step
        # rate (a 1 kHz loop cannot show 700 Hz: it would alias to a falling pitch).
        teeth_rate = p.dog_teeth * abs(difference / ratio)
        teeth_rate = min(teeth_rate, 0.5 * math.pi / dt_s)
        phase = (phase + teeth_rate * dt_s) % (2.0 * math.pi)
        grind = p.grind_amplitude_N * math.sin(phase)
    return SynchronizerState(w_in, phase), SynchronizerOutputs(gate, difference, grind)
