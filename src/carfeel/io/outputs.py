"""A command's output files, all or nothing.

Every command that writes files goes through `Outputs`: each path is checked before anything
runs (a real probe of the folder, not a permission bit: root may be refused by /proc or a
read-only mount), written under a temporary name beside its final one, and moved into place
only when the whole command has succeeded. A failed command leaves the user's files as they were.

    outputs = Outputs()
    csv = outputs.add(Path("run.csv"), ".csv")      # checked now; write to the returned path
    png = outputs.add(Path("run.png"), ".png")
    with outputs:                                    # commits on success, discards on error
        write(csv); plot(png)

Files are created with the usual permissions (0666 less the umask), as any other program's.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
from pathlib import Path
from types import TracebackType

from carfeel.errors import InputError


def check_writable(path: Path, suffix: str | None = None) -> None:
    """Raise InputError unless `path` can be written: its suffix, its folder, not a folder."""
    if not path.name or str(path) in ("", "."):
        raise InputError("an output file name is empty: give a file name")
    if suffix is not None and path.suffix.lower() != suffix:
        raise InputError(f"{path}: expected a {suffix} file name")
    folder = path.parent
    if not folder.is_dir():
        raise InputError(f"cannot write {path}: folder {folder} does not exist")
    if path.is_dir():
        raise InputError(f"cannot write {path}: it is a folder")
    try:
        fd, probe = tempfile.mkstemp(dir=folder, prefix=".carfeel-probe-")
    except OSError as exc:
        raise InputError(
            f"cannot write {path}: folder {folder} does not take new files ({exc.strerror or exc})"
        ) from None
    os.close(fd)
    os.unlink(probe)


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class Outputs:
    """Output files staged under temporary names, committed together (see the module)."""

    def __init__(self) -> None:
        self._staged: list[tuple[Path, Path]] = []

    def add(self, path: Path, suffix: str | None = None, partial: bool = False) -> Path:
        """Check `path` and return where to write it until the command has succeeded.

        `partial=True` gives a visible name, NAME.part.SUFFIX (a recording a killed run leaves
        readable); otherwise a hidden temporary name."""
        check_writable(path, suffix)
        if partial:
            staged = path.with_name(f"{path.stem}.part{path.suffix}")
        else:
            fd, name = tempfile.mkstemp(
                dir=path.parent, prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}"
            )
            os.close(fd)
            staged = Path(name)
        self._staged.append((staged, path))
        return staged

    def commit(self) -> None:
        mode = 0o666 & ~_umask()
        for staged, final in self._staged:
            if staged.exists():
                os.chmod(staged, mode)
                os.replace(staged, final)
        self._staged.clear()

    def discard(self) -> None:
        for staged, _ in self._staged:
            with contextlib.suppress(OSError):
                staged.unlink()
        self._staged.clear()

    def __enter__(self) -> Outputs:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.discard()
