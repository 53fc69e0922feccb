"""The shared-memory games: their live maps and file images, behind the UDP receiver's contract.

`FORMAT` (or `FORMAT:live`) reads the game's live map: on Windows its named memory (`mmap` with
the game's tagname), on Linux the file a bridge exposes under /dev/shm (the games run under
Proton; the bridge copies their named memory to a file of the same name). `FORMAT:file:PATH`
reads a file image instead: a `.ibt` telemetry file is replayed record by record at its own
tick rate (60 Hz), a dump of a live map gives its latest buffer.

`poll` is the UDP receiver's: non-blocking (a live map is read in place: the header, then one
copy of the latest buffer, about a microsecond), never raising: a torn frame (the game rewrote
the buffer while it was copied: its tick count changed) is read again once and counted bad if
it tore again; a frame that decodes to garbage is counted bad. The clock of a file replay is
the one `poll` is given (`now_s`: the loop's simulated or wall time) or, without one, the
monotonic clock from the first poll.
"""

from __future__ import annotations

import math
import mmap
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from carfeel.errors import InputError
from carfeel.telemetry import irsdk, pages
from carfeel.telemetry.state import BAD, VehicleState, plausible

MAX_PER_POLL = 64
"""Records a late poll of a file replay may hand on (the older ones are skipped, counted)."""
RETRY_S = 1.0
"""A live map that is not there (the game not running) is looked for again every second."""
SHM_DIR = Path("/dev/shm")


class Reader(Protocol):
    """A game's frames, read from one image (a live map or a file)."""

    car: str
    finished: bool
    """A file image with nothing more to give (the replay is over)."""

    def read(self, now_s: float) -> list[VehicleState | None]:
        """The frames new since the last read (BAD for a torn or garbage one; None for one
        without a vehicle state). Must not block."""
        ...


Opener = Callable[[tuple[Any, ...], bool, str], Reader]
"""(images: the file's one, or the live maps' one per name; is a file; where) -> Reader;
raises `irsdk.LayoutError` (or ValueError) with the reason where the images are not a layout
the format knows."""


@dataclass(frozen=True, slots=True)
class MapFormat:
    name: str
    describe: str
    map_names: tuple[str, ...]
    """The Windows named memory (its tagname; the Linux file is its last part under /dev/shm)."""
    map_bytes: tuple[int, ...]
    """The size of each named map (Windows maps the size asked for)."""
    open: Opener
    tick_hz: float = 60.0


@dataclass(frozen=True, slots=True)
class MapSource:
    """`FORMAT`, `FORMAT:live` or `FORMAT:file:PATH`."""

    format: MapFormat
    path: Path | None = None
    """The file image; None: the live map."""

    @property
    def text(self) -> str:
        return f"{self.format.name}:file:{self.path}" if self.path else f"{self.format.name}:live"

    @property
    def where(self) -> str:
        if self.path is not None:
            return f"file {self.path.name}"
        if sys.platform == "win32":
            return "shared memory " + ", ".join(self.format.map_names)
        return ", ".join(str(linux_path(n)) for n in self.format.map_names)

    def describe_accept(self) -> str:
        return "this machine's shared memory" if self.path is None else "a file image"


def linux_path(tagname: str) -> Path:
    """Where a bridge exposes `tagname` on Linux: /dev/shm/ and the name after `Local\\`."""
    return SHM_DIR / tagname.rsplit("\\", 1)[-1]


# --- iRacing ------------------------------------------------------------------------------


