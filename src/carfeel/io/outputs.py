"""A command's output files, all or nothing.

Every command that writes files goes through `Outputs`: each path is checked before anything
runs (a real probe of the folder, not a permission bit: root may be refused by /proc or a
read-only mount), written under a temporary name beside its final one, and moved into place
only when the whole command has succeeded. A failed command leaves the user's files as they were.

    outputs = Outputs()
    csv = outputs.add(Path("run.csv"), ".csv")      # checked now; write to the returned path
    png = outputs.add(Path("run.png"), ".png")
    report = outputs.add_folder(Path("report"))     # a folder: index.html and its figures
    with outputs:                                    # commits on success, discards on error
        write(csv); plot(png); draw(report)

Files are created with the usual permissions (0666 less the umask, folders 0777 less it), as any
other program's. A folder is staged as a whole in a temporary folder beside it: a new folder, an
empty one or one that holds only a report (index.html and PNG figures) is replaced as a whole, so
no figure of an older report is left behind; a folder that holds anything else keeps it, and the
report's files are replaced in it one by one.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from pathlib import Path
from types import TracebackType

from carfeel.errors import CarfeelError, InputError


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


def check_folder(path: Path) -> None:
    """Raise InputError unless `path` can become (or be replaced by) an output folder."""
    if not path.name or str(path) in ("", "."):
        raise InputError("an output folder name is empty: give a folder name")
    if path.exists() and not path.is_dir():
        raise InputError(f"cannot write the folder {path}: it exists and is not a folder")
    parent = path.parent
    if not parent.is_dir():
        raise InputError(f"cannot write the folder {path}: folder {parent} does not exist")
    try:
        probe = tempfile.mkdtemp(dir=parent, prefix=".carfeel-probe-")
    except OSError as exc:
        raise InputError(
            f"cannot write the folder {path}: folder {parent} does not take new files "
            f"({exc.strerror or exc})"
        ) from None
    os.rmdir(probe)


REPORT_FILES = (".html", ".png")
"""What a report folder holds; a folder with only these is replaced as a whole."""


def _only_a_report(folder: Path) -> bool:
    return all(
        entry.is_file() and not entry.is_symlink() and entry.suffix.lower() in REPORT_FILES
        for entry in folder.iterdir()
    )


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


class Outputs:
    """Output files staged under temporary names, committed together (see the module)."""

    def __init__(self) -> None:
        self._staged: list[tuple[Path, Path]] = []
        self._folders: list[tuple[Path, Path]] = []

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

    def add_folder(self, path: Path) -> Path:
        """Check `path` and return an empty folder to write it in until the command has
        succeeded (see the module for how it replaces a folder that exists)."""
        check_folder(path)
        staged = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp"))
        self._folders.append((staged, path))
        return staged

    def commit(self) -> None:
        mask = _umask()
        for staged, final in self._staged:
            if staged.exists():
                os.chmod(staged, 0o666 & ~mask)
                os.replace(staged, final)
        self._staged.clear()
        for staged, final in self._folders:
            _commit_folder(staged, final, mask)
        self._folders.clear()

    def discard(self) -> None:
        for staged, _ in self._staged:
            with contextlib.suppress(OSError):
                staged.unlink()
        self._staged.clear()
        for staged, _ in self._folders:
            shutil.rmtree(staged, ignore_errors=True)
        self._folders.clear()

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
            return
        names = self._finals()
        self.discard()
        # A failure names the user's files, not the temporary ones they were staged as.
        if isinstance(exc, OSError):
            for attribute in ("filename", "filename2"):
                value = getattr(exc, attribute, None)
                if isinstance(value, str | os.PathLike):
                    setattr(exc, attribute, _renamed(os.fspath(value), names))
        elif isinstance(exc, CarfeelError):
            text = _renamed(str(exc), names)
            if text != str(exc):
                raise type(exc)(text) from None

    def _finals(self) -> dict[str, str]:
        return {str(staged): str(final) for staged, final in (*self._staged, *self._folders)}


def _commit_folder(staged: Path, final: Path, mask: int) -> None:
    """Put a staged folder in place of `final` (the module says how)."""
    os.chmod(staged, 0o777 & ~mask)
    for entry in staged.iterdir():
        if entry.is_file():
            os.chmod(entry, 0o666 & ~mask)
    if final.is_dir() and (final.is_symlink() or not _only_a_report(final)):
        for entry in staged.iterdir():  # the user's other files (or link) stay
            shutil.move(entry, final / entry.name)  # a link may lead to another file system
        staged.rmdir()
        return
    old = None
    if final.is_dir():
        old = Path(tempfile.mkdtemp(dir=final.parent, prefix=f".{final.name}.", suffix=".old"))
        os.replace(final, old / final.name)
    os.replace(staged, final)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _renamed(text: str, names: dict[str, str]) -> str:
    """`text` with every staged path in it replaced by its final one."""
    for staged, final in sorted(names.items(), key=lambda item: -len(item[0])):
        text = text.replace(staged, final)
    return text
