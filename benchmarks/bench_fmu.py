"""Cost of a step of the exported FMUs beside the Python models, in one run.

For the shift (the engagement over 10 s of a recorded knob force: five shifts with pull-out)
the steering law and the physical steering model (over 10 s of a recorded weave), per step:
  python    the Python step called directly (`engagement.step`, `torque_terms`);
  fmpy      one co-simulation step through FMPy's FMU2Slave: set the inputs, doStep, get the
            outputs (what an importer written in Python pays), and FMPy's simulate_fmu;
  ctypes    one FMI call through ctypes alone (fmi2GetReal of one variable): FMPy's floor;
  c loop    the C port's step in a loop inside C (one ctypes call for all steps): the raw C step.
Needs a C compiler and the fmu extra (pip install 'carfeel[fmu]'). Prints numbers; asserts
nothing. The machines are shared and noisy: compare the ratios within a run.
    python benchmarks/bench_fmu.py [--repeat N]
"""

from __future__ import annotations

import argparse
import ctypes
import dataclasses
import gc
import platform
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.export import fmu, port
from carfeel.io.presets import load_shift, load_steering
from carfeel.models.gearshift import engagement
from carfeel.models.steering.torque import torque_terms
from carfeel.simulation import manoeuvres
from carfeel.simulation.shift import simulate_force_profile, simulate_shift
from carfeel.simulation.steering import simulate_steering

STEPS = 10_000
DT = 1e-3


def knob_force() -> np.ndarray:
    params = load_shift().params
    params = dataclasses.replace(params, driver=dataclasses.replace(params.driver, pull_out=True))
    return np.concatenate(
        [simulate_shift(params, seed=s, duration_s=2.0)["force_N"] for s in range(5)]
    )


def per_step_us(samples: list[float]) -> tuple[float, float]:
    ordered = sorted(samples)
    return statistics.median(ordered), ordered[int(0.99 * (len(ordered) - 1))]


def timed(loop: Callable[[], object], repeat: int) -> float:
    """Best wall time of `repeat` runs of `loop`, s (the least disturbed by other work)."""
    best = float("inf")
    for _ in range(repeat):
        gc.collect()
        t0 = time.perf_counter()
        loop()
        best = min(best, time.perf_counter() - t0)
    return best


def report(label: str, seconds: float, steps: int, reference: float | None = None) -> None:
    us = seconds / steps * 1e6
    ratio = f"   x{us / reference:7.2f} the Python step" if reference else ""
    print(f"  {label:58s} {us:9.3f} us/step{ratio}")


def fmu_instance(path: Path) -> tuple[Any, dict[str, int]]:
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    description = read_model_description(str(path))
    instance = FMU2Slave(
        guid=description.guid,
        unzipDirectory=extract(str(path)),
        modelIdentifier=description.coSimulation.modelIdentifier,
        instanceName="bench",
    )
    instance.instantiate()
    instance.setupExperiment(startTime=0.0)
    instance.enterInitializationMode()
    instance.exitInitializationMode()
    return instance, {v.name: v.valueReference for v in description.modelVariables}


