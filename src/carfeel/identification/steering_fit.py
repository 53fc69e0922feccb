"""Fit the steering torque law (K1..K9 of eqs. 4-7) to measured logs by robust least squares.

A log has `time_s, speed_m_s, steering_angle_rad, steering_torque_Nm` and optionally
`lateral_accel_m_s2` (used when present; else the car's steady-state Ay from speed and angle,
`Ay = V^2 * delta / (L * (1 + K * V^2))`) and `steering_rate_rad_s` (else derived: a
Savitzky-Golay derivative, quadratic over 81 ms, on each stretch of the log between gaps, which
differentiates without amplifying the angle sensor's noise the way a plain difference does).

The fit is `scipy.optimize.least_squares` with an analytic Jacobian, bounds that keep each term
physically signed (every K >= 0 and the scales > 0), and the robust 'soft_l1' loss, so spikes
and dropouts do not drag it; a torque offset (a torque sensor's zero error) is fitted beside
K1..K9 and reported, not kept. Starting values come from the data: K1 from the slope of torque
on Ay while the wheel barely turns, K9 from the slope on the rate while it turns fast, the
friction level from the rest, the tyre-spin scale from parking (V < 2 m/s) if there is any.
Uncertainties are one standard deviation from the Jacobian at the solution (the Gauss-Newton
covariance scaled by the residual variance): statistical only, so a systematic error (a derived
rate's lag, a model the car does not follow) can exceed them. A parameter the data cannot pin down
gets a warning: the tyre-spin terms K4..K6 without parking manoeuvres, the saturation K2, K3 without
lateral accelerations beyond 3 m/s^2, any parameter whose uncertainty exceeds half its value
(infinite where the data leave a direction unconstrained) or that stops at a bound. Before the fit,
logs whose units or signs would fit well but wrongly are refused or warned about (`_check_units`: Ay
against the car's steady state, torque rising with Ay, speeds above 250 km/h); after it, r2 under
0.5 is warned about.
With `fit_vehicle` (and no measured Ay) the understeer gradient is fitted too (the speed steps of
a steady-state test separate it from K1), and the preset's rear cornering stiffness is set to give
it. The steering ratio is not fitted: in the linear range K1 * Ay ~ K1 / SR, so the two trade
exactly; take SR from the car's data.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification import rms_r2
from carfeel.models.steering.torque import SteeringTorqueParams, torque_terms
from carfeel.models.vehicle.single_track import VehicleParams
from carfeel.simulation.result import Result
from carfeel.simulation.steering import SteeringCar

FloatArray = npt.NDArray[np.float64]
REQUIRED = ("time_s", "speed_m_s", "steering_angle_rad", "steering_torque_Nm")
K_NAMES = ("k1_Nm_s2_m", "k2", "k3", "k4_1_Nm", "k5_s_m_Nm", "k6_rad_s", "k7_Nm", "k8_rad_s",
           "k9_Nm_s_rad")  # fmt: skip
LOWER = (1e-3, 0.0, 0.3, 1e-2, 0.0, 1e-2, 0.0, 1e-3, 0.0)
UPPER = (50.0, 10.0, 3.0, 100.0, 100.0, 10.0, 20.0, 5.0, 5.0)
SAVGOL_WINDOW_S = 0.081
PARKING_SPEED_M_S = 2.0
MAX_SAMPLE_PERIOD_S = 0.05
"""20 Hz: slower logs cannot show the friction and damping terms (and ms read as s land here)."""


@dataclass(frozen=True)
class SteeringLog:
    """One log's signals in SI units, checked, with the rate and Ay it will be fitted with."""

    name: str
    time_s: FloatArray
    speed_m_s: FloatArray
    angle_rad: FloatArray
    rate_rad_s: FloatArray
    torque_Nm: FloatArray
    lateral_accel_m_s2: FloatArray | None


@dataclass(frozen=True)
class Estimate:
    name: str
    value: float
    sigma: float
    """One standard deviation."""


