"""The telemetry cues' cost a tick, each beside its reference measured in the same run.

1. `LeverCues`: its update (once a tick) and its call (each model sub-step) with the knob in
   the wall of a refused gear (the costliest path: ratio, difference, wall, grind), beside the
   H-pattern model's own sub-step (`hpattern.step`) it is added to;
2. the steering's telemetry terms: `TyreLag.step` and `GameTorque.value` playing iRacing's six
   samples, beside the single-track model's step the steering renderer takes each tick.
Asserts nothing; prints microseconds (best of 5 repeats) and the ratios.
    python benchmarks/bench_cues.py
"""

from __future__ import annotations

import timeit
from typing import Any

from carfeel.io.presets import load_hpattern, load_steering
from carfeel.models.gearshift import hpattern
from carfeel.models.gearshift.hpattern import HPatternInputs
from carfeel.models.vehicle import single_track
from carfeel.models.vehicle.single_track import VehicleInputs
from carfeel.telemetry.cues import LeverCues
from carfeel.telemetry.driving import GameTorque, TyreLag
from carfeel.telemetry.state import VehicleState

N = 20000


def best_us(call: Any) -> float:
    return min(timeit.repeat(call, number=N, repeat=5)) / N * 1e6


def main() -> None:
    pattern = load_hpattern("6r").pattern()
    cues = LeverCues(pattern, 1000.0)
    game = VehicleState(speed_m_s=25.6, engine_speed_rpm=6719.0, gear=0, clutch_pedal=0.0)
    state = hpattern.initial_state(pattern)
    two = pattern.layout.gear("2")
    knob = state._replace(
        lever=state.lever._replace(position_m=cues.entry_m + 0.001),
        plane=two.plane, direction=two.direction,
    )  # fmt: skip
    cues.update(game, 1.0, "N", 1e-3)
    assert cues(knob)[0] != 0.0  # the wall's path
    update = best_us(lambda: cues.update(game, 1.0, "N", 1e-3))
    call = best_us(lambda: (cues(knob), cues.grind(1e-3)))
    inputs = HPatternInputs(10.0, 0.0, 0.0, 25.6, 700.0)
    model = best_us(lambda: hpattern.step(state, inputs, pattern, 1e-3))
    print(f"LeverCues.update {update:.2f} us a tick; call + grind {call:.2f} us a sub-step; "
          f"reference hpattern.step {model:.2f} us: {call / model:.2f}x a sub-step")  # fmt: skip

    car = load_steering("d-segment").params
    vehicle = single_track.initial_state()
    lag = TyreLag()
    torque = GameTorque(1.0, 11.1, 20.0, exogenous=True)
    frame = VehicleState(speed_m_s=30.0, lateral_accel_m_s2=5.0, wheel_torque_Nm=-3.0,
                         wheel_torque_samples_Nm=(-2.5, -2.6, -2.7, -2.8, -2.9, -3.0))  # fmt: skip
    lagged = best_us(lambda: lag.step(5.0, 30.0, 1e-3))
    played = best_us(lambda: torque.value(frame, 0.007))
    step = best_us(lambda: single_track.step(vehicle, VehicleInputs(30.0, 0.02), car.vehicle, 1e-3))
    print(f"TyreLag.step {lagged:.2f} us, GameTorque.value {played:.2f} us a tick; reference "
          f"single_track.step {step:.2f} us: {(lagged + played) / step:.2f}x")  # fmt: skip


if __name__ == "__main__":
    main()