def bench_shift(folder: Path, library: port.Port, repeat: int) -> None:
    gearbox = load_shift().params.gearbox
    force = knob_force()
    steps = len(force)
    inputs = [engagement.EngagementInputs(float(f)) for f in force]
    print(f"shift: the engagement over {steps} steps of a recorded knob force (5 shifts)")

    def python() -> None:
        state = engagement.initial_state(0)
        step = engagement.step
        for u in inputs:
            state, _ = step(state, u, gearbox, DT)

    reference = timed(python, repeat) / steps * 1e6
    report("python: engagement.step called directly", reference * steps / 1e6, steps)
    path = folder / "shift.fmu"
    fmu.export_fmu(fmu.spec_for("shift", None), 2, path)
    instance, vr = fmu_instance(path)
    force_vr = [vr["driver_force_N"]]
    outputs = [vr[n] for n in ("position_m", "velocity_m_s", "reaction_N")]
    stage_vr = [vr["stage"]]

    def cosim() -> None:
        instance.reset()
        instance.setupExperiment(startTime=0.0)
        instance.enterInitializationMode()
        instance.exitInitializationMode()
        set_real, do_step, get_real = instance.setReal, instance.doStep, instance.getReal
        get_integer = instance.getInteger
        t = 0.0
        for f in force:
            set_real(force_vr, [float(f)])
            do_step(currentCommunicationPoint=t, communicationStepSize=DT)
            get_real(outputs)
            get_integer(stage_vr)
            t += DT

    report("fmpy: setReal + doStep + getReal + getInteger (FMI 2)", timed(cosim, repeat), steps,
           reference)  # fmt: skip

    def step_only() -> None:
        t = 0.0
        for _ in range(steps):
            instance.doStep(currentCommunicationPoint=t, communicationStepSize=DT)
            t += DT

    report("fmpy: doStep alone", timed(step_only, repeat), steps, reference)

    references = (ctypes.c_uint32 * 1)(outputs[0])
    value = (ctypes.c_double * 1)()

    def one_call() -> None:
        get = instance.fmi2GetReal
        component = instance.component
        for _ in range(steps):
            get(component, references, 1, value)

    report("ctypes: one fmi2GetReal of one variable (FMPy's floor)", timed(one_call, repeat),
           steps, reference)  # fmt: skip
    instance.terminate()
    instance.freeInstance()

    from fmpy import simulate_fmu

    names = ("driver_force_N", "extra_friction_N", "wall_stiffness_N_m", "wall_damping_N_s_m",
             "wall_position_m")  # fmt: skip
    signal = np.zeros(
        steps, dtype=[("time", "<f8"), ("gate_open", "<i4")] + [(n, "<f8") for n in names]
    )
    signal["time"] = np.arange(steps) * DT
    signal["driver_force_N"] = force
    signal["gate_open"] = -1
    report(
        "fmpy: simulate_fmu, 10 s at 1 ms, all 6 inputs, 6 outputs",
        timed(lambda: simulate_fmu(str(path), stop_time=steps * DT, output_interval=DT,
                                   input=signal), 1),
        steps, reference,
    )  # fmt: skip
    records = port.engagement_inputs(inputs)
    report(
        "c loop: cf_engagement_step inside C (one ctypes call)",
        timed(lambda: library.engagement_run(gearbox, engagement.initial_state(0), records, DT,
                                             record=False), repeat),
        steps, reference,
    )  # fmt: skip
    one = records[:1].copy()
    start = port.engagement_state(engagement.initial_state(0))
    flat = np.array(fmu.flat_values(gearbox), "<f8")
    run = library.library.cf_engagement_run
    pointers = (start.ctypes.data, one.ctypes.data, flat.ctypes.data)

    def per_call() -> None:
        state, inputs_, params = pointers
        for f in force:
            one["driver_force_N"][0] = f
            run(state, inputs_, 1, params, DT, None, None)

    report("ctypes: cf_engagement_run of one step, one call a step", timed(per_call, repeat),
           steps, reference)  # fmt: skip
    times = list(np.arange(1, steps + 1) * DT)
    report(
        "python: carfeel simulate_force_profile (runner, Result)",
        timed(lambda: simulate_force_profile(gearbox, times, list(force), duration_s=10.0), 1),
        steps, reference,
    )  # fmt: skip