@dataclass(frozen=True)
class SteeringFit:
    car: SteeringCar
    estimates: tuple[Estimate, ...]
    torque_offset_Nm: float
    rms_error_Nm: float
    r2: float
    per_log: dict[str, dict[str, float]]
    """Per log: rms_error_Nm, r2, mean residual (the bias left), samples."""
    warnings: tuple[str, ...]
    iterations: int

    def as_dict(self) -> dict[str, object]:
        return {
            "parameters": {e.name: {"value": e.value, "sigma": e.sigma} for e in self.estimates},
            "torque_offset_Nm": self.torque_offset_Nm,
            "rms_error": self.rms_error_Nm,
            "rms_error_unit": "N m",
            "r2": self.r2,
            "per_log": self.per_log,
            "warnings": list(self.warnings),
            "iterations": self.iterations,
        }


def savgol_rate(time_s: FloatArray, angle_rad: FloatArray) -> FloatArray:
    """d(angle)/dt by a quadratic Savitzky-Golay filter over about 81 ms, per gap-free stretch."""
    from scipy.signal import savgol_filter

    rate = np.zeros_like(angle_rad)
    steps = np.diff(time_s)
    dt = float(np.median(steps))
    cuts = np.concatenate([[0], np.flatnonzero(steps > 1.5 * dt) + 1, [len(time_s)]])
    window = max(5, round(SAVGOL_WINDOW_S / dt) | 1)
    for a, b in itertools.pairwise(cuts):
        n = b - a
        if n >= window:
            rate[a:b] = savgol_filter(angle_rad[a:b], window, 2, deriv=1, delta=dt)
        elif n > 1:
            rate[a:b] = np.gradient(angle_rad[a:b], time_s[a:b])
    return rate


def read_log(result: Result, name: str) -> SteeringLog:
    """Check a log's columns, units and samples; derive what is missing. `torque_Nm` (what
    `carfeel simulate steering` writes) stands for steering_torque_Nm when that is absent."""
    if "steering_torque_Nm" not in result.names and "torque_Nm" in result.names:
        result = Result(
            result.time_s,
            {
                ("steering_torque_Nm" if k == "torque_Nm" else k): v
                for k, v in result.signals.items()
            },
            result.metadata,
        )
    missing = [c for c in REQUIRED if c not in result.names]
    if missing:
        raise InputError(
            f"{name}: missing column(s) {', '.join(missing)}; a steering log needs "
            f"{', '.join(REQUIRED)} (s, m/s, rad, Nm), and may have lateral_accel_m_s2 and "
            "steering_rate_rad_s"
        )
    columns = [*REQUIRED] + [
        c for c in ("lateral_accel_m_s2", "steering_rate_rad_s") if c in result.names
    ]
    for column in columns:
        values = result[column]
        if values.dtype.kind != "f":
            raise InputError(f"{name}: column {column} must hold numbers")
    time = result.time_s
    if len(time) < 50:
        raise InputError(f"{name}: {len(time)} samples; a fit or a validation needs at least 50")
    if np.any(np.diff(time) <= 0):
        row = int(np.flatnonzero(np.diff(time) <= 0)[0]) + 3
        raise InputError(f"{name}, line {row}: time_s does not increase")
    period = float(np.median(np.diff(time)))
    if period > MAX_SAMPLE_PERIOD_S:
        raise InputError(
            f"{name}: a sample every {period:.3g} s; the fit needs at least "
            f"{1 / MAX_SAMPLE_PERIOD_S:.0f} Hz. If time_s is in milliseconds, divide it by 1000"
        )
    keep = np.ones(len(time), dtype=bool)
    for column in columns:
        keep &= np.isfinite(result[column])
    if keep.sum() < 0.5 * len(time):
        raise InputError(f"{name}: more than half of the rows hold NaN; check the logger")
    angle = result["steering_angle_rad"][keep]
    speed = result["speed_m_s"][keep]
    torque = result["steering_torque_Nm"][keep]
    if np.max(np.abs(angle)) > 20.0:
        raise InputError(
            f"{name}: steering_angle_rad reaches {np.max(np.abs(angle)):.0f}: that looks like "
            "degrees; convert to radians"
        )
    if np.max(np.abs(speed)) > 100.0:
        raise InputError(
            f"{name}: speed_m_s reaches {np.max(np.abs(speed)):.0f}: that looks like km/h; "
            "divide by 3.6"
        )
    if np.max(np.abs(torque)) > 200.0:
        raise InputError(
            f"{name}: steering_torque_Nm reaches {np.max(np.abs(torque)):.0f}: check the units "
            "(Nm at the steering wheel)"
        )
    t = time[keep]
    rate = (
        result["steering_rate_rad_s"][keep]
        if "steering_rate_rad_s" in result.names
        else savgol_rate(t, angle)
    )
    ay = result["lateral_accel_m_s2"][keep] if "lateral_accel_m_s2" in result.names else None
    return SteeringLog(name, t, speed, angle, rate, torque, ay)