class IbtReader:
    """A `.ibt` file's records at its tick rate: at time t (from the first read) the records
    up to t x rate have been given, each once."""

    finished = False

    def __init__(self, image: Any, layout: irsdk.Layout) -> None:
        self.image, self.layout = image, layout
        self.session = irsdk.read_session(image, layout)
        self.car = self.session.car
        self.first, self.records, self.claimed = irsdk.disk_records(image, layout)
        self.next = 0
        self.skipped = 0
        """Records a late poll skipped (more than MAX_PER_POLL due at once)."""

    def read(self, now_s: float) -> list[VehicleState | None]:
        due = min(self.records, int(now_s * self.layout.tick_rate_hz + 1e-9) + 1)
        if due <= self.next:
            self.finished = self.next >= self.records
            return []
        start = max(self.next, due - MAX_PER_POLL)
        self.skipped += start - self.next
        self.next = due
        layout, session, first = self.layout, self.session, self.first
        size = layout.buffer_bytes
        return [
            irsdk.decode_record(layout, self.image, first + i * size, session)
            for i in range(start, due)
        ]


class LiveReader:
    """iRacing's live map (or a dump of it): the latest of the rotating buffers, once per tick
    count; the session info again when its update count moves (a new car, a new session)."""

    def __init__(self, image: Any, layout: irsdk.Layout, is_file: bool) -> None:
        self.image, self.layout, self.is_file = image, layout, is_file
        self.session = irsdk.read_session(image, layout)
        self.car = self.session.car
        self.update = irsdk.header_ticks(image)[1]
        self.tick = -1
        self.finished = False

    def read(self, now_s: float) -> list[VehicleState | None]:
        image = self.image
        status, update, slots = irsdk.header_ticks(image)
        if self.is_file and self.tick >= 0:
            self.finished = True
            return []
        if not status & irsdk.STATUS_CONNECTED:
            return []  # the game is not in a session: nothing new (stale in the loop)
        if update != self.update:
            try:
                self.layout = irsdk.read_layout(image)
                self.session = irsdk.read_session(image, self.layout)
            except (irsdk.LayoutError, ValueError):
                return [BAD]
            self.update, self.car = update, self.session.car
        layout = self.layout
        slot = max(range(layout.buffers), key=lambda i: slots[i][0])
        tick, offset = slots[slot]
        if tick == self.tick:
            return []
        size = layout.buffer_bytes
        if not 0 <= offset <= len(image) - size:
            return [BAD]
        for _ in range(2):  # the game may rewrite the buffer while we copy it: copy again once
            frame = bytes(image[offset : offset + size])
            if irsdk.header_ticks(image)[2][slot][0] == tick:
                self.tick = tick
                return [irsdk.decode_record(layout, frame, 0, self.session)]
            tick = irsdk.header_ticks(image)[2][slot][0]
        self.tick = tick
        return [BAD]  # torn twice


def open_iracing(images: tuple[Any, ...], is_file: bool, where: str) -> Reader:
    image = images[0]
    layout = irsdk.read_layout(image)
    if is_file and irsdk.is_disk_file(image, layout):
        return IbtReader(image, layout)
    return LiveReader(image, layout, is_file)