def bench_steering(folder: Path, library: port.Port, repeat: int) -> None:
    car = load_steering().params
    run = simulate_steering(car, manoeuvres.build("weave", car.vehicle))
    speed = [float(x) for x in run["speed_m_s"][:STEPS]]
    rate = [float(x) for x in run["steering_rate_rad_s"][:STEPS]]
    ay = [float(x) for x in run["lateral_accel_m_s2"][:STEPS]]
    print(f"steering: the torque law over {STEPS} samples of a recorded weave")
    law = car.torque

    def python() -> None:
        for v, r, a in zip(speed, rate, ay, strict=True):
            torque_terms(v, r, a, law)

    reference = timed(python, repeat) / STEPS * 1e6
    report("python: torque_terms called directly", reference * STEPS / 1e6, STEPS)
    path = folder / "steering.fmu"
    fmu.export_fmu(fmu.spec_for("steering", None), 2, path)
    instance, vr = fmu_instance(path)
    inputs = [vr[n] for n in ("speed_m_s", "steering_rate_rad_s", "lateral_accel_m_s2")]
    outputs = [vr[n] for n in ("torque_Nm", "torque_aligning_Nm", "torque_tire_spin_Nm",
                               "torque_friction_Nm", "torque_damping_Nm")]  # fmt: skip

    def cosim() -> None:
        set_real, do_step, get_real = instance.setReal, instance.doStep, instance.getReal
        t = 0.0
        for v, r, a in zip(speed, rate, ay, strict=True):
            set_real(inputs, [v, r, a])
            do_step(currentCommunicationPoint=t, communicationStepSize=DT)
            get_real(outputs)
            t += DT

    report("fmpy: setReal + doStep + getReal (FMI 2)", timed(cosim, repeat), STEPS, reference)
    instance.terminate()
    instance.freeInstance()
    report(
        "c loop: cf_torque_terms inside C (one ctypes call)",
        timed(lambda: library.torque_run(law, speed, rate, ay), repeat),
        STEPS, reference,
    )  # fmt: skip


def bench_physical(folder: Path, library: port.Port, repeat: int) -> None:
    from carfeel.models.steering import physical

    car = load_steering().params
    params = car.physical()
    run = simulate_steering(car, manoeuvres.build("weave", car.vehicle), model="physical")
    inputs = [
        physical.PhysicalInputs(float(v), float(a), float(r), 0.0, 1.0)
        for v, a, r in zip(run["speed_m_s"][:STEPS], run["steering_angle_rad"][:STEPS],
                           run["steering_rate_rad_s"][:STEPS], strict=True)
    ]  # fmt: skip
    print(f"physical steering: the model over {STEPS} steps of a recorded weave (hands on)")
    start = physical.initial_state(params)

    def python() -> None:
        state = start
        step = physical.step
        for u in inputs:
            state, _ = step(state, u, params, DT)

    reference = timed(python, repeat) / STEPS * 1e6
    report("python: physical.step called directly", reference * STEPS / 1e6, STEPS)
    path = folder / "physical.fmu"
    fmu.export_fmu(fmu.spec_for("steering", None, steering_model="physical"), 2, path)
    instance, vr = fmu_instance(path)
    names = ("speed_m_s", "steering_angle_rad", "steering_rate_rad_s")
    references = [vr[n] for n in names]
    outputs = [vr[n] for n in ("torque_Nm", "torque_aligning_Nm", "lateral_accel_m_s2")]
    values = [list(u[:3]) for u in inputs]

    def cosim() -> None:
        set_real, do_step, get_real = instance.setReal, instance.doStep, instance.getReal
        t = 0.0
        for row in values:
            set_real(references, row)
            do_step(currentCommunicationPoint=t, communicationStepSize=DT)
            get_real(outputs)
            t += DT

    report("fmpy: setReal + doStep + getReal (FMI 2)", timed(cosim, repeat), STEPS, reference)
    instance.terminate()
    instance.freeInstance()
    records = np.array([tuple(u) for u in inputs], port.PHYSICAL_INPUTS)
    report(
        "c loop: cf_physical_step inside C (one ctypes call)",
        timed(lambda: library.physical_run(params, start, records, DT), repeat),
        STEPS, reference,
    )  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5, help="runs per case, best kept (5)")
    args = parser.parse_args()
    try:
        import fmpy
    except ImportError:
        print("bench_fmu: skipped, it needs the fmu extra: pip install 'carfeel[fmu]'")
        return
    print(
        f"CPython {platform.python_version()}, FMPy {fmpy.__version__}, {platform.machine()}; "
        f"best of {args.repeat} runs per case"
    )
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        library = port.Port(fmu.build_port_library(folder))
        bench_shift(folder, library, args.repeat)
        bench_steering(folder, library, args.repeat)
        bench_physical(folder, library, args.repeat)
    sys.stdout.flush()


if __name__ == "__main__":
    main()
