"""`carfeel fit` and `carfeel validate`: identification from measured logs, and its check."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from typing import Any

from carfeel.commands.common import (
    check_writable,
    positive_float,
    source_options,
    sources_of,
    to_json,
)
from carfeel.errors import InputError
from carfeel.io.outputs import check_folder

LOW_R2 = 0.5
"""Below this r2 a validation is warned about (the fit's threshold)."""
MIN_DRIFT_S = 5.0
"""The closest --drift knots: closer, the offset follows the steering's own torque (a weave's
period is 2-5 s) instead of a road's crown or a sensor's drift, and the fit has a parameter for
every few samples."""


def drift_seconds(text: str) -> float:
    value = positive_float(text)
    if value < MIN_DRIFT_S:
        raise argparse.ArgumentTypeError(
            f"{value:g} s: knots closer than {MIN_DRIFT_S:g} s would follow the steering's own "
            f"torque (a weave's period is 2-5 s), not a drift; give {MIN_DRIFT_S:g} s or more"
        )
    return value


def register(commands: Any) -> None:
    """Add `fit`, `validate` and their options."""
    fit = commands.add_parser(
        "fit",
        help="fit a model to measured logs and write a preset",
        description="Identify a model's parameters from a car's measured logs; write a preset "
        "that `carfeel simulate` and `carfeel run` accept, and optionally a report.",
    )
    fit_kinds = fit.add_subparsers(dest="kind", metavar="KIND", required=True)
    fit_steer = fit_kinds.add_parser(
        "steering",
        help="K1..K9 of the torque law (or the physical model) from steering logs",
        description="Fit the steering torque law (K1..K9, robust least squares) to logs with "
        "time_s, speed_m_s, steering_angle_rad, steering_torque_Nm and optionally "
        "lateral_accel_m_s2 and steering_rate_rad_s (several files: one per manoeuvre); with "
        "--steering-model physical, the physical model's assist gains, frictions, EPS damping, "
        "pneumatic trail and mu, by simulating it with the logged angle and speed.",
    )
    fit_steer.add_argument("logs", nargs="+", metavar="LOG.csv",
                           help="steering logs: CSV, or with carfeel[logs] Parquet, MDF4, CAN "
                           "with --dbc (one per manoeuvre)")  # fmt: skip
    fit_steer.add_argument("--out", required=True, metavar="PRESET.toml", help="preset to write")
    fit_steer.add_argument("--base", default="b-segment", metavar="NAME|PATH",
                           help="car preset the fit starts from (default b-segment)")  # fmt: skip
    fit_steer.add_argument("--fit-vehicle", action="store_true",
                           help="fit the understeer gradient too (the default where no log has "
                           "Ay; refused where every log has it)")  # fmt: skip
    fit_steer.add_argument("--report", metavar="DIR", help="write a report (HTML + PNG)")
    fit_steer.add_argument("--drift", type=drift_seconds, metavar="SECONDS",
                           help="let the torque offset drift: knots this far apart (road crown, "
                           "sensor drift); default one constant offset per log")  # fmt: skip
    fit_steer.add_argument("--holdout", type=float, default=0.0, metavar="FRACTION",
                           help="validate on the last FRACTION of each log, fit on the rest; "
                           "both figures side by side")  # fmt: skip
    _steering_model_option(fit_steer, "the model to fit")
    source_options(fit_steer)
    fit_steer.add_argument("--json", action="store_true", help="print the fit as one JSON object")
    fit_shift = fit_kinds.add_parser(
        "shift",
        help="engagement stages, forces and the stop from measured shift traces",
        description="Fit the gear engagement to traces with time_s, position_m, force_N (the "
        "knob's position and force, as the paper's Fig. 5/6).",
    )
    fit_shift.add_argument("traces", nargs="+", metavar="TRACE.csv",
                           help="shift traces (time_s, position_m, force_N), one or more "
                           "engagements each")  # fmt: skip
    fit_shift.add_argument("--out", required=True, metavar="PRESET.toml", help="preset to write")
    fit_shift.add_argument("--base", default="paper-first-gear", metavar="NAME|PATH",
                           help="shift preset the fit starts from")  # fmt: skip
    fit_shift.add_argument("--report", metavar="DIR", help="write a report (HTML + PNG)")
    source_options(fit_shift)
    fit_shift.add_argument("--json", action="store_true", help="print the fit as one JSON object")
    fit.set_defaults(handler=_fit)

    validate = commands.add_parser(
        "validate",
        help="run a preset's model against measured logs and write a report",
        description="Run the model of a steering or shift preset against measured logs and "
        "write one report (HTML + PNG): overlays, residuals and, for steering, the feel metrics "
        "measured and modelled side by side.",
    )
    validate.add_argument("logs", nargs="+", metavar="LOG.csv",
                          help="steering logs or shift traces measured on the car")  # fmt: skip
    validate.add_argument("--preset", required=True, metavar="PRESET.toml",
                          help="the preset to check against the logs")  # fmt: skip
    validate.add_argument("--report", default=None, metavar="DIR",
                          help="folder for the report (HTML + PNG); without it only the "
                          "figures are printed")  # fmt: skip
    validate.add_argument("--drift", type=drift_seconds, metavar="SECONDS",
                          help="remove each log's own drifting torque offset (knots this far "
                          "apart) before the figures; default a constant one")  # fmt: skip
    _steering_model_option(validate, "the steering model to run against the logs")
    source_options(validate)
    validate.add_argument("--json", action="store_true", help="print the figures as JSON")
    validate.set_defaults(handler=_validate)


def _steering_model_option(parser: Any, what: str) -> None:
    parser.add_argument(
        "--steering-model", choices=("paper", "physical"), default="paper",
        help=f"{what}: paper (K1..K9 of the paper's law, the default) or physical (brush "
        "tyres and the EPS steering system, re-simulated from the logs)",
    )  # fmt: skip


def _physical_options(args: argparse.Namespace) -> None:
    """Refuse what makes no sense with the physical model, with the reason."""
    if getattr(args, "fit_vehicle", False):
        raise InputError(
            "--fit-vehicle fits the paper law's understeer gradient from the logged angle and "
            "torque; the physical model drives the base car's own tyres with the logged angle, "
            "so drop --fit-vehicle (or give --base a preset of this car, with its cornering "
            "stiffnesses)"
        )


def _fit(args: argparse.Namespace) -> int:
    out = Path(args.out)
    check_writable(out, ".toml")  # names an empty --out, and a name that is not a .toml
    report_dir = None if args.report is None else Path(args.report)
    if report_dir is not None:
        check_folder(report_dir)
    if args.kind == "steering" and args.steering_model == "physical":
        from carfeel.identification.physical_workflows import fit_physical_logs
        from carfeel.identification.workflows import Sources, fit_summary

        _physical_options(args)
        fit = fit_physical_logs(
            [Path(p) for p in args.logs], out, base=args.base, report_dir=report_dir,
            show_progress=not args.json, sources=Sources(*sources_of(args)), drift_s=args.drift,
            holdout=args.holdout,
        )  # fmt: skip
        if args.json:
            print(to_json({"steering_model": "physical", **fit.as_dict()}))
        else:
            print("physical steering model: " + fit_summary(fit))
            print(f"wrote {out}" + (f" and {report_dir / 'index.html'}" if report_dir else ""))
        return 0
    if args.kind == "steering":
        from carfeel.identification.workflows import Sources, fit_steering_logs, fit_summary

        fit = fit_steering_logs(
            [Path(p) for p in args.logs], out, base=args.base,
            fit_vehicle=True if args.fit_vehicle else None,  # None: fitted where there is no Ay
            report_dir=report_dir, show_progress=not args.json, sources=Sources(*sources_of(args)),
            drift_s=args.drift, holdout=args.holdout,
        )  # fmt: skip
        if args.json:
            print(to_json(fit.as_dict()))
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
        channels=sources_of(args)[0],
        dbc=sources_of(args)[1],
    )
    text = shift_workflows.summary_text(result, out)
    if report_dir is not None:
        text += f"\nwrote the report {report_dir / 'index.html'}"
    print(to_json(result) if args.json else text)
    return 0


