"""`carfeel demo`: the tour, every run into one folder."""

from __future__ import annotations

import argparse
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import __version__
from carfeel.errors import InputError
from carfeel.io.presets import load_steering
from carfeel.runs import (
    HPatternRunConfig,
    ShiftRun,
    SteeringRun,
    run_hpattern,
    run_shift,
    run_steering,
)
from carfeel.simulation import manoeuvres
from carfeel.simulation.result import Result
from carfeel.simulation.sequence import parse_sequence
from carfeel.simulation.steering import simulate_steering


def demo(folder: Path, clock: str = "wall") -> Iterator[str]:
    """Run the demo into `folder`, yielding a line to print per step."""
    if folder.exists() and not folder.is_dir():
        raise InputError(f"--out-dir {folder} exists and is not a folder")
    folder.mkdir(parents=True, exist_ok=True)
    yield f"carfeel {__version__} demo: writing into {folder.resolve()}"
    summary = run_shift(ShiftRun(seed=0, pull_out=True), folder / "shift.csv", folder / "shift.png")
    yield "gear engagement, neutral to first and back (paper Fig. 5/6/9/11):"
    yield summary.text()
    peaks = []
    for seed in range(1, 6):
        s = run_shift(ShiftRun(seed=seed), folder / f"shift-seed{seed}.csv")
        peaks.append(s.features.engagement_peak_N)
    finite = [p for p in peaks if not math.isnan(p)]
    yield (
        "engagement peaks over seeds 1-5 (the teeth meet at random): "
        + ", ".join(f"{p:.1f}" for p in finite)
        + " N"
    )
    yield ""
    yield "the complete H-pattern (5+R), up and down the box at 30 km/h:"
    pattern = run_hpattern(
        HPatternRunConfig(parse_sequence("N,1,2,3,4,5,4,3,2,1,N"), speed_kmh=30.0),
        folder / "hpattern.csv",
        folder / "hpattern.png",
    )
    yield pattern.text()
    yield "and into reverse at standstill, with the synchronizer's physics:"
    reverse = run_hpattern(
        HPatternRunConfig(parse_sequence("N,R,N"), speed_kmh=0.0, synchronizer="physics"),
        folder / "hpattern-reverse.csv",
        folder / "hpattern-reverse.png",
    )
    yield reverse.text()
    yield ""
    took = " (about 16 s)" if clock == "wall" else ""
    yield f"the H-pattern on the virtual force-feedback joystick, in real time (1 kHz){took}:"
    from carfeel.io.plots import plot_recording
    from carfeel.realtime.identify import IdentificationError
    from carfeel.realtime.session import RealtimeRun, run_realtime

    record = folder / "realtime-hpattern.csv"
    run = RealtimeRun(model="hpattern", mode="admittance", record=record, clock=clock)
    try:
        live = run_realtime(run)
    except IdentificationError as exc:
        # The virtual joystick has no hand on it: only a busy machine (a stall of the loop on
        # a shared core) stops its identification. Once more, saying so; a second stop ends
        # the demo with the reason, as `carfeel run` would.
        yield f"  {exc}; once more:"
        live = run_realtime(run)
    plot_recording(
        Result.from_csv(record, drop_partial_last_line=True),
        folder / "realtime-hpattern.png",
        "H-pattern on the virtual joystick, admittance (the paper's scheme)",
    )
    yield live.text()
    yield f"plotted {folder / 'realtime-hpattern.png'} (cf. paper Fig. 10 and 11)"
    yield ""
    yield "steering wheel torque, ISO 3888-1 double lane change (paper Fig. 3):"
    dlc = run_steering(
        SteeringRun("iso3888"), folder / "steering-iso3888.csv", folder / "steering-iso3888.png"
    )
    yield dlc.text()
    yield ""
    yield "steering feel from an ISO 13674-1 weave:"
    weave = run_steering(
        SteeringRun("weave"), folder / "steering-weave.csv", folder / "steering-weave.png"
    )
    yield weave.text()
    yield ""
    yield from _demo_identification(folder)


def as_logged(run: Result, seed: int, rate_hz: float = 200.0) -> Result:
    """A simulated steering run as a test rig would log it: `rate_hz`, white noise of 0.05 Nm,
    0.02 deg, 0.05 m/s^2 and 0.05 m/s, and no rate column (the fit derives it)."""
    rng = np.random.default_rng(seed)
    idx = np.arange(
        0, len(run.time_s), max(1, round(1.0 / (rate_hz * np.median(np.diff(run.time_s)))))
    )
    n = idx.size
    noise = {"speed_m_s": 0.05, "steering_angle_rad": math.radians(0.02),
             "lateral_accel_m_s2": 0.05, "torque_Nm": 0.05}  # fmt: skip
    signals = {name: run[name][idx] + rng.normal(0.0, sigma, n) for name, sigma in noise.items()}
    signals["steering_torque_Nm"] = signals.pop("torque_Nm")
    return Result(run.time_s[idx], signals)


def _demo_identification(folder: Path) -> Iterator[str]:
    from carfeel.identification.workflows import fit_steering_logs, fit_summary

    yield (
        "identification: K1..K9 fitted back from the weave, the lane change and a parking steer "
        "cycle, logged with noise:"
    )
    car = load_steering().params
    runs = {
        "weave": Result.from_csv(folder / "steering-weave.csv"),
        "iso3888": Result.from_csv(folder / "steering-iso3888.csv"),
        "steer-cycle": simulate_steering(car, manoeuvres.build("steer-cycle", car.vehicle)),
    }
    paths = []
    for seed, (name, run) in enumerate(runs.items()):
        path = folder / f"logged-{name}.csv"
        as_logged(run, seed).to_csv(path)
        paths.append(path)
    fit = fit_steering_logs(
        paths, folder / "fitted-b-segment.toml", report_dir=folder / "fit-report",
        show_progress=True,  # on a terminal only: a line that counts the evaluations
    )  # fmt: skip
    yield fit_summary(fit)
    true = car.torque
    yield (
        f"  (the b-segment preset the logs came from: K1 {true.k1_Nm_s2_m:g}, K4 {true.k4_1_Nm:g}, "
        f"K7 {true.k7_Nm:g}, K9 {true.k9_Nm_s_rad:g})"
    )
    yield f"wrote {folder / 'fitted-b-segment.toml'} and {folder / 'fit-report' / 'index.html'}"


def register(commands: Any) -> None:
    """Add `demo` and their options."""
    demo = commands.add_parser(
        "demo",
        help="a tour: engagement, H-pattern, the haptic loop, steering; files into a folder",
        description="Simulate a neutral-to-first engagement, the H-pattern up and down the box "
        "and into reverse, run the H-pattern on the virtual force-feedback joystick in real "
        "time, and drive the steering through ISO 3888-1 and a weave; write every run's CSV, "
        "metadata and PNG plot into a folder (created if missing).",
    )
    demo.add_argument(
        "--clock",
        choices=("wall", "simulated"),
        default="wall",
        help="clock of the real-time part (default wall: it runs for about 16 s)",
    )
    demo.add_argument(
        "--out-dir",
        default="carfeel-demo",
        metavar="DIR",
        help="folder for the files (default: ./carfeel-demo)",
    )
    demo.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = _demo(args)
    return code


def _demo(args: argparse.Namespace) -> int:
    folder = Path(args.out_dir)
    for line in demo(folder, args.clock):
        print(line)
    return 0