def steady_ay(
    speed: FloatArray, angle: FloatArray, ratio: float, k_us: float, wheelbase: float
) -> FloatArray:
    """Steady-state lateral acceleration (m/s^2) of a car at `speed` (m/s) with the steering
    wheel at `angle` (rad, + left): V^2 * (angle / SR) / (L * (1 + K_us / L * V^2))."""
    v2 = speed * speed
    return np.asarray(v2 * (angle / ratio) / (wheelbase * (1.0 + k_us / wheelbase * v2)))


def _law(x: FloatArray) -> SteeringTorqueParams:
    return SteeringTorqueParams(*(float(v) for v in x[:9]))


def fit_steering(
    logs: Sequence[SteeringLog],
    base: SteeringCar,
    *,
    fit_vehicle: bool = False,
    progress: Callable[[int, float], None] | None = None,
) -> SteeringFit:
    """Fit K1..K9 (and a torque offset; with `fit_vehicle`, SR and K_us) to the logs."""
    from scipy.optimize import least_squares

    if not logs:
        raise InputError("no logs given")
    vehicle = base.vehicle
    measured_ay = all(log.lateral_accel_m_s2 is not None for log in logs)
    if fit_vehicle and measured_ay:
        raise InputError(
            "--fit-vehicle fits the understeer gradient from angle and torque: drop it when the "
            "logs measure lateral_accel_m_s2"
        )
    speed = np.concatenate([log.speed_m_s for log in logs])
    angle = np.concatenate([log.angle_rad for log in logs])
    rate = np.concatenate([log.rate_rad_s for log in logs])
    torque = np.concatenate([log.torque_Nm for log in logs])
    ay_given = (
        np.concatenate(
            [log.lateral_accel_m_s2 for log in logs if log.lateral_accel_m_s2 is not None]
        )
        if measured_ay
        else None
    )
    ratio0, k_us0, wheelbase = (
        vehicle.steering_ratio,
        vehicle.understeer_gradient_rad_s2_m,
        vehicle.wheelbase_m,
    )

    def lateral(x: FloatArray) -> FloatArray:
        if ay_given is not None:
            return ay_given
        k_us = x[10] if fit_vehicle else k_us0
        return steady_ay(speed, angle, ratio0, k_us, wheelbase)

    unit_warnings = _check_units(logs, vehicle)
    start = _start(speed, rate, torque, lateral(np.array([0.0] * 10 + [k_us0])))
    lower = [*LOWER, -5.0]
    upper = [*UPPER, 5.0]
    if fit_vehicle:
        start = np.concatenate([start, [k_us0]])
        lower += [0.0]  # neutral steer; carfeel's presets refuse an oversteering car
        upper += [0.05]
    start = np.clip(start, np.array(lower) + 1e-9, np.array(upper) - 1e-9)
    evaluations = [0]

    def residual(x: FloatArray) -> FloatArray:
        evaluations[0] += 1
        total = torque_terms(speed, rate, lateral(x), _law(x), atan=np.arctan)[0]
        r = np.asarray(total + x[9] - torque)
        if progress is not None:
            progress(evaluations[0], float(np.sqrt(np.mean(r * r))))
        return r

    def jacobian(x: FloatArray) -> FloatArray:
        return _jacobian(x, speed, rate, lateral(x), fit_vehicle, wheelbase, ratio0)

    first = residual(start)
    scale = float(1.4826 * np.median(np.abs(first - np.median(first)))) or 0.1
    solution = least_squares(
        residual, start, jac=jacobian, bounds=(lower, upper), loss="soft_l1", f_scale=scale,
        x_scale="jac", max_nfev=200,
    )  # fmt: skip
    x = solution.x
    r = residual(x)
    n, p = len(r), len(x)
    jac = np.asarray(solution.jac)
    sigma = _sigmas(jac, float(np.sum(r * r)) / max(n - p, 1))
    names = [*K_NAMES, "torque_offset_Nm"] + (
        ["understeer_gradient_rad_s2_m"] if fit_vehicle else []
    )
    estimates = tuple(
        Estimate(nm, float(v), float(s)) for nm, v, s in zip(names, x, sigma, strict=True)
    )
    warnings = unit_warnings + _identifiability(estimates, speed, rate, lateral(x))
    for e, active, lo, hi in zip(estimates, solution.active_mask, lower, upper, strict=True):
        if active != 0 and e.name.startswith("k"):
            warnings.append(
                f"{e.name} stopped at its bound {lo if active < 0 else hi:g}: the data cannot "
                "place it inside the physical range"
            )
    # r is model - measured with the offset: model + offset = measured + r.
    per_log: dict[str, dict[str, float]] = {}
    offset = 0
    for log in logs:
        part = slice(offset, offset + len(log.time_s))
        log_rms, log_r2 = rms_r2(torque[part], torque[part] + r[part])
        per_log[log.name] = {
            "rms_error_Nm": log_rms,
            "r2": log_r2,
            "mean_residual_Nm": float(np.mean(r[part])),
            "samples": float(len(log.time_s)),
        }
        offset += len(log.time_s)
    rms, r2 = rms_r2(torque, torque + r)
    if not r2 > 0.5:
        warnings.append(
            f"r2 {r2:.3g}: the law explains little of the torque; check the logs' units, signs "
            "and columns before using this preset"
        )
    car = dataclasses.replace(base, torque=_law(x))
    if fit_vehicle:
        car = dataclasses.replace(car, vehicle=vehicle_with(vehicle, ratio0, float(x[10])))
    return SteeringFit(
        car, estimates, float(x[9]), rms, r2, per_log,
        tuple(warnings), int(solution.nfev),
    )  # fmt: skip


