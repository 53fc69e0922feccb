"""MDF4 / MDF3 logs through asammdf (the extra carfeel[logs]): each numeric channel with its
channel group's time stamps, the groups' sizes checked before a channel is read."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from carfeel.errors import InputError
from carfeel.io import log_limits as limits
from carfeel.io.log_limits import too_many
from carfeel.io.log_signals import Signal, lazy_extra


def read_mdf(path: Path, wanted: set[str] | None = None) -> list[Signal]:
    """An MDF file's numeric one-dimensional channels (only `wanted` ones, if given) as signals,
    each with its channel group; master (time) channels and others asammdf cannot give as
    numbers are left out."""
    lazy_extra("mdf", path)
    from asammdf import MDF

    try:
        mdf = MDF(str(path))
    except Exception as exc:  # asammdf raises many kinds for a broken file
        raise InputError(f"{path}: not a readable MDF file ({str(exc)[:200]})") from None
    signals = []
    try:
        masters = {(g, i) for g, i in mdf.masters_db.items()}
        chosen = [
            (name, g, i) for name, places in mdf.channels_db.items()
            for g, i in places if (g, i) not in masters and (wanted is None or name in wanted)
        ]  # fmt: skip
        total = 0
        for _, g, _ in chosen:
            cycles = int(mdf.groups[g].channel_group.cycles_nr)
            if cycles > limits.MAX_SAMPLES:
                raise too_many(path, "has", f"{cycles:,} samples in channel group {g}",
                               limits.MAX_SAMPLES)  # fmt: skip
            total += 2 * cycles
        if total > limits.MAX_VALUES:
            raise too_many(path, "holds", f"{total:,} values in the channels read",
                           limits.MAX_VALUES)  # fmt: skip
        for name, g, i in chosen:
            try:
                signal = mdf.get(name, group=g, index=i)
            except Exception:  # a channel asammdf cannot give as numbers: not a signal
                continue
            samples = np.asarray(signal.samples)
            if samples.dtype.kind not in "fiub" or samples.ndim != 1:
                continue
            signals.append(
                Signal(name, np.asarray(signal.timestamps, dtype=float),
                       samples.astype(float), str(signal.unit or "")[:40], g)
            )  # fmt: skip
    finally:
        mdf.close()
    return signals
