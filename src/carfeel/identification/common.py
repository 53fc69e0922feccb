"""What the fit workflows of steering and shift share: progress display, checked presets, and
reading logs of any format (through `carfeel.io.logs`)."""

from __future__ import annotations

import contextlib
import hashlib
import os
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from carfeel import progress
from carfeel.errors import InputError, PresetError
from carfeel.simulation.result import Result


@contextlib.contextmanager
def one_blas_thread() -> Iterator[None]:
    """The fits' linear algebra on one BLAS thread. Their matrices are tall and narrow (tens of
    thousands of samples by tens of parameters): OpenBLAS's threads cost more than they give
    there, and on a machine whose cores are busy they wait on each other (measured on the
    acceptance logs on this project's 2-core machines: a law fit 9.7 s with the default threads,
    3.4 s with one; an SVD of 37,595 x 26 0.25 s against 0.04 s). Without threadpoolctl the
    threads are left as they are."""
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:  # pragma: no cover - a dependency of carfeel's
        yield
        return
    with threadpool_limits(limits=1, user_api="blas"):
        yield


class Progress(progress.Progress):
    """A fit's evaluation counter on stderr (a terminal), shown once the fit has taken more than
    half a second."""

    def __init__(self, label: str, enabled: bool) -> None:
        super().__init__(enabled=enabled, delay_s=0.5)
        self.label = label

    def __call__(self, evaluations: int, rms: float) -> None:
        """`evaluations` of the model so far; `rms`: the residuals' at the latest (the fit's
        unit)."""
        self.show(f"{self.label}: evaluation {evaluations}, rms {rms:.4g}")

    def done(self) -> None:
        """End the line, if one was shown."""
        self.close()


def write_checked_preset(
    kind: str, out: Path, text: str, staged: Path | None = None, hints: Sequence[str] = ()
) -> None:
    """Write a fitted preset only if carfeel's own loader accepts it (ranges, cross-checks);
    else InputError naming `out`, with the fit's `hints` (its warnings): a fit that leaves the
    physical ranges means the data, not the preset. With `staged` (from `Outputs.add`) the text
    goes there and the command puts it in place; else it replaces `out` in one step."""
    from carfeel.io.presets import from_toml

    try:
        from_toml(kind, str(out), text)
    except PresetError as exc:
        said = str(exc)
        extra = [hint for hint in hints if hint.split(": ", 1)[-1] not in said]
        found = "".join(f"\n  {hint}" for hint in extra)
        found = f"\nthe fit warned:{found}" if found else ""
        raise InputError(
            f"the fit gives a {kind} preset that carfeel would refuse, so {out} is not written:"
            f"\n{exc}{found}\ncheck the logs' units and sign conventions (README, 'From your own "
            "car's logs') and that they hold the manoeuvres the fit needs"
        ) from None
    if staged is not None:
        staged.write_text(text, encoding="utf-8")
        return
    # Replaced in one step: a failure while writing leaves the user's file as it was.
    partial = out.with_name(f".{out.name}.part")
    partial.write_text(text, encoding="utf-8")
    os.replace(partial, out)


def read_results(
    paths: Sequence[Path], channels: Path | None = None, dbc: Path | None = None
) -> list[Result]:
    """Each log as carfeel's channels in SI units, through `carfeel.io.logs` (a CSV named in
    carfeel's way needs no map). Every file's size is checked before any is read."""
    from carfeel.io import logs

    channel_map = logs.load_map(channels) if channels is not None else None
    if dbc is not None and not dbc.is_file():
        raise InputError(f"--dbc {dbc}: no such file")
    for path in paths:
        logs.check_size(path)
    seen: dict[bytes, Path] = {}
    for path in paths:
        try:
            with path.open("rb") as handle:
                digest = hashlib.file_digest(handle, "sha256").digest()
        except OSError:
            continue  # the reader below names the problem
        if digest in seen:
            raise InputError(
                f"{path} and {seen[digest]} hold the same log: given twice it would count twice "
                "and shrink the uncertainties by the square root of two; give each log once"
            )
        seen[digest] = path
    results: list[Result] = []
    for path in paths:
        result = logs.read_channels(path, channel_map, dbc)
        check_physical(result, path)
        for other, earlier in zip(paths, results, strict=False):
            if _same_log(result, earlier):
                raise InputError(
                    f"{path} and {other} hold the same log (in two files or formats): given "
                    "twice it would count twice and shrink the uncertainties by the square "
                    "root of two; give each log once"
                )
        results.append(result)
    return results