def _validate(args: argparse.Namespace) -> int:
    import tempfile

    from carfeel.identification.workflows import Sources, validate

    logs = [Path(p) for p in args.logs]
    with tempfile.TemporaryDirectory() as scratch:
        # Without --report the report is drawn in a scratch folder and thrown away.
        folder = Path(scratch) / "report" if args.report is None else Path(args.report)
        if args.steering_model == "physical":
            from carfeel.identification.physical_workflows import validate_physical

            figures = validate_physical(
                args.preset, logs, folder, Sources(*sources_of(args)), args.drift
            )
        else:
            figures = validate(args.preset, logs, folder, Sources(*sources_of(args)), args.drift)
    comparison = figures.pop("comparison", None)
    if args.json:
        print(to_json({**figures, **({"comparison": comparison} if comparison else {})}))
    else:
        for name, values in figures.items():
            print(f"{name}: " + ", ".join(f"{k} {v:.4g}" for k, v in values.items()))
        if comparison:
            from carfeel.identification.workflows import comparison_lines

            split = comparison.pop("split")
            print("\n".join(comparison_lines(comparison, split)).lstrip())
        if args.report is not None:
            print(f"wrote {Path(args.report) / 'index.html'}")
    for name, values in figures.items():  # as the fit warns: a figure that says "do not trust"
        r2 = values.get("r2", 1.0)
        if r2 < LOW_R2:
            print(
                f"warning: {name}: r2 {r2:.3g}: the model explains little of this log's torque; "
                "check the log's units, signs and columns, and that the preset is this car's",
                file=sys.stderr,
            )
    return 0
