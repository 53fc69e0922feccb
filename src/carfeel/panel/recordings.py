"""The recordings in the panel's folder: their names and paths checked, listed, started and
stopped in the session, and whether one can be replayed."""

from __future__ import annotations

import contextlib
import json
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.panel.session import Session
from carfeel.panel.values import inside, jsonable, safe_name, said

MAX_SIDECAR_BYTES = 1024 * 1024


def replay_problem(path: Path) -> str | None:
    """Why `path` is not a recording the replay device can play, in words that quote nothing
    of the file (a file is data: its lines never reach an answer); None when it is one."""
    from carfeel.realtime.devices.replay import JOYSTICK_COLUMNS, WHEEL_COLUMNS

    if path.name.endswith(".part.csv"):
        return f"{path.name} is still being recorded: replay it once it is stopped"
    if not path.with_suffix(".json").is_file():
        return f"{path.name} has no sidecar {path.with_suffix('.json').name} (written with it)"
    with path.open("rb") as handle:
        head = handle.read(64 * 1024)
    first, newline, _ = head.partition(b"\n")
    try:
        names = first.decode("utf-8").strip().split(",")
    except UnicodeDecodeError:
        names = []
    kinds = (JOYSTICK_COLUMNS, WHEEL_COLUMNS)
    if not newline or names[:1] != ["time_s"] or not any(set(k) <= set(names) for k in kinds):
        return (
            f"{path.name} is not a carfeel recording: its first line must name time_s and "
            f"{' and '.join(JOYSTICK_COLUMNS)} or {' and '.join(WHEEL_COLUMNS)}"
        )
    return None


def replays(folder: Path) -> list[str]:
    """replay:NAME of every finished recording in the panel's folder."""
    files = sorted(folder.glob("*.csv"))
    done = [p for p in files if not p.name.endswith(".part.csv")]
    return [f"replay:{p.stem}" for p in done if p.with_suffix(".json").is_file()]


def recording_path(folder: Path, name: object) -> Path:
    """The recording NAME (NAME.csv too) as its CSV's path in `folder`."""
    stem = safe_name(name, "recording")
    stem = stem[:-4] if stem.endswith(".csv") else stem
    return inside(folder, f"{stem}.csv")


def record(session: Session, path: Path) -> dict[str, Any]:
    """Start recording to `path` (a new name) in the session's loop."""
    if path.exists() or path.with_suffix(".json").exists():
        raise InputError(f"recording {path.name} exists: choose another name")
    if session.recording is not None:
        raise InputError(f"recording {Path(session.recording).name} is running: stop it first")
    session.send(("record_start", str(path)))
    session.recording = str(path)
    return {"recording": path.name}


def record_stop(session: Session) -> dict[str, Any]:
    if session.recording is None:
        raise InputError("no recording is running")
    session.send(("record_stop",))
    return {"stopping": Path(session.recording).name}


def list_recordings(folder: Path) -> list[dict[str, Any]]:
    out = []
    for csv in sorted(folder.glob("*.csv")):
        partial = csv.name.endswith(".part.csv")
        sidecar = csv.with_suffix(".json")
        summary = None
        # A sidecar is a page of JSON; one of megabytes is not read for a listing.
        if sidecar.is_file() and not partial and sidecar.stat().st_size <= MAX_SIDECAR_BYTES:
            with contextlib.suppress(ValueError, OSError, AttributeError):
                summary = json.loads(sidecar.read_text(encoding="utf-8")).get("summary")
        stat = csv.stat()
        out.append({
            "name": csv.name, "bytes": stat.st_size, "modified": stat.st_mtime,
            "partial": partial, "summary": jsonable(summary),
        })  # fmt: skip
    return out


def recording_file(folder: Path, name: str) -> Path:
    """NAME.csv or NAME.json of a recording in `folder`, which must exist."""
    safe_name(name, "recording file")
    if not name.endswith((".csv", ".json")):
        raise InputError(f"{said(name)}: a recording is NAME.csv with its NAME.json")
    path = inside(folder, name)
    if not path.is_file():
        raise InputError(f"no recording {said(name)} in {folder}")
    return path
