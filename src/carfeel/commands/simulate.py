"""`carfeel simulate shift|hpattern|steering`: one run offline, its CSV, metadata and plot (the
runs themselves: `carfeel.runs`)."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from carfeel.commands.common import (
    outputs_of,
    positive_float,
    positive_int,
    seed_arg,
)
from carfeel.commands.simulate_prnd import register_prnd, simulate_prnd_command
from carfeel.commands.simulate_sequential import register_sequential, simulate_sequential_command
from carfeel.errors import InputError
from carfeel.runs import (
    HPatternRunConfig,
    ShiftRun,
    SteeringRun,
    run_hpattern,
    run_shift,
    run_steering,
)
from carfeel.simulation.manoeuvres import MANOEUVRES
from carfeel.simulation.sequence import parse_sequence
from carfeel.text import shown

__all__ = ["register"]


def register(commands: Any) -> None:
    """Add `simulate` and their options."""
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
        "--seed", type=seed_arg, default=0, help="seed of the tooth-position draw (default: 0)"
    )
    shift.add_argument(
        "--duration",
        type=positive_float,
        default=None,
        metavar="S",
        help="simulated time, s (default: 1.2, or 2.0 with --pull-out)",
    )
    shift.add_argument(
        "--dt",
        type=positive_float,
        default=1e-3,
        metavar="S",
        help="output sample period, s (default: 0.001, i.e. 1 kHz)",
    )
    shift.add_argument(
        "--substeps",
        type=positive_int,
        default=1,
        metavar="N",
        help="model steps per output sample (default: 1)",
    )
    shift.add_argument(
        "--pull-out",
        action="store_true",
        help="after settling in gear, pull the lever back to neutral",
    )
    shift.add_argument(
        "--force-profile",
        metavar="FILE.csv",
        help="drive the knob open loop with a recorded or hand-made force (CSV columns time_s, "
        "force_N; interpolated linearly) instead of the eq. (10) driver; the run lasts as long "
        "as the profile unless --duration says otherwise",
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
        epilog="layouts: 5r (default), 6r, 7r, 5r-reverse-left (see `carfeel presets`), or a TOML "
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
    hpattern.add_argument("--seed", type=seed_arg, default=0, help="tooth draw seed (default: 0)")
    hpattern.add_argument(
        "--dt", type=positive_float, default=1e-3, metavar="S",
        help="output sample period, s (default: 0.001)",
    )  # fmt: skip
    hpattern.add_argument(
        "--substeps", type=positive_int, default=1, metavar="N",
        help="model steps per output sample (default: 1)",
    )  # fmt: skip
    hpattern.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    hpattern.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")

    register_sequential(models)
    register_prnd(models)

    steering = models.add_parser(
        "steering",
        help="steering wheel torque (paper eqs. 1-7) on a car through an ISO manoeuvre",
        description="Simulate the steering wheel torque of the paper's law (tau0 aligning, tau1 "
        "tire spin, tau2 friction, tau3 damping) on a single-track car driven through a standard "
        "manoeuvre. CSV columns: time_s, speed_m_s, steering_angle_rad, steering_rate_rad_s, "
        "lateral_accel_m_s2, torque_Nm and its four terms, yaw_rate_rad_s, sideslip_rad, x_m, "
        "y_m, yaw_rad, cross_track_m, segment. Signs: positive to the left (counter-clockwise).",
        epilog="manoeuvres: iso4138 (steady-state circle, R 40 m, Ay in 0.5 m/s^2 steps, both "
        "ways), iso4138-limit (the same up to 1.1 g: the physical model's tyres saturate), "
        "iso3888 (ISO 3888-1 double lane change, 80 km/h), iso7401-step / iso7401-sine / "
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
        "--dt", type=positive_float, default=1e-3, metavar="S",
        help="output sample period, s (default: 0.001)",
    )  # fmt: skip
    steering.add_argument(
        "--substeps", type=positive_int, default=1, metavar="N",
        help="model steps per output sample (default: 1)",
    )  # fmt: skip
    steering.add_argument(
        "--steering-model", choices=("paper", "physical"), default="paper",
        help="paper: the linear car and the paper's law (default); physical: brush tyres, "
        "nonlinear car, EPS steering system with assist, friction, jacking and stops",
    )  # fmt: skip
    steering.add_argument(
        "--road", choices=("dry", "wet", "snow"), default=None,
        help="road under the physical model's tyres: mu 1.0, 0.7, 0.3 in place of the preset's "
        "tyres.friction_coefficient (default: the preset's)",
    )  # fmt: skip
    steering.add_argument("--out", required=True, metavar="FILE.csv", help="CSV file to write")
    steering.add_argument("--plot", metavar="FILE.png", help="also write a PNG plot")
    simulate.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = {
        "shift": _simulate_shift,
        "steering": _simulate_steering,
        "hpattern": _simulate_hpattern,
        "sequential": simulate_sequential_command,
        "prnd": simulate_prnd_command,
    }[args.model](args)
    return code


def _simulate_shift(args: argparse.Namespace) -> int:
    staging = outputs_of(args)
    config = ShiftRun(
        preset=args.preset,
        seed=args.seed,
        duration_s=args.duration,
        dt_s=args.dt,
        substeps=args.substeps,
        pull_out=args.pull_out,
        force_profile=Path(args.force_profile) if args.force_profile else None,
    )
    with staging.outputs:
        summary = run_shift(config, staging.out, staging.plot, staged=True)
    print(staging.text(summary.text()))
    return 0


def _simulate_steering(args: argparse.Namespace) -> int:
    staging = outputs_of(args)
    config = SteeringRun(
        manoeuvre=args.manoeuvre,
        speed_kmh=args.speed_kmh,
        preset=args.preset,
        dt_s=args.dt,
        substeps=args.substeps,
        steering_model=args.steering_model,
        road=args.road,
    )
    with staging.outputs:
        summary = run_steering(config, staging.out, staging.plot, staged=True)
    print(staging.text(summary.text()))
    return 0


def _simulate_hpattern(args: argparse.Namespace) -> int:
    staging = outputs_of(args)
    sequence = parse_sequence(args.sequence)
    mistakes = {"early-clutch": 0, "wall": 0}
    for text in args.mistake:
        kind, _, number = text.partition(":")
        if kind not in mistakes or not number.isdigit():
            raise InputError(
                f"--mistake '{shown(text)}': expected early-clutch:K or wall:K, K the position of "
                "a gear in --sequence (1 for the first)"
            )
        if mistakes[kind]:
            raise InputError(f"--mistake {kind}: given twice; one {kind} mistake per run")
        if int(number) < 1:
            raise InputError(
                f"--mistake '{shown(text)}': K counts the gears of --sequence from 1 (not N); "
                "leave --mistake out for a run without one"
            )
        mistakes[kind] = int(number)
    config = HPatternRunConfig(
        sequence=sequence,
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
    with staging.outputs:
        summary = run_hpattern(config, staging.out, staging.plot, staged=True)
    print(staging.text(summary.text()))
    return 0
