"""What the fit workflows of steering and shift share: progress display, checked presets, and
reading logs of any format (through `carfeel.io.logs`)."""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence
from pathlib import Path

from carfeel.errors import InputError, PresetError
from carfeel.simulation.result import Result


class Progress:
    """A one-line progress display on stderr, for fits that take more than a moment."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label, self.enabled = label, enabled and sys.stderr.isatty()
        self.start = time.monotonic()
        self.shown = False

    def __call__(self, evaluations: int, rms: float) -> None:
        if self.enabled and time.monotonic() - self.start > 0.5:
            self.shown = True
            print(f"\r{self.label}: evaluation {evaluations}, rms {rms:.4g}", end="",
                  file=sys.stderr, flush=True)  # fmt: skip

    def done(self) -> None:
        if self.shown:
            print(file=sys.stderr)


def write_checked_preset(kind: str, out: Path, text: str) -> None:
    """Write a fitted preset only if carfeel's own loader accepts it (ranges, cross-checks);
    else InputError: a fit that leaves the physical ranges means the data, not the preset."""
    from carfeel.io.presets import from_toml

    try:
        from_toml(kind, str(out), text)
    except PresetError as exc:
        raise InputError(
            f"the fit gives a {kind} preset that carfeel would refuse, so {out} is not written:"
            f"\n{exc}\ncheck the logs' units and sign conventions (README, 'From your own car's "
            "logs') and that they hold the manoeuvres the fit needs"
        ) from None
    out.write_text(text)


def read_results(
    paths: Sequence[Path], channels: Path | None = None, dbc: Path | None = None
) -> list[Result]:
    """Each log as carfeel's channels in SI units: CSV as carfeel writes it directly, every
    other format (or any file with a channel map) through `carfeel.io.logs`."""
    from carfeel.io import logs

    channel_map = logs.load_map(channels) if channels is not None else None
    if dbc is not None and not dbc.is_file():
        raise InputError(f"--dbc {dbc}: no such file")
    results = []
    for path in paths:
        if channel_map is None and path.suffix.lower() == ".csv":
            results.append(Result.from_csv(path))
        else:
            results.append(logs.read_channels(path, channel_map, dbc))
    return results
