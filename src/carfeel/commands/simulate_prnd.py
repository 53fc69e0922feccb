"""`carfeel simulate prnd`: an automatic's selector moved through target positions, offline."""

from __future__ import annotations

import argparse
from typing import Any

from carfeel.commands.common import changes, check_lever_step, lever_run_options, outputs_of


def register_prnd(models: Any) -> None:
    """Add `simulate prnd` to the `simulate` sub-commands."""
    parser = models.add_parser(
        "prnd",
        help="an automatic's selector (P, R, N, D) with its shift lock, moved to target positions",
        description="Simulate an automatic's selector (1 DOF, a detent per position): for each "
        "target of --moves the hand pushes the knob toward it with the preset driver's force "
        "until it registers, then lets go. The shift lock is a wall: out of P only with the "
        "brake, into R from N only with the lock button (if the preset asks) and below the "
        "preset's speed. CSV columns: time_s, x_m (+ toward D), v_m_s, hand_N, lever_N (the "
        "mechanism's force on the knob), wall_depth_m (into a lock's wall), shift (+1 toward "
        "D, -1 toward P as a position registers), position (P, R, N, D ...).",
    )
    parser.add_argument(
        "--moves", required=True, metavar="R,N,D,...",
        help="target positions, comma separated (the preset's: P, R, N, D ...)",
    )  # fmt: skip
    parser.add_argument(
        "--brake", default="on", metavar="on|off[,...]",
        help="the brake pedal during each move: once for all, or once per move (default: on)",
    )  # fmt: skip
    parser.add_argument(
        "--button", default="on", metavar="on|off[,...]",
        help="the knob's lock button during each move: once for all, or once per move "
        "(default: on)",
    )  # fmt: skip
    parser.add_argument(
        "--speed", default="0", metavar="M_S[,...]",
        help="the car's road speed during each move, m/s: once for all, or once per move "
        "(default: 0)",
    )  # fmt: skip
    lever_run_options(parser, "prnd", "automatic")


def simulate_prnd_command(args: argparse.Namespace) -> int:
    from carfeel.io.presets import load_prnd
    from carfeel.runs import write_metadata
    from carfeel.simulation.prnd import parse_flags, parse_moves, parse_speeds, simulate_prnd

    check_lever_step(args.dt, 0.002, "the selector")
    preset = load_prnd(args.preset)
    positions = preset.params.selector.positions
    moves = parse_moves(args.moves, positions)
    brake = parse_flags(args.brake, len(moves), "--brake")
    button = parse_flags(args.button, len(moves), "--button")
    speeds = parse_speeds(args.speed, len(moves))
    staging = outputs_of(args)
    result = simulate_prnd(preset.params, moves, brake, button, speeds, args.dt)
    seen = result["position"]
    path = changes(seen)
    depth_mm = 1000.0 * float(result["wall_depth_m"].max())
    with staging.outputs:
        result.to_csv(staging.out)
        write_metadata(
            {
                "preset": preset.name,
                "moves": args.moves,
                "brake": args.brake,
                "button": args.button,
                "speed_m_s": args.speed,
            },
            staging.out,
        )
    # A move is refused when its target had not registered by the end of its hold.
    hold = round(preset.params.driver.hold_s / args.dt)
    rest = round(preset.params.driver.rest_s / args.dt)
    reached = sum(
        1
        for k, target in enumerate(moves)
        if seen[k * (hold + rest) + hold - 1] == positions[target]
    )
    print(
        staging.text(
            f"{preset.name}: {len(moves)} moves, {reached} reached, {len(moves) - reached} "
            f"refused by the shift lock (deepest into its wall {depth_mm:.1f} mm); positions "
            f"{' '.join(path)}; wrote {staging.out}"
        )
    )
    return 0
