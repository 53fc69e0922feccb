"""carfeel's command line: parse, call one function, print. Bad input exits with code 2."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from carfeel import __version__
from carfeel.errors import CarfeelError, InputError
from carfeel.simulation.manoeuvres import MANOEUVRES

DESCRIPTION = """\
carfeel: the feel of a car's primary controls from physics.

Simulate a manual gearshift engagement (synchronization, tooth engagement, end stop), the complete
H-pattern gearshift and the steering wheel torque through the ISO manoeuvres, plot them as in the
PERCRO 2005 paper, write the samples as CSV and compute steering feel metrics. Start with
`carfeel demo`.
"""

EPILOG = """\
examples:
  carfeel demo                                   simulate, plot and write into ./carfeel-demo
  carfeel simulate shift --out shift.csv --plot shift.png
  carfeel simulate shift --seed 7 --pull-out --out shift.csv
  carfeel simulate hpattern --sequence N,1,2,3,2,N --out hp.csv --plot hp.png
  carfeel simulate steering --manoeuvre iso3888 --out dlc.csv --plot dlc.png
  carfeel metrics steering dlc.csv --json        steering feel figures of a run or a log
  carfeel presets                                list the shipped presets
"""


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None
    if not value > 0.0 or value != value or value == float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def _seed(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, got {text!r}") from None


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="carfeel",
        description=DESCRIPTION,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"carfeel {__version__}")
    commands = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)

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

    simulate = commands.add_parser(
        "simulate",
        help="run a model offline in simulated time",
        description="Run a model offline in simulated time and write its samples as CSV.",
    )
    models = simulate.add_subparsers(dest="model", metavar="MODEL", required=True)
    shift = models.add_parser(
        "shift",
        help="one gear engagement, neutral to first, pushed by the paper's driver (eq. 10)",
        description="Simulate one gear engagement along the slot: the driver of eq. (10) pushes "
        "the knob from neutral through synchronization, tooth engagement and the end stop into "
        "gear, and (with --pull-out) back to neutral. CSV columns: time_s, position_m, "
        "velocity_m_s, force_N (the driver's force at the knob), reaction_N, stage, "
        "driver_phase.",
        epilog="The plot shows force and position vs time and force vs position (as the paper's "
        "Fig. 5, 6, 9 and 11), with the stages coloured.",
    )
    shift.add_argument(
        "--preset",
        default="paper-first-gear",
        metavar="NAME|PATH",
        help="shipped preset name or TOML file (default: paper-first-gear; see `carfeel presets`)",
    )
    shift.add_argument(
        "--seed", type=_seed, default=0, help="seed of the tooth-position draw (default: 0)"
    )
    shift.add_argument(
        "--duration",
        type=_positive_float,
        default=None,
        metavar="S",
        help="simulated time, s (default: 1.2, or 2.0 with --pull-out)",
    )
    shift.add_argument(
        "--dt",
        type=_positive_float,
        default=1e-3,
        metavar="S",
        help="output sample period, s (default: 0.001, i.e. 1 kHz)",
    )
    shift.add_argument(
        "--substeps",
        type=_positive_int,
        default=1,
        metavar="N",
        help="model steps per output sample (default: 1)",
    )
    shift.add_argument(
        "--pull-out",
        action="store_true",
        help="after settling in gear, pull the lever back to neutral",
    )
    shift.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    shift.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")

    hpattern = models.add_parser(
        "hpattern",
        help="the complete H-pattern gearshift driven through a gear sequence",
        description="Simulate the 2-DOF H-pattern gearshift: a driver pulls out, selects in the "
        "neutral corridor and pushes each gear of --sequence in with the paper's law (eq. 10); "
        "every slot runs the single-gear engagement model, walls keep the knob on the paths, "
        "the synchronizer decides when the gate opens. CSV columns: time_s, x_m (engage, "
        "forward +), y_m (select), vx_m_s, vy_m_s, force_x_N, force_y_N (the driver's force on "
        "the knob), reaction_x_N, reaction_y_N (the gearbox's force on it), region, gear (N, R, "
        "1, 2 ...), event, stage, clutch_pedal, speed_difference_rad_s, grind_N, click_N, "
        "driver_phase, target.",
        epilog="layouts: 5r (default), 6r, 5r-reverse-left (see `carfeel presets`), or a TOML "
        "file. mistakes (K counts the gears of --sequence, not N): early-clutch:K releases the "
        "clutch while pushing into the K-th gear; wall:K pushes toward the K-th gear while the "
        "knob is still between planes.",
    )
    hpattern.add_argument(
        "--sequence", required=True, metavar="N,1,2,...",
        help="gears to go through, comma separated, e.g. N,1,2,3,2,N or N,R,N",
    )  # fmt: skip
    hpattern.add_argument(
        "--layout", default="5r", metavar="NAME|PATH",
        help="H-pattern preset name or TOML file (default: 5r)",
    )  # fmt: skip
    hpattern.add_argument(
        "--clutch", type=float, default=1.0, metavar="0..1",
        help="clutch pedal held during the run: 1 pressed to the floor (default), 0 released",
    )  # fmt: skip
    hpattern.add_argument(
        "--speed-kmh", type=float, default=30.0, metavar="V",
        help="vehicle speed during the shifts, km/h (default: 30)",
    )  # fmt: skip
    hpattern.add_argument(
        "--synchronizer", choices=("fixed", "physics"), default=None,
        help="fixed: the paper's synchronization time; physics: cone torque against the speed "
        "difference (default: the layout preset's)",
    )  # fmt: skip
    hpattern.add_argument(
        "--mistake", action="append", default=[], metavar="KIND:K",
        help="make a mistake on the K-th gear: early-clutch:K or wall:K (repeatable)",
    )  # fmt: skip
    hpattern.add_argument("--seed", type=_seed, default=0, help="tooth draw seed (default: 0)")
    hpattern.add_argument(
        "--dt", type=_positive_float, default=1e-3, metavar="S",
        help="output sample period, s (default: 0.001)",
    )  # fmt: skip
    hpattern.add_argument(
        "--substeps", type=_positive_int, default=1, metavar="N",
        help="model steps per output sample (default: 1)",
    )  # fmt: skip
    hpattern.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    hpattern.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")

    steering = models.add_parser(
        "steering",
        help="steering wheel torque (paper eqs. 1-7) on a car through an ISO manoeuvre",
        description="Simulate the steering wheel torque of the paper's law (tau0 aligning, tau1 "
        "tire spin, tau2 friction, tau3 damping) on a single-track car driven through a standard "
        "manoeuvre. CSV columns: time_s, speed_m_s, steering_angle_rad, steering_rate_rad_s, "
        "lateral_accel_m_s2, torque_Nm and its four terms, yaw_rate_rad_s, sideslip_rad, x_m, "
        "y_m, yaw_rad, cross_track_m, segment. Signs: positive to the left (counter-clockwise).",
        epilog="manoeuvres: iso4138 (steady-state circle, R 40 m, Ay in 0.5 m/s^2 steps, both "
        "ways), iso3888 (ISO 3888-1 double lane change, 80 km/h), iso7401-step / iso7401-sine / "
        "iso7401-sweep (lateral transient response, 60 km/h), steer-cycle (lock to lock and back "
        "at standstill), weave (ISO 13674-1 on-centre, 0.2 Hz, 0.2 g, 100 km/h).",
    )
    steering.add_argument(
        "--manoeuvre", required=True, choices=MANOEUVRES, metavar="NAME",
        help="one of: " + ", ".join(MANOEUVRES),
    )  # fmt: skip
    steering.add_argument(
        "--speed-kmh",
        type=float,
        default=None,
        metavar="V",
        help="vehicle speed, km/h (default: the manoeuvre's standard speed)",
    )
    steering.add_argument(
        "--preset",
        default="b-segment",
        metavar="NAME|PATH",
        help="car preset name or TOML file (default: b-segment; see `carfeel presets`)",
    )
    steering.add_argument(
        "--dt", type=_positive_float, default=1e-3, metavar="S",
        help="output sample period, s (default: 0.001)",
    )  # fmt: skip
    steering.add_argument(
        "--substeps", type=_positive_int, default=1, metavar="N",
        help="model steps per output sample (default: 1)",
    )  # fmt: skip
    steering.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    steering.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")

    metrics = commands.add_parser(
        "metrics",
        help="figures computed from a run or a measured log",
        description="Compute figures from a CSV written by carfeel or measured on a car.",
    )
    metric_kinds = metrics.add_subparsers(dest="kind", metavar="KIND", required=True)
    feel = metric_kinds.add_parser(
        "steering",
        help="steering feel: torque gradient, torque at 0.1 g, deadband, hysteresis, "
        "sensitivity, understeer gradient",
        description="Steering feel metrics (after ISO 13674-1) of a CSV with the columns "
        "time_s, speed_m_s, steering_angle_rad, lateral_accel_m_s2, torque_Nm. A weave "
        "(carfeel simulate steering --manoeuvre weave) gives all six.",
    )
    feel.add_argument("csv", metavar="FILE.csv", help="run or log to analyse")
    feel.add_argument("--json", action="store_true", help="print one JSON object")
    _source_options(feel)
    feel.add_argument(
        "--preset",
        default=None,
        metavar="NAME|PATH",
        help="car preset for the steering ratio and wheelbase (default: from the run's .json "
        "beside the CSV, else b-segment)",
    )

    run = commands.add_parser(
        "run",
        help="render a model at 1 kHz on a force-feedback device (virtual by default)",
        description="Run a model in a fixed-rate loop against a force-feedback device: "
        "admittance (the paper's: the device's force drives the model, the model's motion is "
        "displayed) or impedance with a virtual coupling (the device's motion drives the model, "
        "the coupling force is rendered). Forces are limited in size and slew; a stall, a lost "
        "device or a bad reading fades the force to zero. Ctrl-C stops cleanly, force first.",
        epilog="devices: virtual (a 10 N joystick, or a 4 Nm wheel for --model steering, held by "
        "a simulated hand that drives the model's own script), evdev:/dev/input/eventN, "
        "sdl:INDEX, replay:RECORDING.csv. `carfeel devices` lists what is attached.",
    )
    run.add_argument("--model", choices=("shift", "hpattern", "steering"), default="hpattern")
    run.add_argument("--device", default="virtual", metavar="SPEC",
                     help="virtual (default), evdev:PATH, sdl:INDEX or replay:FILE")  # fmt: skip
    run.add_argument("--mode", choices=("admittance", "impedance"), default="impedance",
                     help="rendering (default impedance; steering: impedance)")  # fmt: skip
    run.add_argument("--rate-hz", type=_positive_float, default=1000.0, metavar="HZ",
                     help="loop rate, Hz (default 1000)")  # fmt: skip
    run.add_argument("--substeps", type=_positive_int, default=1, metavar="N",
                     help="model steps per tick (up to 10 kHz of model steps)")  # fmt: skip
    run.add_argument("--duration", type=_positive_float, default=None, metavar="S",
                     help="seconds to run (default: long enough for the script)")  # fmt: skip
    run.add_argument("--sequence", default="N,1,2,3,4,5,4,3,2,1,N", metavar="N,1,2,...",
                     help="gears for --model hpattern (the virtual hand's script)")  # fmt: skip
    run.add_argument("--preset", default=None, metavar="NAME|PATH",
                     help="shift, hpattern (layout) or steering preset for the model")  # fmt: skip
    run.add_argument("--speed-kmh", type=float, default=30.0, metavar="V",
                     help="vehicle speed (synchronizer, steering), km/h (default 30)")  # fmt: skip
    run.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    run.add_argument("--clock", choices=("wall", "simulated"), default="wall",
                     help="wall (real time, default) or simulated (as fast as it goes; "
                          "virtual and replay devices only)")  # fmt: skip
    run.add_argument("--no-calibration", action="store_true",
                     help="skip the start-up polarity pulses and force ramp-in")  # fmt: skip
    run.add_argument("--device-max-force", type=_positive_float, default=None, metavar="F",
                     help="a real device's force (N) or torque (Nm) limit")  # fmt: skip
    run.add_argument("--device-travel", type=_positive_float, default=None, metavar="X",
                     help="a real device's half travel, m or rad")  # fmt: skip
    run.add_argument("--record", metavar="FILE.csv", help="record every sample (+ FILE.json)")
    run.add_argument("--plot", metavar="FILE.png", help="plot the recording (needs --record)")
    run.add_argument("--json", action="store_true", help="print the summary as one JSON object")

    fit = commands.add_parser(
        "fit",
        help="fit a model to measured logs and write a preset",
        description="Identify a model's parameters from a car's measured logs; write a preset "
        "that `carfeel simulate` and `carfeel run` accept, and optionally a report.",
    )
    fit_kinds = fit.add_subparsers(dest="kind", metavar="KIND", required=True)
    fit_steer = fit_kinds.add_parser(
        "steering",
        help="K1..K9 of the torque law from steering logs",
        description="Fit the steering torque law (K1..K9, robust least squares) to logs with "
        "time_s, speed_m_s, steering_angle_rad, steering_torque_Nm and optionally "
        "lateral_accel_m_s2 and steering_rate_rad_s (several files: one per manoeuvre).",
    )
    fit_steer.add_argument("logs", nargs="+", metavar="LOG.csv")
    fit_steer.add_argument("--out", required=True, metavar="PRESET.toml", help="preset to write")
    fit_steer.add_argument("--base", default="b-segment", metavar="NAME|PATH",
                           help="car preset the fit starts from (default b-segment)")  # fmt: skip
    fit_steer.add_argument("--fit-vehicle", action="store_true",
                           help="also fit the understeer gradient (logs without Ay)")  # fmt: skip
    fit_steer.add_argument("--report", metavar="DIR", help="write a report (HTML + PNG)")
    fit_steer.add_argument("--drift", type=_positive_float, metavar="SECONDS",
                           help="let the torque offset drift: knots this far apart (road crown, "
                           "sensor drift); default one constant offset per log")  # fmt: skip
    fit_steer.add_argument("--holdout", type=float, default=0.0, metavar="FRACTION",
                           help="validate on the last FRACTION of each log, fit on the rest; "
                           "both figures side by side")  # fmt: skip
    _source_options(fit_steer)
    fit_steer.add_argument("--json", action="store_true", help="print the fit as one JSON object")
    fit_shift = fit_kinds.add_parser(
        "shift",
        help="engagement stages, forces and the stop from measured shift traces",
        description="Fit the gear engagement to traces with time_s, position_m, force_N (the "
        "knob's position and force, as the paper's Fig. 5/6).",
    )
    fit_shift.add_argument("traces", nargs="+", metavar="TRACE.csv")
    fit_shift.add_argument("--out", required=True, metavar="PRESET.toml", help="preset to write")
    fit_shift.add_argument("--base", default="paper-first-gear", metavar="NAME|PATH",
                           help="shift preset the fit starts from")  # fmt: skip
    fit_shift.add_argument("--report", metavar="DIR", help="write a report (HTML + PNG)")
    _source_options(fit_shift)
    fit_shift.add_argument("--json", action="store_true", help="print the fit as one JSON object")

    validate = commands.add_parser(
        "validate",
        help="run a preset's model against measured logs and write a report",
        description="Run the model of a steering or shift preset against measured logs and "
        "write one report (HTML + PNG): overlays, residuals and, for steering, the feel metrics "
        "measured and modelled side by side.",
    )
    validate.add_argument("logs", nargs="+", metavar="LOG.csv")
    validate.add_argument("--preset", required=True, metavar="PRESET.toml")
    validate.add_argument("--report", required=True, metavar="DIR")
    validate.add_argument("--json", action="store_true", help="print the figures as JSON")
    validate.add_argument("--drift", type=_positive_float, metavar="SECONDS",
                          help="remove each log's own drifting torque offset (knots this far "
                          "apart) before the figures; default a constant one")  # fmt: skip
    _source_options(validate)
    channels = commands.add_parser(
        "channels",
        help="list the signals of a log (name, unit, samples, rate, range)",
        description="List what a log holds (CSV, Parquet, MDF4, or a CAN log with --dbc), so a "
        "channel map (--channels MAP.toml) can be written for it.",
    )
    channels.add_argument("file", metavar="FILE")
    channels.add_argument("--dbc", metavar="FILE.dbc", help="DBC to decode a CAN log with")
    channels.add_argument("--json", action="store_true", help="print one JSON object")

    devices = commands.add_parser(
        "devices",
        help="list the force-feedback devices evdev and SDL2 can see",
        description="List the force-feedback devices the evdev (Linux) and SDL2 backends see, "
        "and say plainly when there is none or a backend library is missing.",
    )
    devices.add_argument("--json", action="store_true", help="print one JSON object")

    presets = commands.add_parser(
        "presets",
        help="list the shipped presets",
        description="List the presets that ship with carfeel, by kind.",
    )
    presets.add_argument("--json", action="store_true", help="print one JSON object")
    return parser


def _source_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--channels", metavar="MAP.toml",
                        help="channel map: which signal of the logs is which channel, with units "
                        "(README, 'Channel maps')")  # fmt: skip
    parser.add_argument("--dbc", metavar="FILE.dbc", help="DBC to decode CAN logs with")


def _sources(args: argparse.Namespace) -> tuple[Path | None, Path | None]:
    return (Path(args.channels) if args.channels else None, Path(args.dbc) if args.dbc else None)


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        if args.command == "demo":
            return _demo(args)
        if args.command == "simulate":
            handlers = {
                "shift": _simulate_shift,
                "steering": _simulate_steering,
                "hpattern": _simulate_hpattern,
            }
            return handlers[args.model](args)
        if args.command == "metrics":
            return _metrics_steering(args)
        if args.command == "run":
            return _run(args)
        if args.command == "devices":
            return _devices(args)
        if args.command == "fit":
            return _fit(args)
        if args.command == "validate":
            return _validate(args)
        if args.command == "channels":
            return _channels(args)
        return _presets(args)
    except CarfeelError as exc:
        print(f"carfeel: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:  # the file system said no: name the file and the reason
        where = exc.filename if exc.filename is not None else "a file"
        print(f"carfeel: error: cannot use {where}: {exc.strerror or exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("carfeel: interrupted", file=sys.stderr)
        return 130


def _simulate_shift(args: argparse.Namespace) -> int:
    from carfeel.runs import ShiftRun, run_shift

    out, plot = _outputs(args)
    config = ShiftRun(
        preset=args.preset,
        seed=args.seed,
        duration_s=args.duration,
        dt_s=args.dt,
        substeps=args.substeps,
        pull_out=args.pull_out,
    )
    summary = run_shift(config, out, plot)
    print(summary.text())
    return 0


def _simulate_steering(args: argparse.Namespace) -> int:
    from carfeel.runs import SteeringRun, run_steering

    out, plot = _outputs(args)
    config = SteeringRun(
        manoeuvre=args.manoeuvre,
        speed_kmh=args.speed_kmh,
        preset=args.preset,
        dt_s=args.dt,
        substeps=args.substeps,
    )
    print(run_steering(config, out, plot).text())
    return 0


def _simulate_hpattern(args: argparse.Namespace) -> int:
    from carfeel.runs import HPatternRunConfig, parse_sequence, run_hpattern

    out, plot = _outputs(args)
    mistakes = {"early-clutch": 0, "wall": 0}
    for text in args.mistake:
        kind, _, number = text.partition(":")
        if kind not in mistakes or not number.isdigit():
            raise InputError(
                f"--mistake {text!r}: expected early-clutch:K or wall:K, K the position of a "
                "gear in --sequence (1 for the first)"
            )
        mistakes[kind] = int(number)
    config = HPatternRunConfig(
        sequence=parse_sequence(args.sequence),
        layout=args.layout,
        clutch=args.clutch,
        speed_kmh=args.speed_kmh,
        seed=args.seed,
        synchronizer=args.synchronizer,
        early_clutch_release=mistakes["early-clutch"],
        wall_push=mistakes["wall"],
        dt_s=args.dt,
        substeps=args.substeps,
    )
    print(run_hpattern(config, out, plot).text())
    return 0


def _run(args: argparse.Namespace) -> int:
    from carfeel.realtime.session import RealtimeRun, run_realtime
    from carfeel.runs import parse_sequence

    record = Path(args.record) if args.record else None
    if record is not None:
        _check_writable(record, ".csv")
    if args.plot:
        if record is None:
            raise InputError("--plot draws the recording: give --record FILE.csv too")
        _check_writable(Path(args.plot), ".png")
    config = RealtimeRun(
        model=args.model,
        device=args.device,
        mode=args.mode,
        rate_hz=args.rate_hz,
        substeps=args.substeps,
        duration_s=args.duration,
        sequence=parse_sequence(args.sequence),
        preset=args.preset,
        speed_kmh=args.speed_kmh,
        seed=args.seed,
        clock=args.clock,
        record=record,
        calibrate=not args.no_calibration,
        device_max_force=args.device_max_force,
        device_travel=args.device_travel,
    )
    if not args.json:
        print(f"carfeel run: {args.model} on {args.device}, {args.mode}, {args.rate_hz:g} Hz "
              f"({args.clock} clock); Ctrl-C stops")  # fmt: skip
    result = run_realtime(config)
    if args.plot and record is not None:
        from carfeel.io.plots import plot_recording
        from carfeel.simulation.result import Result

        recording = Result.from_csv(record, drop_partial_last_line=True)
        plot_recording(recording, Path(args.plot), f"{args.model} on {result.device}, {args.mode}")
    print(_json(result.as_dict()) if args.json else result.text())
    return 0


def _finite(value: object) -> object:
    """NaN and infinities as null (JSON has no NaN), through dicts, lists and tuples."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _finite(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_finite(v) for v in value]
    return value