def _same_log(a: Result, b: Result) -> bool:
    """The same samples, to a CSV's digits: the time stamps (from the start) and the measured
    torque or force."""
    if len(a) != len(b) or len(a) == 0:
        return False

    def measured(r: Result) -> Any:  # torque_Nm is what carfeel simulate writes for it
        return next(
            (r[n] for n in ("steering_torque_Nm", "torque_Nm", "force_N") if n in r.names), None
        )

    fa, fb = measured(a), measured(b)
    if fa is None or fb is None:
        return False
    ta, tb = a.time_s - a.time_s[0], b.time_s - b.time_s[0]
    return bool(
        np.allclose(ta, tb, rtol=1e-7, atol=1e-9)
        and np.allclose(fa, fb, rtol=1e-6, atol=1e-9, equal_nan=True)
    )


PHYSICAL_LIMITS = {
    "torque_Nm": 200.0,
    "steering_torque_Nm": 200.0,
    "steering_angle_rad": 20.0,
    "steering_rate_rad_s": 100.0,
    "speed_m_s": 150.0,
    "lateral_accel_m_s2": 50.0,
    "force_N": 2000.0,
    "position_m": 1.0,
}
"""Magnitudes no car's steering or gearshift reaches (about 3 turns of a wheel either way, 540
km/h, 5 g, 200 kgf at a knob): beyond them a sample is a logging error, not a measurement."""

UNIT_HINTS = {
    "steering_angle_rad": "an angle in degrees? convert it to radians",
    "steering_rate_rad_s": "a rate in deg/s? convert it to rad/s",
    "speed_m_s": "a speed in km/h or mph? convert it to m/s",
    "torque_Nm": "a torque in Ncm or Nmm? convert it to Nm",
    "steering_torque_Nm": "a torque in Ncm or Nmm? convert it to Nm",
    "position_m": "a position in mm? divide it by 1000",
}
"""The unit mistake each limit most often catches."""


def check_physical(result: Result, path: Path) -> None:
    """Refuse values no car produces, and Ay at a standstill (a speed in the wrong unit or
    column): each named with its line and the fix."""
    for name, limit in PHYSICAL_LIMITS.items():
        if name not in result.names:
            continue
        values = np.asarray(result[name])
        if values.dtype.kind != "f":
            continue
        beyond = np.flatnonzero(np.abs(values) > limit)
        if len(beyond):
            i = int(beyond[0])
            hint = f" ({UNIT_HINTS[name]})" if name in UNIT_HINTS else ""
            raise InputError(
                f"{path}, line {i + 2}: {name} = {float(values[i]):.4g}, beyond the {limit:g} no "
                f"car reaches: a logging error or a unit{hint}, not a measurement; remove the "
                "sample or fix the column (or the channel map's unit and scale)"
            )
    if "speed_m_s" in result.names and "lateral_accel_m_s2" in result.names:
        speed = np.asarray(result["speed_m_s"])
        ay = np.asarray(result["lateral_accel_m_s2"])
        if speed.dtype.kind == "f" and ay.dtype.kind == "f" and len(speed):
            parked = np.abs(speed) < 0.5
            if parked.mean() > 0.9 and np.median(np.abs(ay[parked])) > 1.0:
                raise InputError(
                    f"{path}: the car stands (speed under 0.5 m/s in {parked.mean():.0%} of the "
                    f"samples) yet Ay is {float(np.median(np.abs(ay[parked]))):.2g} m/s^2: a car "
                    "at rest has none; check the speed column (its unit, or the wrong signal)"
                )


def check_torque_logged(where: str, column: str, torque: np.ndarray) -> None:
    """Refuse a torque channel that holds one value throughout: it logged nothing (all-zero
    torque read as 'the opposite sign of Ay' before), or it is the wrong signal."""
    if len(torque) > 1 and np.ptp(torque) == 0.0:
        raise InputError(
            f"{where}: {column} is {float(torque[0]):.4g} Nm in every row: the channel logged "
            "nothing (or it is the wrong signal); check the column"
        )
