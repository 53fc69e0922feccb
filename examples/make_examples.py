"""Make the example files under `examples/` with carfeel itself.

    python examples/make_examples.py          # rewrites the files below, the same bytes each time

Nothing here is measured on a real car: every log is a carfeel simulation of a shipped preset,
passed through the sensor errors a test rig has (its rate, noise, quantization, an offset, a
lag), so that the pages' commands have something real-looking to chew on *and* a known answer
to compare the fit with. Which preset each file comes from is written in `examples/README.md`.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import numpy as np

from carfeel.io.presets import load_shift, load_steering
from carfeel.models.drivers import shift as shift_driver
from carfeel.simulation import manoeuvres
from carfeel.simulation import shift as shift_loop
from carfeel.simulation.result import Result
from carfeel.simulation.runner import run
from carfeel.simulation.steering import simulate_steering
from carfeel.telemetry.formats import encode_carfeel
from carfeel.telemetry.state import VehicleState

HERE = Path(__file__).resolve().parent

CAR = "d-segment"
"""The car the steering logs are made from (the tutorial fits them starting from b-segment)."""
LOG_RATE_HZ = 200.0
TORQUE_OFFSET_NM = 0.15
"""A torque sensor's zero offset (the fit reports it per log)."""
TORQUE_LAG_S = 0.010
"""The torque channel logged 10 ms behind the others (the fit reports the delay)."""
ANGLE_STEP_RAD = math.radians(0.1)
"""A steering angle sensor's resolution (0.1 deg, a common CAN angle sensor's)."""


def _sensor(run_: Result, seed: int, *, rate_hz: float = LOG_RATE_HZ) -> Result:
    """A simulated steering run as a rig logs it: `rate_hz`, white noise, the angle quantized,
    the torque offset and late, no rate column (the fit differentiates the angle)."""
    rng = np.random.default_rng(seed)
    t = np.arange(run_.time_s[0], run_.time_s[-1] - TORQUE_LAG_S, 1.0 / rate_hz)
    n = t.size

    def at(name: str, sigma: float, shift_s: float = 0.0) -> np.ndarray:
        value = np.interp(t - shift_s, run_.time_s, run_[name])
        return value + rng.normal(0.0, sigma, n)

    angle = at("steering_angle_rad", math.radians(0.02))
    signals = {
        "speed_m_s": at("speed_m_s", 0.05),
        "steering_angle_rad": np.round(angle / ANGLE_STEP_RAD) * ANGLE_STEP_RAD,
        "lateral_accel_m_s2": at("lateral_accel_m_s2", 0.05),
        # Late by TORQUE_LAG_S: the sample at t holds the torque of t - lag.
        "steering_torque_Nm": at("torque_Nm", 0.05, TORQUE_LAG_S) + TORQUE_OFFSET_NM,
    }
    return Result(np.round(t, 6), signals)


def steering_logs(folder: Path) -> dict[str, Result]:
    """Three logs of the d-segment car (paper law): a weave, a lane change, a parking cycle."""
    car = load_steering(CAR).params
    runs = {
        "weave": simulate_steering(car, manoeuvres.build("weave", car.vehicle)),
        "lanechange": simulate_steering(car, manoeuvres.build("iso3888", car.vehicle)),
        "park": simulate_steering(car, manoeuvres.build("steer-cycle", car.vehicle)),
    }
    logs = {}
    for seed, (name, result) in enumerate(runs.items()):
        logs[name] = _sensor(result, seed)
        logs[name].to_csv(folder / f"{name}.csv")
    return runs


def physical_logs(folder: Path) -> None:
    """A parking cycle and 10 s of the weave of the d-segment car's physical model (brush tyres,
    EPS), with the same sensor errors: what `fit steering --steering-model physical` takes."""
    car = load_steering(CAR).params
    for seed, (name, manoeuvre) in enumerate((("park", "steer-cycle"), ("weave", "weave")), 20):
        result = simulate_steering(car, manoeuvres.build(manoeuvre, car.vehicle), model="physical")
        if name == "weave":  # two of its five periods: enough to place the trail, half the time
            keep = result.time_s <= 10.0
            result = Result(result.time_s[keep], {n: result[n][keep] for n in result.names})
        _sensor(result, seed).to_csv(folder / f"{name}-physical.csv")


