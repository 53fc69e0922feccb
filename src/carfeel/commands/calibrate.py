"""`carfeel calibrate`: identify a force-feedback device hands off and store its profile."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from carfeel.commands.common import positive_float, to_json


def register(commands: Any) -> None:
    """Add `calibrate` and its options."""
    calibrate = commands.add_parser(
        "calibrate",
        help="measure a device hands off (inertia, damping, friction, delay) and store it",
        description="Identify a force-feedback device: with the hand off, each axis is pushed a "
        "little (pulses, a short chirp and two slow sweeps, at most a quarter of its force "
        "limit, within a fifth of its travel, through the force limiter and the watchdog) and "
        "its polarity, round-trip delay, report rate, moving inertia, damping, friction and any "
        "centring spring are fitted, each with its uncertainty. The profile is stored under the "
        "user's configuration folder (or --device-profile) and checked at every `carfeel run` "
        "on the device, which identifies it again when it no longer matches.",
        epilog="devices: virtual[:KIND[:KEY=VALUE,...]] (KIND joystick, shifter, wheel, "
        "dd-wheel), evdev:/dev/input/eventN, sdl:INDEX. A real device needs its maximum force "
        "once (--device-max-force): the profile keeps it.",
    )
    calibrate.add_argument("--device", default="virtual", metavar="SPEC",
                           help="the device (default virtual: the joystick)")  # fmt: skip
    calibrate.add_argument("--kind", choices=("joystick", "wheel"), default=None,
                           help="what a real device is (default joystick; a virtual one "
                           "knows)")  # fmt: skip
    calibrate.add_argument("--rate-hz", type=positive_float, default=1000.0, metavar="HZ",
                           help="the loop rate it is measured at (default 1000)")  # fmt: skip
    calibrate.add_argument("--clock", choices=("wall", "simulated"), default="wall",
                           help="wall (default) or simulated (virtual devices)")  # fmt: skip
    calibrate.add_argument("--device-max-force", type=positive_float, default=None,
                           metavar="F", help="a real device's rated maximum force (N) or "
                           "torque (Nm), kept in its profile")  # fmt: skip
    calibrate.add_argument("--device-travel", type=positive_float, default=None, metavar="X",
                           help="a real device's half travel, m or rad")  # fmt: skip
    calibrate.add_argument("--device-delay-ms", type=float, default=None, metavar="MS",
                           help="a virtual device's transport delay each way")  # fmt: skip
    calibrate.add_argument("--device-report-hz", type=float, default=None, metavar="HZ",
                           help="a virtual device's report rate")  # fmt: skip
    calibrate.add_argument("--device-profile", metavar="FILE.toml", default=None,
                           help="where to write the profile (default: the device's own in the "
                           "user's configuration folder)")  # fmt: skip
    calibrate.add_argument("--loop-cpu", type=int, default=None, metavar="N",
                           help="the core the measurement runs on (default: the last)")  # fmt: skip
    calibrate.add_argument("--json", action="store_true", help="print one JSON object")
    calibrate.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from carfeel.io.outputs import Outputs
    from carfeel.realtime.session import Calibration, calibrate_device

    if args.device_profile:
        # Checked before the device moves: a profile that cannot be written fails first.
        Outputs().add(Path(args.device_profile), ".toml")
    calibration = Calibration(
        device=args.device, kind=args.kind, rate_hz=args.rate_hz, clock=args.clock,
        device_max_force=args.device_max_force, device_travel=args.device_travel,
        device_delay_ms=args.device_delay_ms, device_report_hz=args.device_report_hz,
        device_profile=Path(args.device_profile) if args.device_profile else None,
        loop_cpu=args.loop_cpu,
    )  # fmt: skip

    def say(message: str) -> None:
        print(f"carfeel calibrate: {message}", file=sys.stderr, flush=True)

    known = calibrate_device(calibration, say)
    if args.json:
        print(to_json(known.as_dict()))
        return 0
    print(describe(known))
    return 0


def describe(known: Any) -> str:
    """The profile as a table: per axis each figure with its standard deviation."""
    from carfeel.realtime.knowledge import describe as summary

    info = known.info
    wheel = info.kind == "wheel"
    units = {
        "mass": "kg m^2" if wheel else "kg",
        "damping": "Nm*s/rad" if wheel else "N*s/m",
        "friction": "Nm" if wheel else "N",
        "stiffness": "Nm/rad" if wheel else "N/m",
    }
    ident = known.identification
    lines = [
        f"{info.name}: identified in {ident.duration_s:.1f} s, the largest force "
        f"{ident.peak_force:.3g} ({ident.peak_force / ident.max_force:.0%} of its limit)",
    ]
    for i, a in enumerate(ident.axes):
        lines.append(
            f"axis {i}: polarity {a.polarity:+.0f}; inertia {a.mass:.4g} +- {a.mass_sigma:.2g} "
            f"{units['mass']}; damping {a.damping:.4g} +- {a.damping_sigma:.2g} "
            f"{units['damping']}; friction {a.friction:.3g} +- {a.friction_sigma:.2g} "
            f"{units['friction']}; spring {a.stiffness:.3g} +- {a.stiffness_sigma:.2g} "
            f"{units['stiffness']}; round trip {a.round_trip_s * 1e3:.3g} +- "
            f"{a.round_trip_sigma_s * 1e3:.2g} ms; {a.report_hz:.0f} reports/s; fit r2 {a.r2:.4f}"
        )
    lines.append(summary(known))
    lines += list(known.notes)
    return "\n".join(lines)