def _json(value: object) -> str:
    """Strict JSON (RFC 8259) of a result: what a script reading `--json` can parse."""
    return json.dumps(_finite(value), allow_nan=False)


def _fit(args: argparse.Namespace) -> int:
    out = Path(args.out)
    if out.suffix.lower() != ".toml":
        raise InputError(f"--out {out}: expected a .toml file name for the preset")
    _check_writable(out, ".toml")
    report_dir = Path(args.report) if args.report else None
    if args.kind == "steering":
        from carfeel.identification.workflows import Sources, fit_steering_logs, fit_summary

        fit = fit_steering_logs(
            [Path(p) for p in args.logs], out, base=args.base, fit_vehicle=args.fit_vehicle,
            report_dir=report_dir, show_progress=not args.json, sources=Sources(*_sources(args)),
            drift_s=args.drift, holdout=args.holdout,
        )  # fmt: skip
        if args.json:
            print(_json(fit.as_dict()))
        else:
            print(fit_summary(fit))
            print(f"wrote {out}" + (f" and {report_dir / 'index.html'}" if report_dir else ""))
        return 0
    from carfeel.identification import shift_workflows

    result = shift_workflows.fit_shift_traces(
        [Path(p) for p in args.traces],
        out,
        base=args.base,
        report_dir=report_dir,
        show_progress=not args.json,
        channels=_sources(args)[0],
        dbc=_sources(args)[1],
    )
    print(_json(result) if args.json else shift_workflows.summary_text(result, out))
    return 0