def rig_export(folder: Path, weave: Result) -> None:
    """The weave as another logger writes it: its own column names, km/h, degrees, g with
    + to the right, the torque in Ncm; `examples/channels/rig.toml` maps it back."""
    log = _sensor(weave, 7, rate_hz=100.0)
    signals = {
        "VehSpd_kph": log["speed_m_s"] * 3.6,
        "SWA_deg": np.degrees(log["steering_angle_rad"]),
        "LatAcc_g_right": -log["lateral_accel_m_s2"] / 9.80665,
        "ColTrq_Ncm": log["steering_torque_Nm"] * 100.0,
    }
    Result(log.time_s, signals).to_csv(folder / "rig-weave.csv")


def _push_again(pause_s: float = 0.25):  # type: ignore[no-untyped-def]
    """The shift loop's step with a driver who pushes into gear again `pause_s` after pulling
    out: several engagements in one trace, each with its own draw of the teeth."""

    def step(state, inputs, params, dt_s):  # type: ignore[no-untyped-def]
        hand = state.driver
        if hand.phase is shift_driver.DriverPhase.IDLE and hand.phase_time_s >= pause_s:
            state = state._replace(driver=shift_driver.initial_state(state.lever.position_m))
        return shift_loop.step(state, inputs, params, dt_s)

    return step


def shift_trace(folder: Path) -> Result:
    """Three pushes into first gear and back (paper-first-gear), logged at 500 Hz with 0.05 mm
    and 0.5 N of noise: `first-gear.csv` (time_s, position_m, force_N)."""
    preset = load_shift("paper-first-gear").params
    hand = dataclasses.replace(preset.driver, pull_out=True, hold_s=0.2)
    params = shift_loop.ShiftParams(preset.gearbox, hand)
    clean, _ = run(
        _push_again(), shift_loop.initial_state(3), params, duration_s=3.6, dt_s=1e-3, substeps=10
    )
    rng = np.random.default_rng(11)
    t = np.arange(0.0005, clean.time_s[-1], 1.0 / 500.0)
    trace = Result(
        np.round(t, 6),
        {
            "position_m": np.interp(t, clean.time_s, clean["position_m"])
            + rng.normal(0.0, 5e-5, t.size),
            "force_N": np.interp(t, clean.time_s, clean["force_N"]) + rng.normal(0.0, 0.5, t.size),
        },
    )
    trace.to_csv(folder / "first-gear.csv")
    return clean


def knob_profile(folder: Path, clean: Result) -> None:
    """The first push's knob force at 100 Hz (time_s, force_N): `simulate shift
    --force-profile` drives the lever open loop with it."""
    t = np.arange(0.0, 1.2, 0.01)
    force = np.interp(t, clean.time_s, clean["force_N"])
    Result(np.round(t, 6), {"force_N": np.round(force, 3)}).to_csv(folder / "knob.csv")


def telemetry_capture(folder: Path, weave: Result) -> None:
    """The weave as a simulator would send it in carfeel's own format at 100 Hz, 20 s: speed,
    Ay, yaw rate, 4th gear at 2800 rpm, clutch released (datagrams concatenated)."""
    t = np.arange(0.0, 20.0, 0.01)
    speed = np.interp(t, weave.time_s, weave["speed_m_s"])
    ay = np.interp(t, weave.time_s, weave["lateral_accel_m_s2"])
    yaw = np.interp(t, weave.time_s, weave["yaw_rate_rad_s"])
    angle = np.interp(t, weave.time_s, weave["steering_angle_rad"])
    packets = bytearray()
    for i, ti in enumerate(t):
        state = VehicleState(
            speed_m_s=float(speed[i]), lateral_accel_m_s2=float(ay[i]),
            yaw_rate_rad_s=float(yaw[i]), engine_speed_rpm=2800.0, gear=4, clutch_pedal=0.0,
            throttle=0.3, brake=0.0, steering_angle_rad=float(angle[i]),
        )  # fmt: skip
        packets += encode_carfeel(state, sequence=i, time_s=float(ti))
    (folder / "weave.carfeel.raw").write_bytes(bytes(packets))


def main() -> None:
    logs = HERE / "logs"
    logs.mkdir(exist_ok=True)
    runs = steering_logs(logs)
    physical_logs(logs)
    rig_export(logs, runs["weave"])
    clean = shift_trace(logs)
    knob_profile(HERE / "shift", clean)
    telemetry_capture(HERE / "telemetry", runs["weave"])
    print(f"wrote the example logs, the knob profile and the capture under {HERE}")


if __name__ == "__main__":
    main()
