"""`carfeel export fmu {steering,shift}`: a self-contained C co-simulation FMU of a model."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from carfeel.commands.common import seed_arg

FMU_HELP = """\
Write a co-simulation FMU (FMI 2.0 or 3.0) of the steering torque law or of the gear engagement,
with its C sources and a Linux x86-64 binary built here by the C compiler (gcc): it runs in
Simulink, CarMaker, OpenModelica, Unity or any FMI importer, without Python. The preset's
parameters are the FMU's tunable parameters, with units and ranges. Each communication step must
be a whole number of model steps (parameter model_step_s, 1 ms by default); the inputs are held
over it, and an output reflects the inputs set before the step that computed it, so an importer
sees an input's effect one communication step later.

steering: inputs speed_m_s, lateral_accel_m_s2, steering_angle_rad, steering_rate_rad_s; outputs
  torque_Nm and its terms (aligning, tire spin, friction, damping). Parameter ay_source: the Ay
  of tau0 from the input (default) or from the FMU's single-track car (vehicle, front_axle,
  steady_state). With --steering-model physical: brush tyres, car and EPS; inputs speed_m_s,
  steering_angle_rad, steering_rate_rad_s, hand_torque_Nm, hands_on; outputs torque_Nm and
  its eight terms, the car's Ay, yaw rate, grip used.
shift: input driver_force_N (and gate_open, extra_friction_N, wall_*); outputs position_m,
  velocity_m_s, force_N, reaction_N, stage; parameter seed (the tooth draws).
"""

FMU_EPILOG = """\
examples:
  carfeel export fmu shift --out shift.fmu
  carfeel export fmu steering --preset mycar.toml --fmi 3 --out mycar-steering.fmu
"""


def register(commands: Any) -> None:
    """Add `export fmu` and its options."""
    export = commands.add_parser(
        "export",
        help="export a model for other tools (an FMU)",
        description="Export carfeel's models for other tools.",
    )
    kinds = export.add_subparsers(dest="export_kind", metavar="KIND", required=True)
    fmu = kinds.add_parser(
        "fmu",
        help="a C co-simulation FMU (FMI 2 or 3) of the steering torque or the engagement",
        description=FMU_HELP,
        epilog=FMU_EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    fmu.add_argument("model", choices=("steering", "shift"), help="the model to export")
    fmu.add_argument("--preset", help="shipped preset name or TOML file (default: the model's "
                     "default preset: b-segment, paper-first-gear)")  # fmt: skip
    fmu.add_argument("--steering-model", choices=("paper", "physical"), default=None,
                     help="steering: the paper's law (default) or the physical model (brush "
                     "tyres, EPS; the preset needs its [tyres] and [steering_system])")  # fmt: skip
    fmu.add_argument("--fmi", type=int, default=2, metavar="2|3",
                     help="FMI version (default 2, which more importers take)")  # fmt: skip
    fmu.add_argument("--seed", type=seed_arg, default=None,
                     help="shift: the seed parameter's start value (default 0)")  # fmt: skip
    fmu.add_argument("--out", required=True, metavar="NAME.fmu", help="the FMU file to write")
    fmu.add_argument("--build", choices=("auto", "gcc", "cmake"), default="auto",
                     help="how the binary is built: gcc (Linux x86-64), cmake (FMPy's CMake "
                     "build: Windows, macOS, Linux), auto (default: gcc where it applies, else "
                     "cmake)")  # fmt: skip
    fmu.set_defaults(handler=_handle)


def _handle(args: argparse.Namespace) -> int:
    from carfeel.errors import InputError
    from carfeel.export.fmu import FMI_VERSIONS, INTEGER_MAX, export_fmu, signed_seed, spec_for
    from carfeel.io.outputs import Outputs

    if args.fmi not in FMI_VERSIONS:
        raise InputError(f"--fmi {args.fmi}: the FMI version is 2 or 3")
    if args.steering_model is not None and args.model != "steering":
        raise InputError("--steering-model is for the steering FMU, not the shift's")
    if args.seed is not None and args.model != "shift":
        raise InputError("--seed is for the shift FMU (its tooth draws); the steering has none")
    # The FMU's seed is signed (two's complement of carfeel's 0..2^64-1): FMI 2's 32 bits.
    signed = signed_seed(args.seed or 0)
    if not -INTEGER_MAX[args.fmi] - 1 <= signed <= INTEGER_MAX[args.fmi]:
        raise InputError(
            f"--seed {args.seed}: the FMI 2 FMU's seed parameter is a 32-bit Integer: it "
            f"reaches the seeds 0..{INTEGER_MAX[2]} and from {2**64 - 2**31}; --fmi 3 reaches "
            "every seed"
        )
    steering_model = args.steering_model or "paper"
    spec = spec_for(args.model, args.preset, seed=args.seed or 0, steering_model=steering_model)
    out = Path(args.out)
    outputs = Outputs()
    staged = outputs.add(out, ".fmu")  # checked before anything is built
    with outputs:
        files = export_fmu(spec, args.fmi, staged, args.build)
    binary = next(name for name in files if name.startswith("binaries/"))
    title = spec.title if spec.title.isprintable() else ascii(spec.title)  # a newline in a name
    print(
        f"wrote {out}: FMI {args.fmi}.0 co-simulation FMU of {title}, "
        f"{sum(v.causality == 'parameter' for v in spec.variables)} parameters, "
        f"{sum(v.causality == 'input' for v in spec.variables)} inputs, "
        f"{sum(v.causality == 'output' for v in spec.variables)} outputs; binary {binary}"
    )
    return 0