MAP_FORMATS: dict[str, MapFormat] = {
    f.name: f
    for f in (
        MapFormat(
            "iracing",
            "iRacing (irsdk live memory map; .ibt telemetry files)",
            (irsdk.LIVE_MAP_NAME,),
            (irsdk.LIVE_MAP_SIZE,),
            open_iracing,
        ),
        MapFormat(
            "acc",
            "Assetto Corsa Competizione shared memory (physics, graphics, static pages)",
            pages.AC_MAP_NAMES,
            pages.ACC.page_bytes,
            lambda images, is_file, where: pages.PagesReader(pages.ACC, images, is_file),
            pages.FRAME_HZ,
        ),
        MapFormat(
            "assetto",
            "Assetto Corsa shared memory (physics, graphics, static pages)",
            pages.AC_MAP_NAMES,
            pages.ASSETTO.page_bytes,
            lambda images, is_file, where: pages.PagesReader(pages.ASSETTO, images, is_file),
            pages.FRAME_HZ,
        ),
        MapFormat(
            "scs",
            "Euro Truck Simulator 2 / American Truck Simulator (scs-sdk-plugin rev. 12 map)",
            (pages.SCS_MAP_NAME,),
            (pages.SCS_MAP_BYTES,),
            lambda images, is_file, where: pages.PagesReader(pages.SCS, images, is_file),
            pages.FRAME_HZ,
        ),
        MapFormat(
            "ams2",
            "Automobilista 2 / Project CARS 2 shared memory ($pcars2$, versions 8-14)",
            (pages.AMS2_MAP_NAME,),
            (pages.AMS2_MAP_BYTES,),
            lambda images, is_file, where: pages.PagesReader(pages.AMS2, images, is_file),
            pages.FRAME_HZ,
        ),
        MapFormat(
            "rf2",
            "rFactor 2 / Le Mans Ultimate (rF2SharedMemoryMapPlugin telemetry and scoring)",
            pages.RF2_MAP_NAMES,
            (pages.RF2_TELEMETRY_BYTES, pages.RF2_SCORING_BYTES),
            lambda images, is_file, where: pages.PagesReader(pages.RF2, images, is_file),
            pages.FRAME_HZ,
        ),
        MapFormat(
            "r3e",
            "RaceRoom shared memory ($R3E, r3e.h version 3.4)",
            (pages.R3E_MAP_NAME,),
            (pages.R3E_MAP_BYTES,),
            lambda images, is_file, where: pages.PagesReader(pages.R3E, images, is_file),
            pages.FRAME_HZ,
        ),
    )
}
UDP_TOO = frozenset({"assetto"})
"""Formats that are UDP as well: bare or FORMAT:HOST:PORT is the UDP source; the map is
FORMAT:live and the image FORMAT:file:PATH."""


# --- opening images ----------------------------------------------------------------------


def _read_file(path: Path) -> Any:
    """The file's bytes, mapped read-only (an hour of .ibt is a gigabyte: not read in)."""
    try:
        with path.open("rb") as handle:
            if path.stat().st_size == 0:
                return b""
            return mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot be read ({exc})") from exc


def _open_map(name: str, size: int) -> Any | None:
    if sys.platform == "win32":
        try:
            return mmap.mmap(-1, size, tagname=name, access=mmap.ACCESS_READ)
        except OSError:
            return None
    path = linux_path(name)
    try:
        with path.open("rb") as handle:
            return mmap.mmap(handle.fileno(), 0, access=mmap.ACCESS_READ)
    except (OSError, ValueError):
        return None


def _open_live(fmt: MapFormat) -> tuple[Any, ...] | None:
    """The live maps' images (one per name), or None if the game has not made them all."""
    images: list[Any] = []
    for name, size in zip(fmt.map_names, fmt.map_bytes, strict=True):
        image = _open_map(name, size)
        if image is None:
            for opened in images:
                opened.close()
            return None
        images.append(image)
    return tuple(images)


