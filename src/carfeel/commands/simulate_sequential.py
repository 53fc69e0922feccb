"""`carfeel simulate sequential`: a sequential lever through a pattern of moves, offline."""

from __future__ import annotations

import argparse
from typing import Any

from carfeel.commands.common import changes, check_lever_step, lever_run_options, outputs_of


def register_sequential(models: Any) -> None:
    """Add `simulate sequential` to the `simulate` sub-commands."""
    parser = models.add_parser(
        "sequential",
        help="a sequential (rally/race) lever pushed and pulled through a pattern of moves",
        description="Simulate a sequential lever (1 DOF, spring-centred): each move of --moves "
        "pushes or pulls the knob with the preset driver's force, then lets go; a shift "
        "registers at the click, a locked move (up from the top gear, down from R, neutral or "
        "reverse without the lift button, or --locked) meets a wall before it. CSV columns: "
        "time_s, x_m (+ forward), v_m_s, hand_N, lever_N (the mechanism's force on the knob), "
        "wall_depth_m (into a lock's wall), shift (+1 up, -1 down at the click), gear (R, N, "
        "1 ...).",
    )
    parser.add_argument(
        "--moves", required=True, metavar="up,down,...",
        help="moves, comma separated: up, down, lift-down, lift-up (lift-: the knob's lift "
        "button held, for neutral and reverse)",
    )  # fmt: skip
    parser.add_argument(
        "--locked", choices=("up", "down"), action="append", default=[],
        help="the game reports this direction locked (repeatable): its moves meet the wall",
    )  # fmt: skip
    lever_run_options(parser, "sequential", "rally-6")


def simulate_sequential_command(args: argparse.Namespace) -> int:
    from carfeel.io.presets import load_sequential
    from carfeel.runs import write_metadata
    from carfeel.simulation.sequential import parse_moves, simulate_sequential

    moves = parse_moves(args.moves)
    check_lever_step(args.dt, 0.01, "the lever")
    preset = load_sequential(args.preset)
    staging = outputs_of(args)
    result = simulate_sequential(
        preset.params, moves, args.dt, "up" in args.locked, "down" in args.locked
    )
    shifts = [int(s) for s in result["shift"] if s]
    gears = changes(result["gear"])
    depth_mm = 1000.0 * float(result["wall_depth_m"].max())
    with staging.outputs:
        result.to_csv(staging.out)
        write_metadata(
            {"preset": preset.name, "moves": ",".join(moves), "locked": ",".join(args.locked)},
            staging.out,
        )
    refused = len(moves) - len(shifts)
    print(
        staging.text(
            f"{preset.name}: {len(moves)} moves, {len(shifts)} shifts, {refused} refused by a "
            f"lock (deepest into its wall {depth_mm:.1f} mm); gears {' '.join(gears)}; wrote "
            f"{staging.out}"
        )
    )
    return 0
