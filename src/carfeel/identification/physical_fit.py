"""Fit the physical steering model (issue 13) to measured logs by re-simulation (output error).

The model has state (rack, frictions, tyres' lag, the car), so it cannot be fitted sample by
sample as the paper's law is: each trial parameter set is simulated over the logs with the
logged rim angle and rate imposed (`hands_on` = 1) and the logged speed, at the 1 ms step the
model runs at, and its rim torque is compared with the logged one at the logs' samples.

Fitted (`PARAMETERS`), each where the logs excite it (decided before the fit, from the logs):
the EPS assist gains at standstill and at speed, the column and rack friction, the EPS damping
at speed, the tyres' pneumatic trail and the road's friction coefficient mu. Beside them, as for
the law: a torque offset per log (constant or drifting, `drift_s`) and one delay of the torque
behind the other channels (a scan with the model held: no re-simulation, the simulated torque
is shifted). Everything else (geometry, inertias, torsion bar, the tyres' stiffness and the
rest of the EPS map) is the base car's: a car's data sheet has it, the torque hardly sees it.

Cost, and how it is kept small: the pure step costs about 15 us a step, so a 60 s log is about
1 s per simulation and a finite-difference Jacobian of p parameters p of them. Instead, each
log is cut into pieces of SEGMENT_S (each with a BURN_IN_S run-in), and all pieces of all logs,
for the trial point and its p neighbours at once, run through `physical_batch` (the same
arithmetic over numpy arrays: about 1 us per simulated step in a batch of 700). A piece starts
from the state the piece before it reached there for the same parameters, so the pieces are
swept (`Batch`) until they join up, within SWEEP_TOL_NM: then each parameter set's torque is
the pure model's over the whole log (the final check against the pure model,
`batch_check_Nm`, is about 1e-9 Nm), and the Jacobian carries the states' memory (a stuck
friction, the patches' wind-up at standstill) across pieces. The starts are guessed from the
last evaluation moved by its finite-difference sensitivities, so near the solution one sweep
suffices. The fit's rms and figures come from a final run of the pure model.

The inputs the model is driven with: the speed as `read_log` conditions it (1 Hz zero-phase);
the rate as logged (or low-passed, or derived, as for the law); the angle complementary-fused
with a logged rate (`fused_angle`), between samples a cubic Hermite through angle and rate.
The first SETTLE_S of each stretch of log is simulated but not scored: the model starts in the
linear car's steady state with its frictions relaxed, which the real car's were not.
Uncertainties, kept parameters and their reasons, the robust loss and the output are those of
`steering_fit` (`SteeringFit`, a block sandwich covariance over 2 s blocks).

Here: what the logs excite, the fit's steps and its result. The parts: `physical_types` (the
fitted parameters and `PhysicalFit`), `physical_runs` (the runs, the pure model's run over
them, the scored samples), `physical_predict` (the pieces and the batch swept over them) and
`physical_solver` (the evaluations, the delay scan, the Levenberg-Marquardt, the covariance).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from carfeel.errors import InputError
from carfeel.identification import rms_r2, uncertainty
from carfeel.identification.delay import MAX_DELAY_S, RESCAN_S
from carfeel.identification.physical_predict import SWEEP_TOL_NM as SWEEP_TOL_NM
from carfeel.identification.physical_predict import Batch as Batch
from carfeel.identification.physical_predict import pieces_of as pieces_of
from carfeel.identification.physical_runs import DT_S as DT_S
from carfeel.identification.physical_runs import SETTLE_S as SETTLE_S
from carfeel.identification.physical_runs import Run, _Data
from carfeel.identification.physical_runs import _data as _data
from carfeel.identification.physical_runs import reference as reference
from carfeel.identification.physical_runs import runs_of as runs_of
from carfeel.identification.physical_solver import _offsets, _scan_delay, _solve, covariance_at
from carfeel.identification.physical_types import LIMIT_G
from carfeel.identification.physical_types import MEANINGS as MEANINGS
from carfeel.identification.physical_types import NAMES as NAMES
from carfeel.identification.physical_types import PARAMETERS as PARAMETERS
from carfeel.identification.physical_types import PhysicalFit as PhysicalFit
from carfeel.identification.physical_types import value_of as value_of
from carfeel.identification.physical_types import with_values as with_values
from carfeel.identification.steering_checks import check_units
from carfeel.identification.steering_fit import PARKING_SPEED_M_S
from carfeel.identification.steering_types import (
    Estimate,
    SteeringLog,
    log_figures,
    poorly_pinned,
)
from carfeel.models.vehicle.single_track import STANDARD_GRAVITY_M_S2
from carfeel.simulation.steering import SteeringCar

FloatArray = npt.NDArray[np.float64]
BATCH_CHECK_NM = 1e-3


def excitation(
    logs: Sequence[SteeringLog], simulated_ay: Sequence[FloatArray], base: SteeringCar
) -> dict[int, str]:
    """PARAMETERS the logs cannot identify, by index, with the reason (decided before the fit).

    Thresholds: parking is V < 2 m/s with the wheel turning (> 0.5 rad/s) in 1 % of the
    samples (as for the law's tyre spin); the assist at speed needs 2 % of the samples above
    15 m/s (where its gain is within 15 % of the high-speed one) with the torque 1.5 Nm past
    the deadband (boost = gain * excess^2: 2 Nm^2 per unit of gain at the least); friction needs
    4 reversals of the steering; the damping 1 % of the samples above 10 m/s steered faster
    than 1 rad/s; the trail 5 % at speed with |Ay| > 1 m/s^2; mu 1 % beyond LIMIT_G (measured
    Ay, else the base model's), or parking: the dry-park moment the patches slide at is
    (2/3) mu Fz r_patch, so parked the model sees mu too (kept at the base's while parking is
    fitted, a wrong mu went into the assist gain: +12 % on the command line test's logs)."""
    speed = np.concatenate([log.speed_m_s for log in logs])
    rate = np.concatenate([log.rate_rad_s for log in logs])
    torque = np.concatenate([log.torque_Nm for log in logs])
    ay = np.concatenate([
        log.lateral_accel_m_s2 if log.lateral_accel_m_s2 is not None else sim
        for log, sim in zip(logs, simulated_ay, strict=True)
    ])  # fmt: skip
    assert base.steering_system is not None
    deadband = base.steering_system.assist_deadband_Nm
    reversals = 0
    for log in logs:
        moving = log.rate_rad_s[np.abs(log.rate_rad_s) > 0.05]
        reversals += int(np.count_nonzero(np.diff(np.sign(moving)) != 0))
    kept: dict[int, str] = {}
    parked = (speed < PARKING_SPEED_M_S) & (np.abs(rate) > 0.5)
    index = {name: i for i, name in enumerate(NAMES)}
    if parked.mean() < 0.01:
        kept[index["assist_gain_standstill_1_Nm"]] = (
            "kept from the base preset: the logs have almost no parking manoeuvres (V < 2 m/s "
            "with the wheel turning); add a steer cycle at standstill"
        )
    fast = speed > 15.0
    if np.mean(fast & (np.abs(torque) > deadband + 1.5)) < 0.02:
        kept[index["assist_gain_high_speed_1_Nm"]] = (
            "kept from the base preset: the torque at speed (V > 15 m/s) hardly leaves the "
            "assist's deadband; add a lane change or a steady circle at speed"
        )
    if reversals < 4:
        for name in ("column_friction_Nm", "rack_friction_Nm"):
            kept[index[name]] = (
                "kept from the base preset: the steering reverses fewer than 4 times; add a "
                "weave or a steer cycle"
            )
    if np.mean((speed > 10.0) & (np.abs(rate) > 1.0)) < 0.01:
        kept[index["eps_damping_high_speed_Nm_s_rad"]] = (
            "kept from the base preset: the wheel is hardly turned fast (> 1 rad/s) at speed; "
            "add a step steer or a sine steer at speed"
        )
    if np.mean((speed > 10.0) & (np.abs(ay) > 1.0)) < 0.05:
        kept[index["pneumatic_trail_m"]] = (
            "kept from the base preset: the logs hardly corner at speed (|Ay| > 1 m/s^2 above "
            "10 m/s); add a weave"
        )
    if np.mean(np.abs(ay) > LIMIT_G * STANDARD_GRAVITY_M_S2) < 0.01 and parked.mean() < 0.01:
        kept[index["friction_coefficient"]] = (
            f"kept from the base preset: Ay stays under {LIMIT_G:g} g, where the tyres' grip "
            "is not yet felt, and the logs have no parking (where the patches slide at a moment "
            "proportional to it); add a circle driven to the limit"
        )
    return kept


def fit_physical(
    logs: Sequence[SteeringLog],
    base: SteeringCar,
    *,
    drift_s: float | None = None,
    estimate_delay: bool = True,
    progress: Callable[[int, float], None] | None = None,
) -> PhysicalFit:
    """Fit PARAMETERS (and a torque offset per log and the torque's delay) to the logs; what
    they cannot identify keeps the base's value (status "kept", with the reason)."""
    _check_inputs(logs, base, drift_s)
    unit_warnings = check_units(logs, base.vehicle)
    start = _start(logs, base, drift_s, estimate_delay)
    counter = [0]
    x, free, notes = _fit(start, base, estimate_delay, counter, progress)
    return _result(logs, base, start, x, free, notes, unit_warnings, counter)


def _check_inputs(logs: Sequence[SteeringLog], base: SteeringCar, drift_s: float | None) -> None:
    """InputError unless there are logs, the base has the physical model and `drift_s` > 0."""
    if not logs:
        raise InputError("no logs given")
    if not base.has_physical:
        raise InputError(
            "the base preset has no [tyres] and [steering_system] tables, so it has no physical "
            "steering model to fit; start from a car that has them (--base b-segment or "
            "d-segment) or fit the paper's law (--steering-model paper)"
        )
    if drift_s is not None and not drift_s > 0:
        raise InputError(f"--drift {drift_s:g}: the knot spacing must be a positive time in s")


@dataclass
class _Start:
    """Where the fit starts: the logs' runs and scored samples, the batch (its pieces' first
    starts from the base model's run), and x (the model's parameters, the torque's delay in s,
    the offsets' coefficients in Nm) with its bounds, the base's values, what is free and why
    the rest is kept."""

    runs: list[Run]
    data: _Data
    batch: Batch
    x: FloatArray
    base_x: FloatArray
    lower: FloatArray
    upper: FloatArray
    free: npt.NDArray[np.bool_]
    notes: dict[int, str]


def _start(
    logs: Sequence[SteeringLog], base: SteeringCar, drift_s: float | None, estimate_delay: bool
) -> _Start:
    """`_Start` from a run of the base model: the batch's starts, what the logs excite, the
    delay placed by a scan, the offsets and mu's first value."""
    runs = runs_of(logs)
    pieces = pieces_of(runs)
    data = _data(logs, runs, drift_s)
    n_par, n_off = len(PARAMETERS), data.offsets.shape[1]
    base_x = np.array([value_of(base, p) for p in PARAMETERS])
    # x: the model's parameters, the torque's delay (s), the offsets' coefficients (Nm).
    lower = np.array([p.lower for p in PARAMETERS] + [-MAX_DELAY_S] + [-5.0] * n_off)
    upper = np.array([p.upper for p in PARAMETERS] + [MAX_DELAY_S] + [5.0] * n_off)
    wanted: dict[int, set[int]] = {}
    for index, begin in zip(pieces.run, pieces.begin, strict=True):
        wanted.setdefault(index, set()).add(begin)
    ref = reference(base.physical(), runs, wanted, grid_dtype=np.float32)
    batch = Batch(runs, pieces, ref, data)
    sim_ay = [np.zeros(len(log.time_s)) for log in logs]
    for run, ay_samples in zip(runs, ref.lateral_accel_m_s2, strict=True):
        sim_ay[run.log][run.samples] = ay_samples
    ref.states.clear()  # the batch has taken its starts
    free = np.ones(n_par + 1 + n_off, dtype=bool)
    free[n_par] = estimate_delay
    notes: dict[int, str] = {}
    for i, why in excitation(logs, sim_ay, base).items():
        free[i], notes[i] = False, why
    x = np.concatenate([base_x, [0.0], np.zeros(n_off)])
    grids = [t[None, :] for t in ref.torque_Nm]
    if estimate_delay:
        # Placed first by a scan on the base model (the cost has a minimum every period of a
        # weave), then fitted with the rest: a CAN delay of tens of ms left out of the first
        # solve pushed its parameters to their bounds.
        x[n_par] = _scan_delay(data, grids, x)
    x[n_par + 1 :] = _offsets(data, grids, float(x[n_par]))
    del ref, grids  # the base model's grid (ten points a sample at 100 Hz) is done with
    mu_index = NAMES.index("friction_coefficient")
    if free[mu_index]:
        x[mu_index] = _mu_start(logs, sim_ay, base_x[mu_index])
    del sim_ay
    return _Start(runs, data, batch, x, base_x, lower, upper, free, notes)


def _fit(
    start: _Start, base: SteeringCar, estimate_delay: bool, counter: list[int],
    progress: Callable[[int, float], None] | None,
) -> tuple[FloatArray, npt.NDArray[np.bool_], dict[int, str]]:  # fmt: skip
    """(x, free, notes) of the solved fit (`_solve`); where the delay's scan at the solution
    finds a better minimum further than RESCAN_S, solved again from there."""
    n_par = len(PARAMETERS)
    data, batch, lower, upper = start.data, start.batch, start.lower, start.upper
    x, free, notes = start.x, start.free, start.notes
    excited, excited_notes = free.copy(), dict(notes)
    x, free, grids = _solve(data, batch, base, x, free, notes, lower, upper, counter, progress)
    if estimate_delay:
        found = _scan_delay(data, grids, x)
        if abs(found - x[n_par]) > RESCAN_S:  # a better minimum elsewhere: solve from there
            x[n_par] = found
            free, notes = excited, excited_notes  # what stops at a bound, decided afresh
            x[:n_par][~free[:n_par]] = start.base_x[~free[:n_par]]
            x, free, grids = _solve(data, batch, base, x, free, notes, lower, upper, counter,
                                    progress)  # fmt: skip
    del grids
    return x, free, notes


def _pure_residual(base: SteeringCar, start: _Start, x: FloatArray) -> FloatArray:
    """The residual (model + offsets - measured, Nm) at the scored samples, the model's torque
    from a run of the pure model at x (the torque shifted by x's delay)."""
    n_par, data = len(PARAMETERS), start.data
    delay = float(x[n_par])
    final = reference(with_values(base, x[:n_par]).physical(), start.runs,
                      at=[times - delay for times in data.run_times])  # fmt: skip
    r = np.empty(len(data.time_s))  # the residual; the model is torque + r
    for rows, sampled in zip(data.run_rows, final.sampled_Nm, strict=True):
        r[rows] = sampled
    del final
    r += data.offsets @ x[n_par + 1 :]
    r -= data.torque_Nm
    return r


def _result(
    logs: Sequence[SteeringLog], base: SteeringCar, start: _Start, x: FloatArray,
    free: npt.NDArray[np.bool_], notes: dict[int, str], unit_warnings: Sequence[str],
    counter: list[int],
) -> PhysicalFit:  # fmt: skip
    """The fit at the solution x: its figures from the pure model; the covariance from the
    batch at the same point (the same run to rounding: their largest difference is reported by
    `batch_check_Nm`)."""
    n_par, data, batch = len(PARAMETERS), start.data, start.batch
    delay = float(x[n_par])
    r = _pure_residual(base, start, x)
    covariance, check = covariance_at(data, batch, base, x, free, r, counter)
    sigma_all = np.full(len(x), math.nan)
    sigma_all[free] = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
    estimates = tuple(
        Estimate(name, float(x[i]), float(sigma_all[i]), "fitted" if free[i] else "kept",
                 notes.get(i, ""))
        for i, name in enumerate(NAMES)
    )  # fmt: skip
    correlation = uncertainty.correlation(covariance, free, n_par, NAMES)
    warnings = [*unit_warnings, *_identifiability(estimates)]
    if check > BATCH_CHECK_NM:
        warnings.append(
            f"the fit's batch simulation differs from the model by up to {check:.2g} Nm at the "
            "solution (its pieces did not join up): the uncertainties are approximate"
        )
    per_log: dict[str, dict[str, float]] = {}
    offset_values = data.offsets @ x[n_par + 1 :]
    for log, rows in zip(logs, data.log_rows, strict=True):
        per_log[log.name] = log_figures(
            data.torque_Nm[rows], r[rows], offset_values[rows], len(log.time_s)
        )
    rms, r2 = rms_r2(data.torque_Nm, data.torque_Nm + r)
    if not r2 > 0.5:
        warnings.append(
            f"r2 {r2:.3g}: the physical model explains little of the torque; check the logs' "
            "units, signs and columns, and the base car, before using this preset"
        )
    return PhysicalFit(
        with_values(base, x[:n_par]), estimates, float(np.mean(offset_values)), rms, r2, per_log,
        tuple(warnings), counter[0], delay, correlation, batch_check_Nm=check,
        sweeps=batch.sweeps, simulated_s=batch.simulated_s,
    )  # fmt: skip


def _mu_start(
    logs: Sequence[SteeringLog], simulated_ay: Sequence[FloatArray], base_mu: float
) -> float:
    """mu scaled by how far the measured Ay goes beyond LIMIT_G against the base model's on the
    same steering (the measured peak over the simulated one); the base's without measured Ay."""
    measured, simulated = [], []
    for log, sim in zip(logs, simulated_ay, strict=True):
        if log.lateral_accel_m_s2 is not None:
            measured.append(np.abs(log.lateral_accel_m_s2))
            simulated.append(np.abs(sim))
    if not measured:
        return base_mu
    peak = float(np.percentile(np.concatenate(measured), 99.5))
    model = float(np.percentile(np.concatenate(simulated), 99.5))
    if peak < LIMIT_G * STANDARD_GRAVITY_M_S2 or model <= 0.0:
        return base_mu
    return float(np.clip(base_mu * peak / model, 0.3 * base_mu, 2.0 * base_mu))


def _identifiability(estimates: Sequence[Estimate]) -> list[str]:
    warnings = []
    for reason in dict.fromkeys(e.note for e in estimates if e.status == "kept"):
        kept = [e.name for e in estimates if e.note == reason]
        warnings.append(f"{', '.join(kept)} not identifiable, {reason}")
    return warnings + poorly_pinned(estimates)


def simulate_log(
    car: SteeringCar, log: SteeringLog, delay_s: float = 0.0
) -> tuple[FloatArray, FloatArray, npt.NDArray[np.bool_]]:
    """(Ay, torque, scored) of the physical model (the pure step) driven by a log's angle, rate
    and speed, at the log's samples (the torque shifted by `delay_s`); `scored` is False in
    each stretch's first SETTLE_S."""
    params = car.physical()
    runs = runs_of([log])
    ref = reference(params, runs)
    ay = np.zeros(len(log.time_s))
    torque = np.zeros(len(log.time_s))
    scored = np.zeros(len(log.time_s), dtype=bool)
    for run, t_grid, ay_samples in zip(runs, ref.torque_Nm, ref.lateral_accel_m_s2,
                                       strict=True):  # fmt: skip
        t = log.time_s[run.samples]
        torque[run.samples] = np.interp(t - delay_s, run.grid_s, t_grid)
        ay[run.samples] = ay_samples
        scored[run.samples] = t >= t[0] + SETTLE_S
    return ay, torque, scored