def _validate(args: argparse.Namespace) -> int:
    from carfeel.identification.workflows import Sources, validate

    figures = validate(args.preset, [Path(p) for p in args.logs], Path(args.report),
                       Sources(*_sources(args)), args.drift)  # fmt: skip
    if args.json:
        print(_json(figures))
    else:
        for name, values in figures.items():
            print(f"{name}: " + ", ".join(f"{k} {v:.4g}" for k, v in values.items()))
        print(f"wrote {Path(args.report) / 'index.html'}")
    return 0


def _devices(args: argparse.Namespace) -> int:
    from carfeel.realtime.devices.listing import describe_backends, list_devices

    if args.json:
        print(_json(describe_backends()))
    else:
        print("\n".join(list_devices()))
    return 0


def _metrics_steering(args: argparse.Namespace) -> int:
    from carfeel.runs import feel_lines, steering_metrics

    feel = steering_metrics(Path(args.csv), args.preset, *_sources(args))
    if args.json:
        values = {k: (None if math.isnan(v) else v) for k, v in feel.as_dict().items()}
        print(_json({**values, "notes": list(feel.notes)}))
    else:
        print(f"steering feel of {args.csv}:")
        print("\n".join(feel_lines(feel)))
    return 0


def _channels(args: argparse.Namespace) -> int:
    from carfeel.io.logs import describe

    rows = describe(Path(args.file), Path(args.dbc) if args.dbc else None)
    if args.json:
        print(_json({"file": args.file, "signals": rows}))
        return 0
    print(f"{args.file}: {len(rows)} signal(s)")
    for r in rows:
        print(f"  {r['signal']:48s} {r['unit'] or '-':8s} {r['samples']:8d} samples "
              f"{r['rate_hz']:8.1f} Hz  {r['min']:.4g} .. {r['max']:.4g}")  # fmt: skip
    return 0