class MapReceiver:
    """A shared-memory source with the UDP `Receiver`'s counters and `poll`."""

    def __init__(self, source: MapSource) -> None:
        self.source = source
        self.format = source.format
        self.latest = VehicleState()
        self.packets = self.bad = self.ignored = self.foreign = self.errors = 0
        self.foreign_from: dict[str, int] = {}
        self.first_error = ""
        self.notes: list[str] = []
        """What the run's summary should say of this source (the car's profile)."""
        self.torque_scale_Nm = math.nan
        """The car profile's torque scale (the game's torque at the wheel's full force), N*m."""
        self.first_ns = self.arrival_ns = 0
        self.socket = None
        self.where = source.where
        self.bound = (self.where, 0)
        self.address = self.bound
        self.reader: Reader | None = None
        self._images: tuple[Any, ...] = ()
        self._looked_s = -math.inf
        self._origin: tuple[bool, float] | None = None
        self.arrival_s = math.nan
        """The poll's clock when the latest good frame came."""
        if source.path is not None:
            image = _read_file(source.path)
            try:
                self.reader = source.format.open((image,), True, str(source.path))
            except ValueError as exc:
                raise InputError(
                    f"{source.text}: not a {source.format.describe} image: {exc}"
                ) from None
            self._images = (image,)
            self.latest = VehicleState(car=self.reader.car)
        else:
            if sys.platform != "win32" and not sys.platform.startswith("linux"):
                raise InputError(
                    f"{source.text}: a game's live map is read on Windows (its named memory) "
                    f"and on Linux (a bridge's file under {SHM_DIR}); {sys.platform} has "
                    f"neither: read a file image ({source.format.name}:file:PATH)"
                )
            self._look()

    @property
    def car(self) -> str:
        return self.reader.car if self.reader is not None else ""

    @property
    def finished(self) -> bool:
        return self.reader is not None and self.reader.finished

    def _look(self) -> None:
        self._looked_s = time.monotonic()
        images = _open_live(self.format)
        if images is None:
            return
        try:
            self.reader = self.format.open(images, False, self.where)
            self._images = images
            self.latest = self.latest._replace(car=self.reader.car)
        except ValueError as exc:  # the game made the map but has not filled it yet
            self.first_error = self.first_error or f"{self.where}: {exc}"
            for image in images:
                image.close()

    def _clock(self, now_s: float | None) -> float:
        given = now_s is not None
        t = now_s if now_s is not None else time.monotonic()
        if self._origin is None or self._origin[0] != given:
            self._origin = (given, t)  # a replay starts at its first poll of this clock
        return t - self._origin[1]

    def poll(
        self, sink: Callable[[VehicleState], object] | None = None, now_s: float | None = None
    ) -> int:
        """Read what is new; `sink` gets every good state in order. Never raises."""
        t = self._clock(now_s)
        reader = self.reader
        if reader is None:
            if time.monotonic() - self._looked_s > RETRY_S:
                self._look()
            return 0
        try:
            frames = reader.read(t)
        except Exception as exc:  # a reader's bug must not end a session: counted, named
            self.errors += 1
            self.bad += 1
            self.first_error = self.first_error or f"{type(exc).__name__}: {exc}"
            return 0
        fresh = 0
        for state in frames:
            if state is None:
                self.ignored += 1
            elif plausible(state):
                self.latest = state
                fresh += 1
                if sink is not None:
                    sink(state)
            else:
                self.bad += 1
        if fresh:
            self.packets += fresh
            self.arrival_ns = time.perf_counter_ns()  # a map's frame: when it was seen
            self.first_ns = self.first_ns or self.arrival_ns
            self.arrival_s = t
        return fresh

    def flush(self, limit: int = 0) -> int:
        """Nothing queues in a map: the latest is all there is."""
        return 0

    def counts(self) -> str:
        text = f"{self.packets} good frames, {self.bad} bad, {self.ignored} ignored"
        skipped = getattr(self.reader, "skipped", 0)
        if skipped:
            text += f", {skipped} skipped (late polls)"
        if self.reader is None:
            text += f" (no {self.format.name} map at {self.where}: is the game running?)"
        if self.errors:
            text += f"; {self.errors} raised in the decoder (a bug: {self.first_error})"
        return text

    def close(self) -> None:
        images, self._images = self._images, ()
        for image in images:
            if isinstance(image, mmap.mmap):
                image.close()

    def __enter__(self) -> MapReceiver:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def parse_map_source(text: str) -> MapSource | None:
    """A shared-memory source from its text, or None where FORMAT is not a map format."""
    name, _, rest = text.partition(":")
    fmt = MAP_FORMATS.get(name)
    if fmt is None:
        return None
    if name in UDP_TOO and rest != "live" and not rest.startswith("file:"):
        return None  # the UDP source of the same name (assetto:HOST:PORT)
    if rest in ("", "live"):
        return MapSource(fmt)
    kind, _, path = rest.partition(":")
    if kind != "file" or not path:
        raise InputError(
            f"telemetry source {text!r}: {name} reads its live map ({name} or {name}:live) or "
            f"a file image ({name}:file:PATH)"
        )
    return MapSource(fmt, Path(path))
