"""`carfeel run`: a model in the fixed-rate loop on a force-feedback device."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from carfeel.commands.common import (
    EXIT_FAULT,
    positive_float,
    positive_int,
    seed_arg,
    to_json,
)
from carfeel.errors import InputError

MODELS = ("shift", "hpattern", "sequential", "prnd", "steering")
"""`realtime.run_options.MODELS`, named here so that the help is built without numpy (a test
holds the two equal, and the scripts' defaults below to `DEFAULT_SEQUENCES`)."""
DEFAULT_SEQUENCE = "N,1,2,3,4,5,4,3,2,1,N"
LEVER_SEQUENCES = {
    "sequential": "up,up,down,down,lift-down,lift-down,lift-down,lift-up,up",
    "prnd": "R,N,D,N,R,P",
}


def register(commands: Any) -> None:
    """Add `run` and their options."""
    run = commands.add_parser(
        "run",
        help="render a model at 1 kHz on a force-feedback device (virtual by default)",
        description="Run a model in a fixed-rate loop against a force-feedback device: "
        "admittance (the paper's: the device's force drives the model, the model's motion is "
        "displayed) or impedance with a virtual coupling (the device's motion drives the model, "
        "the coupling force is rendered). Forces are limited in size and slew; a stall, a lost "
        "device or a bad reading fades the force to zero. Ctrl-C stops cleanly, force first.",
        epilog="devices: virtual[:KIND] (KIND joystick: the paper's 10 N one, the default; "
        "shifter: an active 30 N H-shifter; wheel: a 4 Nm belt wheel, the default for --model "
        "steering; dd-wheel: a 15 Nm direct-drive wheel; held by a simulated hand that drives "
        "the model's own script), virtual:KIND:KEY=VALUE,... (the true plant unlike what it "
        "tells: mass, damping, friction, delay_ms, report_hz, report_phase, grip, grip_damping; "
        "a value ending in x is a factor: virtual:dd-wheel:mass=0.5x,delay_ms=6), "
        "evdev:/dev/input/eventN, sdl:INDEX, replay:RECORDING.csv. `carfeel devices` lists "
        "what is attached; `carfeel calibrate` measures one.",
    )
    run.add_argument("--model", choices=MODELS, default="hpattern",
                     help="what to render: one engagement (shift), the H-pattern (default), "
                     "a sequential lever, an automatic's PRND selector, or the steering wheel "
                     "torque (on a wheel)")  # fmt: skip
    run.add_argument("--device", default="virtual", metavar="SPEC",
                     help="virtual (default), evdev:PATH, sdl:INDEX or replay:FILE")  # fmt: skip
    run.add_argument("--mode", choices=("admittance", "impedance"), default="impedance",
                     help="rendering (default impedance; steering: impedance)")  # fmt: skip
    run.add_argument("--rate-hz", type=positive_float, default=1000.0, metavar="HZ",
                     help="loop rate, Hz (default 1000)")  # fmt: skip
    run.add_argument("--substeps", type=positive_int, default=1, metavar="N",
                     help="model steps per tick (up to 10 kHz of model steps)")  # fmt: skip
    run.add_argument("--duration", type=positive_float, default=None, metavar="S",
                     help="seconds to run (default: long enough for the script)")  # fmt: skip
    run.add_argument("--sequence", default=None, metavar="N,1,2,...",
                     help="the virtual hand's script: gears for --model hpattern (default "
                     f"{DEFAULT_SEQUENCE}); moves for sequential (up, down, lift-down, lift-up; "
                     f"default {LEVER_SEQUENCES['sequential']}); target positions for prnd "
                     f"(default {LEVER_SEQUENCES['prnd']})")  # fmt: skip
    run.add_argument("--preset", default=None, metavar="NAME|PATH",
                     help="shift, hpattern (layout), sequential, prnd or steering preset for the "
                     "model")  # fmt: skip
    run.add_argument("--speed-kmh", type=float, default=30.0, metavar="V",
                     help="vehicle speed (synchronizer, steering), km/h (default 30)")  # fmt: skip
    run.add_argument("--seed", type=seed_arg, default=0, help="seed (default 0)")
    run.add_argument("--clock", choices=("wall", "simulated"), default="wall",
                     help="wall (real time, default) or simulated (as fast as it goes; "
                          "virtual and replay devices only)")  # fmt: skip
    run.add_argument("--no-calibration", action="store_true",
                     help="skip the start-up polarity pulses and force ramp-in")  # fmt: skip
    run.add_argument("--device-max-force", type=positive_float, default=None, metavar="F",
                     help="a real device's force (N) or torque (Nm) limit")  # fmt: skip
    run.add_argument("--device-travel", type=positive_float, default=None, metavar="X",
                     help="a real device's half travel, m or rad")  # fmt: skip
    run.add_argument("--hand", choices=("script", "none", "release"), default="script",
                     help="virtual devices: the simulated driver holds the device (script), "
                     "nobody touches it (none), or the script runs, then lets go "
                     "(release)")  # fmt: skip
    run.add_argument("--release-angle-deg", type=float, default=30.0, metavar="DEG",
                     help="--hand release, steering: rim angle held for 1 s before letting "
                     "go")  # fmt: skip
    run.add_argument("--device-delay-ms", type=float, default=None, metavar="MS",
                     help="transport delay each way (commands and readings): sets a virtual "
                     "device's (default 2), declares a real one's (default 2)")  # fmt: skip
    run.add_argument("--device-report-hz", type=float, default=None, metavar="HZ",
                     help="position reports per second: a virtual device's (default 1000), "
                     "a real one's (default 500)")  # fmt: skip
    run.add_argument("--device-damping", type=positive_float, default=None, metavar="B",
                     help="a real device's own damping, N*s/m (or Nm*s/rad): the rendering is "
                     "sized on it")  # fmt: skip
    run.add_argument("--device-mass", type=positive_float, default=None, metavar="M",
                     help="a real device's moving mass at the handle, kg (or kg m^2)")  # fmt: skip
    run.add_argument("--aligning", choices=("front-axle", "steady-state"), default=None,
                     help="--model steering, the paper's law: the aligning torque from the front "
                     "axle's force (default) or from the paper's steady-state Ay")  # fmt: skip
    run.add_argument("--steering-model", choices=("paper", "physical"), default="paper",
                     help="--model steering: the paper's law (default) or the physical model "
                     "(brush tyres, EPS steering system) behind a virtual coupling sized for "
                     "the device")  # fmt: skip
    run.add_argument("--road", choices=("dry", "wet", "snow"), default=None,
                     help="--steering-model physical: the road under its tyres, mu 1.0, 0.7, "
                     "0.3 in place of the preset's (default: the preset's "
                     "tyres.friction_coefficient)")  # fmt: skip
    run.add_argument("--synchronizer", choices=("fixed", "physics"), default=None,
                     help="--model hpattern: the paper's synchronization time, or cone torque "
                     "against the speed difference (default: the preset's)")  # fmt: skip
    run.add_argument("--telemetry", metavar="SOURCE", default=None,
                     help="FORMAT:HOST:PORT: the game's speed, Ay, engine, gear and clutch drive "
                     "the model (see `carfeel telemetry listen`)")  # fmt: skip
    run.add_argument("--accept-from", metavar="ADDR", default=None,
                     help="--telemetry: take packets from ADDR only (an address, a network such "
                     "as 192.168.1.0/24, or any); default: the game's host")  # fmt: skip
    run.add_argument(
        "--gear-output",
        default="none",
        metavar="uinput|vjoy|none",
        help="--model hpattern, sequential or prnd: the lever's gear (or the selector's "
        "position, a button each) as a virtual joystick's buttons",
    )
    run.add_argument(
        "--gear-timing",
        default="slot",
        metavar="slot|engaged",
        help="press the gear's button at slot entry (default) or once in gear",
    )
    run.add_argument(
        "--gear-mapping",
        default="buttons",
        choices=("buttons", "sequential", "range-splitter"),
        help="--gear-output: the binding the game expects: a button per gear, held (buttons, "
        "the default), up/down pulses (sequential: button 1 up, 2 down) or a truck's "
        "(range-splitter: a button per handle position, then the range and splitter buttons; "
        "a truck layout such as truck-14r2)",
    )
    run.add_argument(
        "--lever-buttons",
        default=None,
        metavar="CONTROL=BUTTON,...",
        help="--model sequential|prnd on a real device: its buttons press the lever's controls "
        "(sequential: lift; prnd: button, brake), an evdev name or code (lift=BTN_TRIGGER) or an "
        "SDL index (button=0,brake=1); unmapped, a person's run keeps them at rest",
    )
    run.add_argument(
        "--car-presets",
        metavar="FILE.toml",
        default=None,
        help="--telemetry: your car map (profiles per car the game names: layout, presets, "
        "torque scale), over the one carfeel ships",
    )
    run.add_argument(
        "--interlock",
        choices=("tell", "hold"),
        default="tell",
        help="--telemetry, --model hpattern: on a lever/game gear mismatch, tell the game the "
        "lever's gear through --gear-output (tell, the default), or also push the lever out of "
        "a gear the game stays in neutral on for 0.15 s (hold: it refused the shift)",
    )
    run.add_argument(
        "--game-torque",
        metavar="SHARE",
        type=float,
        default=0.0,
        help="--telemetry, --model steering: the share of the aligning torque taken from the "
        "game's own force feedback (iRacing's SteeringWheelTorque at 360 Hz, normalised by the "
        "car profile's torque scale): 0 the law's alone (the default), 1 the game's instead",
    )
    run.add_argument("--identify", choices=("auto", "full", "off"), default="auto",
                     help="how the device is known: auto (default: its stored profile checked "
                     "in a fraction of a second, else identified hands off in a few seconds and "
                     "stored), full (identified now), off (as declared: sized for inertia "
                     "x0.5..2, damping x0.3..1, delay x1..2 around it)")  # fmt: skip
    run.add_argument("--device-profile", metavar="FILE.toml", default=None,
                     help="the device profile to check and use (or write), instead of the "
                     "device's own in the user's configuration folder")  # fmt: skip
    run.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                     help="wall clock: the core the run is pinned to (default: the last one "
                     "it may use); it also takes real-time scheduling where allowed")  # fmt: skip
    run.add_argument("--record", metavar="FILE.csv", help="record every sample (+ FILE.json)")
    run.add_argument("--plot", metavar="FILE.png", help="plot the recording (needs --record)")
    run.add_argument("--json", action="store_true", help="print the summary as one JSON object")
    run.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    code: int = _run(args)
    return code


