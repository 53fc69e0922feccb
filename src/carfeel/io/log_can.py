"""CAN logs decoded with the car's DBC through python-can and cantools (the extra
carfeel[logs]): candump -l .log, Vector .asc and .blf; each signal named MESSAGE.SIGNAL, with the
time stamps of the frames that carry it. The DBC's size and scales are checked before a frame is
decoded."""

from __future__ import annotations

import math
from array import array
from pathlib import Path
from typing import Any

import numpy as np

from carfeel.errors import InputError
from carfeel.io import log_limits as limits
from carfeel.io.log_limits import byte_size, too_many
from carfeel.io.log_signals import Signal, lazy_extra


def read_can(path: Path, dbc: Path, wanted: set[str] | None) -> list[Signal]:
    """A CAN log's signals as `dbc` decodes them (only `wanted` MESSAGE.SIGNAL ones, if given),
    in the DBC's units."""
    can = lazy_extra("can", path)
    try:
        import cantools
    except ImportError:
        raise InputError(
            f"{path}: decoding a CAN log needs the optional extra: pip install 'carfeel[logs]'"
        ) from None
    db = _load_dbc(cantools, dbc)
    messages = {m.frame_id: m for m in getattr(db, "messages", [])}
    if wanted is not None:
        names = {w.split(".", 1)[0] for w in wanted}
        messages = {i: m for i, m in messages.items() if m.name in names}
    _check_scales(dbc, messages, wanted)
    times, values = _decode(can, path, dbc, messages)
    units = {f"{m.name}.{s.name}": s.unit or "" for m in messages.values() for s in m.signals}
    return [
        Signal(k, np.frombuffer(times[k], dtype=float), np.frombuffer(values[k], dtype=float),
               units.get(k, ""))
        for k in times
    ]  # fmt: skip


def _load_dbc(cantools: Any, dbc: Path) -> Any:
    """The DBC database, its size checked (MAX_DBC_BYTES) before it is parsed."""
    try:
        size = dbc.stat().st_size
    except FileNotFoundError:
        raise InputError(f"--dbc {dbc}: no such file") from None
    if size > limits.MAX_DBC_BYTES:
        raise InputError(f"--dbc {dbc}: {size:,} bytes, beyond the "
                         f"{byte_size(limits.MAX_DBC_BYTES)} a DBC may have: is it the right "
                         "file?")  # fmt: skip
    try:
        return cantools.database.load_file(str(dbc), strict=False)
    except FileNotFoundError:
        raise InputError(f"--dbc {dbc}: no such file") from None
    except RecursionError:
        raise InputError(f"--dbc {dbc}: not a readable DBC file (nested too deep)") from None
    except Exception as exc:  # cantools raises its own parse errors
        raise InputError(f"--dbc {dbc}: not a readable DBC file ({str(exc)[:200]})") from None


def _check_scales(dbc: Path, messages: dict[int, Any], wanted: set[str] | None) -> None:
    """Refuse a signal read whose scale or offset would give values no sensor does (MAX_RAW_VALUE)
    before a frame is decoded."""
    for message in messages.values():
        for s in message.signals:
            scale, offset = float(s.scale), float(s.offset)
            if wanted is not None and f"{message.name}.{s.name}" not in wanted:
                continue
            if not all(
                math.isfinite(v) and abs(v) <= limits.MAX_RAW_VALUE for v in (scale, offset)
            ):
                raise InputError(
                    f"--dbc {dbc}: {message.name}.{s.name} has scale {scale:g} and offset "
                    f"{offset:g}: its values would reach beyond anything a sensor gives (1e15) "
                    "or overflow; fix the DBC's factor and offset"
                )


def _decode(
    can: Any, path: Path, dbc: Path, messages: dict[int, Any]
) -> tuple[dict[str, array[float]], dict[str, array[float]]]:
    """Every frame of the log whose message the DBC has, decoded: per MESSAGE.SIGNAL its time
    stamps (s) and values."""
    times: dict[str, array[float]] = {}
    values: dict[str, array[float]] = {}
    frames = matched = 0
    try:
        for frame in can.LogReader(str(path)):
            frames += 1
            if frames > limits.MAX_CAN_FRAMES:
                raise too_many(path, "has", f"over {limits.MAX_CAN_FRAMES:,} frames",
                               limits.MAX_CAN_FRAMES)  # fmt: skip
            message = messages.get(frame.arbitration_id)
            if message is None:
                continue
            try:
                decoded = message.decode(bytes(frame.data), decode_choices=False)
            except Exception:  # a frame the DBC cannot decode (short, wrong multiplex): skip
                continue
            matched += 1
            for name, value in dict(decoded).items():
                key = f"{message.name}.{name}"
                if key not in times:
                    times[key], values[key] = array("d"), array("d")
                times[key].append(float(frame.timestamp))
                values[key].append(float(value))
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: not a readable CAN log ({str(exc)[:200]})") from None
    if frames == 0:
        raise InputError(f"{path}: no CAN frames found (candump -l .log, Vector .asc or .blf)")
    if matched == 0:
        raise InputError(
            f"{path}: none of its {frames} frames decodes with {dbc}: is it the DBC of this car "
            "and bus?"
        )
    return times, values
