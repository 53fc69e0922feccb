"""The panel's configuration: its folder (recordings, presets), credential, hosts, display rate."""

from __future__ import annotations

import secrets
from dataclasses import dataclass, field
from pathlib import Path

STREAM_HZ = 30.0
KINDS = {"shift": "shift", "hpattern": "hpattern", "steering": "steering",
         "sequential": "sequential", "prnd": "prnd"}  # fmt: skip
"""The kinds of preset the panel saves, each in folder/presets/KIND."""


@dataclass
class PanelConfig:
    folder: Path
    """Recordings go to folder/recordings, presets to folder/presets/KIND; nothing leaves it."""
    token: str = field(default_factory=lambda: secrets.token_urlsafe(32))
    """Every request but the page's own files carries it (`Guard`); a panel always has one."""
    hosts: tuple[str, ...] = ("127.0.0.1", "localhost", "[::1]")
    """Host headers accepted (a page elsewhere reaching 127.0.0.1 by DNS rebinding is refused)."""
    loop_cpu: int | None = None
    """Pin the loop's process to this core (benchmarks)."""
    stream_hz: float = STREAM_HZ