def _sigmas(jac: FloatArray, variance: float) -> FloatArray:
    """One standard deviation per parameter from the Gauss-Newton covariance, infinite for a
    parameter in a direction the data do not constrain (a singular value under 1e-8 of the
    largest, after scaling each column to unit norm), not the zero a pseudo-inverse gives."""
    norms = np.linalg.norm(jac, axis=0)
    sigma = np.full(jac.shape[1], math.inf)
    live = norms > 0.0
    if not live.any():
        return sigma
    _, s, vt = np.linalg.svd(jac[:, live] / norms[live], full_matrices=False)
    weak = s < 1e-8 * s[0]
    covariance = (vt[~weak].T / s[~weak] ** 2) @ vt[~weak] * variance
    free = np.sqrt(np.clip(np.diag(covariance), 0.0, None)) / norms[live]
    if weak.any():
        free[np.any(np.abs(vt[weak]) > 0.1, axis=0)] = math.inf
    sigma[live] = free
    return sigma


def _check_units(logs: Sequence[SteeringLog], vehicle: VehicleParams) -> list[str]:
    """Catch a log in the wrong units or sign, which would fit to a good r2 and a wrong preset;
    return warnings for what only looks suspicious. Each log is judged alone (one bad log among
    good ones would otherwise pass) and named.

    On quasi-steady samples (V > 5 m/s, |rate| < 0.2 rad/s, 1 < |Ay| < 6 m/s^2): a measured Ay
    must agree with the base car's steady state within a factor of 4 (a car's SR and K_us do not
    stray further; degrees make it 1/57), with a warning beyond a factor of 1.6; and the torque
    must mostly share Ay's sign (the aligning torque the driver holds, + with + Ay: a sign test,
    which a log turning one way at constant Ay still passes). km/h read as m/s cannot be told
    from Ay at speed (understeer flattens Ay(V): at 100 km/h it makes 0.53x), so speeds beyond
    250 km/h get a warning too."""
    warnings = []
    for log in logs:
        name, speed, angle, torque = log.name, log.speed_m_s, log.angle_rad, log.torque_Nm
        top = float(np.max(speed))
        if top > 70.0:
            warnings.append(
                f"{name}: speed_m_s reaches {top:.0f} m/s ({top * 3.6:.0f} km/h): if it is in "
                "km/h, divide it by 3.6 and fit again"
            )
        ay_model = steady_ay(
            speed, angle, vehicle.steering_ratio, vehicle.understeer_gradient_rad_s2_m,
            vehicle.wheelbase_m,
        )  # fmt: skip
        measured = log.lateral_accel_m_s2
        ay = measured if measured is not None else ay_model
        steady = (speed > 5.0) & (np.abs(log.rate_rad_s) < 0.2) & (np.abs(ay) > 1.0)
        steady &= np.abs(ay) < 6.0
        if steady.sum() < 50:
            continue
        usable = steady & (np.abs(ay_model) > 0.1)
        if measured is not None and usable.sum() >= 50:
            factor = float(np.median(measured[usable] / ay_model[usable]))
            if not 0.25 < factor < 4.0:
                hint = (
                    "steering_angle_rad looks like degrees (convert to radians)"
                    if 1 / 90 < factor < 1 / 35
                    else "check the units of steering_angle_rad (rad at the wheel), speed_m_s "
                    "(m/s, not km/h) and lateral_accel_m_s2 (m/s^2, not g), and the sign of Ay; "
                    "for a car far from the base preset, give --base a preset with its "
                    "steering ratio, wheelbase and understeer"
                )
                raise InputError(
                    f"{name}: the measured lateral_accel_m_s2 is {factor:.3g} times the base "
                    f"car's steady-state Ay from speed and angle (expected about 1): {hint}"
                )
            if not 1 / 1.6 < factor < 1.6:
                warnings.append(
                    f"{name}: the measured Ay is {factor:.3g} times the base car's steady state "
                    "from speed and angle: check the units of speed_m_s and steering_angle_rad, "
                    "or start from a base preset with this car's steering ratio and understeer"
                )
        agree = float(np.mean(np.sign(torque[steady]) == np.sign(ay[steady])))
        if agree < 0.2:
            raise InputError(
                f"{name}: steering_torque_Nm has the opposite sign of Ay in {1 - agree:.0%} of the "
                "steady cornering; carfeel's convention is + torque with + Ay (the driver holds "
                "the aligning torque): flip the sign of steering_torque_Nm (or of the angle and Ay)"
            )
    return warnings