def _with_accept(telemetry: str | None, accept_from: str | None) -> str | None:
    """The source with `--accept-from` in it (`,from=ADDR`, as `Source.parse` reads it)."""
    if telemetry is None or accept_from is None:
        return telemetry
    if ",from=" in telemetry:
        raise InputError(f"--telemetry {telemetry!r} names its ,from= already: drop --accept-from")
    return f"{telemetry},from={accept_from}"


def _run(args: argparse.Namespace) -> int:
    from carfeel.io.outputs import Outputs
    from carfeel.realtime.run_options import parse_lever_buttons
    from carfeel.realtime.session import RealtimeRun, run_realtime
    from carfeel.simulation.sequence import parse_sequence

    outputs = Outputs()
    record = Path(args.record) if args.record else None
    staged_record = staged_plot = None
    if args.plot and record is None:
        raise InputError("--plot draws the recording: give --record FILE.csv too")
    if args.aligning is not None and args.steering_model == "physical":
        raise InputError(
            "--aligning chooses the paper law's aligning torque; the physical model's comes from "
            "its own tyres (drop --aligning, or use --steering-model paper)"
        )
    if args.accept_from is not None and args.telemetry is None:
        raise InputError("--accept-from filters --telemetry's packets: give --telemetry too")
    if args.sequence is not None and args.model not in ("hpattern", *LEVER_SEQUENCES):
        raise InputError(
            f"--sequence is the virtual hand's script for the H-pattern and the levers; --model "
            f"{args.model} has none"
        )
    if record is not None:
        # A killed run leaves NAME.part.csv readable; a finished one replaces NAME.csv.
        staged_record = outputs.add(record, ".csv", partial=True)
        outputs.add(record.with_suffix(".json"), ".json", partial=True)
    if args.plot:
        staged_plot = outputs.add(Path(args.plot), ".png")
    config = RealtimeRun(
        model=args.model,
        device=args.device,
        mode=args.mode,
        rate_hz=args.rate_hz,
        substeps=args.substeps,
        duration_s=args.duration,
        sequence=None if args.sequence is None else parse_sequence(args.sequence),
        preset=args.preset,
        speed_kmh=args.speed_kmh,
        seed=args.seed,
        clock=args.clock,
        record=staged_record,
        calibrate=not args.no_calibration,
        device_max_force=args.device_max_force,
        device_travel=args.device_travel,
        hand=args.hand,
        release_angle_deg=args.release_angle_deg,
        device_delay_ms=args.device_delay_ms,
        device_report_hz=args.device_report_hz,
        device_damping=args.device_damping,
        device_mass=args.device_mass,
        aligning=args.aligning or "front-axle",
        steering_model=args.steering_model,
        road=args.road,
        synchronizer=args.synchronizer,
        telemetry=_with_accept(args.telemetry, args.accept_from),
        gear_output=args.gear_output,
        gear_timing=args.gear_timing,
        gear_mapping=args.gear_mapping,
        car_presets=Path(args.car_presets) if args.car_presets else None,
        game_torque=args.game_torque,
        interlock=args.interlock,
        identify=args.identify,
        loop_cpu=args.loop_cpu,
        device_profile=Path(args.device_profile) if args.device_profile else None,
        lever_buttons=parse_lever_buttons(args.lever_buttons) if args.lever_buttons else (),
    )

    def announce() -> None:
        if not args.json:
            print(f"carfeel run: {args.model} on {args.device}, {args.mode}, {args.rate_hz:g} Hz "
                  f"({args.clock} clock); Ctrl-C stops", flush=True)  # fmt: skip

    def say(message: str) -> None:
        print(f"carfeel run: {message}", file=sys.stderr, flush=True)

    with outputs:
        result = run_realtime(config, announce, say=say)
        if staged_plot is not None and staged_record is not None:
            from carfeel.io.plots import plot_recording
            from carfeel.simulation.result import Result

            recording = Result.from_csv(staged_record, drop_partial_last_line=True)
            title = f"{args.model} on {result.device}, {args.mode}"
            plot_recording(recording, staged_plot, title)
    result.record = record
    text = result.text()
    if args.plot:
        text += f"\nplotted {args.plot}"
    print(to_json(result.as_dict()) if args.json else text)
    if result.summary.stopped == "fault":
        return EXIT_FAULT
    return {"SIGINT": 130, "SIGTERM": 143}.get(result.summary.stopped, 0)