def _demo(args: argparse.Namespace) -> int:
    from carfeel.runs import demo

    folder = Path(args.out_dir)
    for line in demo(folder, args.clock):
        print(line)
    return 0


def _presets(args: argparse.Namespace) -> int:
    from carfeel.io.presets import PRESET_KINDS, available

    listing = {kind: available(kind) for kind in PRESET_KINDS}
    if args.json:
        print(_json(listing))
    else:
        for kind, names in listing.items():
            print(f"{kind}: {', '.join(names)}")
    return 0


def _outputs(args: argparse.Namespace) -> tuple[Path, Path | None]:
    """--out and --plot, checked before any work is done."""
    out = Path(args.out)
    _check_writable(out, ".csv")
    plot = Path(args.plot) if args.plot else None
    if plot is not None:
        _check_writable(plot, ".png")
    return out, plot


def _check_writable(path: Path, suffix: str) -> None:
    if path.suffix.lower() != suffix:
        raise InputError(f"{path}: expected a {suffix} file name")
    folder = path.parent
    if not folder.is_dir():
        raise InputError(f"cannot write {path}: folder {folder} does not exist")
    if not os.access(folder, os.W_OK):
        raise InputError(f"cannot write {path}: folder {folder} is not writable")
    targets = [path, path.with_suffix(".json")] if suffix == ".csv" else [path]
    for target in targets:
        if target.is_dir():
            raise InputError(f"cannot write {target}: it is a folder")


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