def vehicle_with(vehicle: VehicleParams, ratio: float, k_us: float) -> VehicleParams:
    """The car with this steering ratio, and the rear cornering stiffness that gives K_us."""
    a, b = vehicle.cg_to_front_axle_m, vehicle.cg_to_rear_axle_m
    denominator = b / vehicle.front_cornering_stiffness_N_rad - k_us * vehicle.wheelbase_m / (
        vehicle.mass_kg
    )
    if denominator <= 0.0:
        raise InputError(
            f"the fitted understeer gradient {math.degrees(k_us) * 9.80665:.2f} deg/g cannot be "
            "reached by the rear axle with this car's front cornering stiffness"
        )
    return dataclasses.replace(
        vehicle, steering_ratio=ratio, rear_cornering_stiffness_N_rad=a / denominator
    )


def _start(speed: FloatArray, rate: FloatArray, torque: FloatArray, ay: FloatArray) -> FloatArray:
    """Starting values from the data (see the module docstring)."""
    slow = (np.abs(rate) < 0.1) & (np.abs(ay) < 3.0) & (speed > PARKING_SPEED_M_S)
    k1 = 2.0
    if slow.sum() > 20 and np.ptp(ay[slow]) > 0.5:
        k1 = float(max(np.polyfit(ay[slow], torque[slow], 1)[0], 0.05))
    rest = torque - k1 * ay
    fast = np.abs(rate) > 1.0
    k9 = (
        float(max(np.polyfit(rate[fast], rest[fast], 1)[0], 0.0)) * 0.3 if fast.sum() > 20 else 0.05
    )
    moving = np.abs(rate) > 0.05
    k7 = float(np.median(np.abs(rest[moving]))) / 2.0 if moving.sum() > 20 else 0.5
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    k4 = 0.5
    if parked.sum() > 20:
        spin = float(np.percentile(np.abs(rest[parked]), 90)) - k7 * math.pi / 2
        k4 = math.pi / 2 / max(spin, 0.5)
    return np.array([k1, 0.1, 1.2, k4, 0.1, 0.5, max(k7, 0.05), 0.05, max(k9, 0.01), 0.0])


