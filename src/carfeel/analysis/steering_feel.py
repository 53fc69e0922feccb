"""Steering feel metrics from any run or log (after ISO 13674-1's on-centre measures).

From the samples of speed V, steering wheel angle delta_w, lateral acceleration Ay and steering
torque T (signs: positive to the left), with Ay in g (9.80665 m/s^2):

- The loop T(Ay) is split into its two branches by the sign of dAy/dt (Ay rising, Ay falling).
  On each branch a straight line is fitted on centre, |Ay| <= 0.1 g.
- torque_gradient_Nm_per_g: the mean of the two branches' slopes at 0 g.
- hysteresis_Nm ("torque at 0 g"): half the gap between the branches at Ay = 0.
- deadband_g ("Ay at 0 torque"): half the gap between the branches at T = 0.
- torque_at_0_1g_Nm: the torque at +0.1 g and -0.1 g (a line fitted on each branch within
  0.08..0.12 g), averaged over both branches and both sides (sign taken out).
- sensitivity_g_per_100deg: the slope of Ay against delta_w on centre (both branches), per 100 deg.
- understeer_gradient_deg_per_g: the slope K_us of delta_w/SR - L*Ay/V^2 against Ay (steady-state
  cornering, delta = L/R + K_us*Ay), over V > 5 m/s and |Ay| <= 4 m/s^2; it needs the car's
  steering ratio SR and wheelbase L.
A metric the data cannot give (no on-centre samples, a single branch, no speed) is NaN, with a note
saying why.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np
import numpy.typing as npt

from carfeel.models.vehicle.single_track import STANDARD_GRAVITY_M_S2

G = STANDARD_GRAVITY_M_S2
ON_CENTRE_G = 0.1
MIN_SAMPLES = 10
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True)
class SteeringFeel:
    torque_gradient_Nm_per_g: float
    torque_at_0_1g_Nm: float
    deadband_g: float
    hysteresis_Nm: float
    sensitivity_g_per_100deg: float
    understeer_gradient_deg_per_g: float
    notes: tuple[str, ...] = field(default=())

    def as_dict(self) -> dict[str, float]:
        """The six metrics by name (NaN as None is left to the JSON writer)."""
        values = asdict(self)
        values.pop("notes")
        return values


def _line(x: FloatArray, y: FloatArray) -> tuple[float, float]:
    """Least-squares (slope, intercept) of y against x."""
    slope, intercept = np.polyfit(x, y, 1)
    return float(slope), float(intercept)


def _branches(ay_g: FloatArray, time_s: FloatArray) -> list[npt.NDArray[np.bool_]]:
    rate = np.gradient(ay_g, time_s)
    return [rate > 0.0, rate < 0.0]


def steering_feel(
    time_s: FloatArray,
    speed_m_s: FloatArray,
    steering_angle_rad: FloatArray,
    lateral_accel_m_s2: FloatArray,
    torque_Nm: FloatArray,
    *,
    steering_ratio: float | None = None,
    wheelbase_m: float | None = None,
) -> SteeringFeel:
    """The six feel metrics of a run or log (see the module docstring for definitions)."""
    notes: list[str] = []
    nan = math.nan
    ay_g = lateral_accel_m_s2 / G
    moving = speed_m_s > 1.0
    centre = moving & (np.abs(ay_g) <= ON_CENTRE_G)

    slopes, at_zero_ay, at_zero_torque, at_01 = [], [], [], []
    for branch in _branches(ay_g, time_s):
        sel = centre & branch
        if sel.sum() < MIN_SAMPLES or np.ptp(ay_g[sel]) < 0.05:
            continue
        slope, intercept = _line(ay_g[sel], torque_Nm[sel])
        slopes.append(slope)
        at_zero_ay.append(intercept)
        at_zero_torque.append(-intercept / slope if slope != 0.0 else nan)
        for side in (1.0, -1.0):
            near = moving & branch & (np.abs(ay_g - side * ON_CENTRE_G) <= 0.02)
            if near.sum() >= MIN_SAMPLES and np.ptp(ay_g[near]) > 0.01:
                s, c = _line(ay_g[near], torque_Nm[near])
                at_01.append(side * (s * side * ON_CENTRE_G + c))
    if len(slopes) == 2:
        gradient = float(np.mean(slopes))
        hysteresis = abs(at_zero_ay[0] - at_zero_ay[1]) / 2
        deadband = abs(at_zero_torque[0] - at_zero_torque[1]) / 2
    elif len(slopes) == 1:
        gradient, hysteresis, deadband = slopes[0], nan, nan
        notes.append("Ay crosses the centre one way only: no hysteresis or deadband")
    else:
        gradient = hysteresis = deadband = nan
        notes.append("too few on-centre samples (|Ay| <= 0.1 g, V > 1 m/s) for the torque gradient")
    torque_01 = float(np.mean(at_01)) if at_01 else nan
    if not at_01:
        notes.append("Ay does not sweep through 0.1 g: no torque at 0.1 g")

    if centre.sum() >= MIN_SAMPLES and np.ptp(steering_angle_rad[centre]) > 0.0:
        per_deg, _ = _line(np.degrees(steering_angle_rad[centre]), ay_g[centre])
        sensitivity = per_deg * 100.0
    else:
        sensitivity = nan
        notes.append("no on-centre steering to measure the sensitivity from")

    understeer = nan
    if steering_ratio is None or wheelbase_m is None:
        notes.append("understeer gradient needs the car's steering ratio and wheelbase")
    else:
        sel = (speed_m_s > 5.0) & (np.abs(lateral_accel_m_s2) <= 4.0)
        if sel.sum() >= MIN_SAMPLES and np.ptp(lateral_accel_m_s2[sel]) > 0.5:
            ay = lateral_accel_m_s2[sel]
            beyond_ackermann = (
                steering_angle_rad[sel] / steering_ratio - wheelbase_m * ay / speed_m_s[sel] ** 2
            )
            k_us, _ = _line(ay, beyond_ackermann)
            understeer = math.degrees(k_us) * G
        else:
            notes.append("too little cornering (V > 5 m/s, Ay range > 0.5 m/s^2) for understeer")
    return SteeringFeel(
        gradient, torque_01, deadband, hysteresis, sensitivity, understeer, tuple(notes)
    )
