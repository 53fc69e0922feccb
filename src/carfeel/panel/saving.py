"""A session's parameters now as preset files in the panel's folder: written staged, taken back
by the loader, then put in place."""

from __future__ import annotations

import contextlib
import os
import time
from pathlib import Path
from typing import Any

from carfeel.errors import InputError
from carfeel.panel.config import KINDS
from carfeel.panel.session import Session
from carfeel.panel.values import inside


def save_preset(presets: Path, session: Session, name: str) -> dict[str, Any]:
    """The preset NAME (a safe name) of the session's model, in presets/KIND."""
    from carfeel.io import presets as io_presets

    model = session.model
    folder = presets / KINDS[model]
    target = inside(folder, f"{name}.toml")
    if target.exists():
        raise InputError(f"preset {name!r} exists in {folder}: choose another name")
    history = "; ".join(
        f"{path} {change[0]:g} -> {change[1]:g}"
        for record in session.tuning_history
        for path, change in record["changes"].items()
    )
    base = getattr(session, "preset_name", "")
    source = (f"Tuned live in carfeel panel from preset {base} on "
              f"{time.strftime('%Y-%m-%d %H:%M')}: {history or 'no change'}.")  # fmt: skip
    written = []
    p = session.preset
    if model == "shift":
        texts = [(target, "shift", io_presets.to_toml(name, source, {
            "gearbox": p.gearbox, "driver": p.driver}))]  # fmt: skip
    elif model == "steering":
        tables = {"vehicle": p.vehicle, "torque": p.torque, "driver": p.driver}
        if p.tyres is not None:
            tables |= {"tyres": p.tyres, "steering_system": p.steering_system}
        texts = [(target, "steering", io_presets.to_toml(name, source, tables))]
    elif model == "sequential":
        tables = {"lever": p.lever, "driver": p.driver}
        texts = [(target, "sequential", io_presets.to_toml(name, source, tables))]
    elif model == "prnd":
        tables = {"selector": p.selector, "driver": p.driver}
        texts = [(target, "prnd", io_presets.to_toml(name, source, tables))]
    else:
        engagement = inside(presets / "shift", f"{name}-engagement.toml")
        if engagement.exists():
            raise InputError(f"preset {engagement.name} exists: choose another name")
        shift_text = io_presets.to_toml(f"{name}-engagement", source, {
            "gearbox": p.shift.gearbox, "driver": p.shift.driver})  # fmt: skip
        setup = p.setup
        text = io_presets.to_toml(
            name, source,
            {"layout": setup.layout, "select": setup.select, "walls": setup.walls,
             "synchronizer": setup.synchronizer, "feel": setup.feel, "driver": setup.driver},
            extra={"engagement": f"../shift/{engagement.name}"},
        )  # fmt: skip
        texts = [(engagement, "shift", shift_text), (target, "hpattern", text)]
    staged = [(path.with_name(f".{path.stem}.part.toml"), path) for path, _, _ in texts]
    try:
        for (part, _), (_, kind, text) in zip(staged, texts, strict=True):
            if kind == "hpattern":  # checked against the staged engagement beside it
                text = text.replace(f"../shift/{staged[0][1].name}",
                                    f"../shift/{staged[0][0].name}")  # fmt: skip
            part.write_text(text, encoding="utf-8")
        # The loader must take them back: the panel never writes a preset carfeel refuses.
        for (part, _), (_, kind, _) in zip(staged, texts, strict=True):
            if kind == "hpattern":
                io_presets.load_hpattern(str(part))
            else:
                io_presets.load(kind, str(part))
        for (part, path), (_, _, text) in zip(staged, texts, strict=True):
            part.write_text(text, encoding="utf-8")
            os.replace(part, path)
            written.append(path.name)
    finally:
        for part, _ in staged:
            with contextlib.suppress(FileNotFoundError):
                part.unlink()
    return {"saved": written, "preset": f"saved:{name}", "folder": str(folder)}