def _jacobian(
    x: FloatArray, speed: FloatArray, rate: FloatArray, ay: FloatArray, fit_vehicle: bool,
    wheelbase: float, ratio: float,
) -> FloatArray:  # fmt: skip
    k1, k2, k3, k4, k5, k6, k7, k8 = (float(v) for v in x[:8])
    abs_ay = np.abs(ay)
    power = np.where(abs_ay > 0.0, abs_ay**k3, 0.0)
    log_ay = np.where(abs_ay > 0.0, np.log(np.where(abs_ay > 0.0, abs_ay, 1.0)), 0.0)
    d = 1.0 + k2 * power
    spin_atan = np.arctan(rate / k6)
    e = k4 + k5 * np.abs(speed)
    columns = [
        ay / d,
        -k1 * ay * power / d**2,
        -k1 * ay * k2 * power * log_ay / d**2,
        -spin_atan / e**2,
        -np.abs(speed) * spin_atan / e**2,
        (1.0 / e) / (1.0 + (rate / k6) ** 2) * (-rate / k6**2),
        np.arctan(rate / k8),
        k7 / (1.0 + (rate / k8) ** 2) * (-rate / k8**2),
        rate,
        np.ones_like(rate),
    ]
    if fit_vehicle:
        k_us = float(x[10])
        d_tau_d_ay = k1 * (1.0 + k2 * (1.0 - k3) * power) / d**2
        v2 = speed * speed
        columns.append(d_tau_d_ay * (-ay * (v2 / wheelbase) / (1.0 + k_us / wheelbase * v2)))
    return np.column_stack(columns)


def _identifiability(
    estimates: Sequence[Estimate], speed: FloatArray, rate: FloatArray, ay: FloatArray
) -> list[str]:
    warnings = []
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    if parked.mean() < 0.01:
        warnings.append(
            "tyre spin (K4, K5, K6) is not identifiable: the logs have almost no parking "
            "manoeuvres (V < 2 m/s with the wheel turning); add a steer cycle at standstill"
        )
    if np.percentile(np.abs(ay), 99) < 3.0:
        warnings.append(
            "the aligning torque's saturation (K2, K3) is not identifiable: Ay stays under "
            "3 m/s^2; add a steady-state circle or a lane change"
        )
    for e in estimates:
        if e.name.startswith("k") and e.value > 0 and e.sigma > 0.5 * abs(e.value):
            warnings.append(
                f"{e.name} = {e.value:.3g} +- {e.sigma:.2g}: the data pin it down poorly"
            )
    return warnings
