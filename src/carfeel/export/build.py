"""The FMU's binary: the C compiler called directly (gcc, Linux x86-64: the fast path) or FMPy's
CMake build of the FMU's own sources/ (other platforms), with the flags that keep the C port's
arithmetic Python's; the FMI headers from FMPy; the C ports alone for tests and benchmarks.
"""

from __future__ import annotations

import importlib.util
import os
import platform
import shutil
import subprocess
import tempfile
from collections.abc import Sequence
from pathlib import Path

from carfeel.export.csource import HEADERS, PORT_SOURCES, c_source_dir
from carfeel.export.variables import FMI_VERSIONS, ExportError

CFLAGS = (
    "-std=c99",
    "-O2",
    "-ffp-contract=off",  # no fused multiply-add: Python rounds every operation
    "-fno-fast-math",
    "-fno-builtin",  # libm's pow(x, 2.0) as Python calls it, not x * x; no sin+cos -> sincos
    "-fPIC",
    "-fvisibility=hidden",  # only the fmi2*/fmi3* functions are exported
    "-Wall",
    "-Wextra",
)
"""How the FMU's library is compiled; the same flags give the port's bit-for-bit equality."""

PLATFORM_FOLDER = {2: "linux64", 3: "x86_64-linux"}
"""The folder under binaries/ of the Linux x86-64 library, by FMI version (each standard's name)."""


def fmi_header_dir() -> Path:
    """The FMI headers FMPy ships (its c-code folder); ExportError naming the extra without it."""
    spec = importlib.util.find_spec("fmpy")
    if spec is None or spec.origin is None:
        raise ExportError(
            "FMU export takes the standard FMI headers from FMPy, which is not installed: "
            "pip install 'carfeel[fmu]'"
        )
    folder = Path(spec.origin).parent / "c-code"
    missing = [h for v in FMI_VERSIONS for h in HEADERS[v] if not (folder / h).is_file()]
    if missing:
        raise ExportError(
            f"the installed FMPy ({folder}) lacks the FMI headers {', '.join(missing)}: "
            "reinstall it with pip install --force-reinstall 'carfeel[fmu]'"
        )
    return folder


def find_compiler() -> str:
    """The C compiler ($CC, else cc or gcc); ExportError naming the package to install."""
    wanted = os.environ.get("CC")
    for name in ([wanted] if wanted else []) + ["cc", "gcc"]:
        found = shutil.which(name)
        if found:
            return found
    raise ExportError(
        "no C compiler found (looked for "
        + (f"$CC={wanted}, " if wanted else "")
        + "cc and gcc): install the distribution's gcc package (Debian and Ubuntu: "
        "apt-get install gcc; Fedora: dnf install gcc) or set CC to a C99 compiler"
    )


def check_platform() -> None:
    """The binaries are built for Linux x86-64; elsewhere ExportError says so."""
    system, machine = platform.system(), platform.machine().lower()
    if system != "Linux" or machine not in ("x86_64", "amd64"):
        raise ExportError(
            f"FMU binaries are built for Linux x86-64 only; this is {system} {machine}. "
            "Export on a Linux x86-64 machine (the FMU's sources/ build elsewhere too)"
        )


def compile_library(compiler: str, folder: Path, sources: Sequence[str], library: Path) -> None:
    """Compile `sources` (in `folder`) into the shared library `library`."""
    command = [
        compiler, *CFLAGS, "-shared", "-I", str(folder), "-o", str(library),
        *(str(folder / s) for s in sources), "-lm",
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise ExportError(
            f"the C compiler failed ({' '.join(command)}):\n{done.stderr.strip()}\n"
            "this is a bug in carfeel's FMU export or an unusual compiler: please report it"
        )
    if done.stderr.strip():
        raise ExportError(f"the C compiler warned, which carfeel's sources must not make it do:\n"
                          f"{done.stderr.strip()}")  # fmt: skip


BUILDERS = ("auto", "gcc", "cmake")
"""How the FMU's binary is built: gcc (the C compiler called directly: Linux x86-64), cmake
(FMPy's CMake build of the FMU's own sources/: Windows with Visual Studio or MinGW, macOS,
Linux), auto (gcc where it applies, else cmake)."""


def choose_builder(builder: str) -> str:
    """The builder to use here (see BUILDERS); ExportError naming what to install."""
    if builder not in BUILDERS:
        raise ExportError(f"--build {builder!r}: choose one of {', '.join(BUILDERS)}")
    system, machine = platform.system(), platform.machine().lower()
    linux64 = system == "Linux" and machine in ("x86_64", "amd64")
    if builder == "auto":
        has_cc = any(shutil.which(n) for n in (os.environ.get("CC") or "", "cc", "gcc") if n)
        if linux64 and not has_cc and shutil.which("cmake") is None:
            find_compiler()  # names the compiler to install (the fast path here)
        builder = "gcc" if linux64 and has_cc else "cmake"
    if builder == "cmake" and shutil.which("cmake") is None:
        raise ExportError(
            "FMPy's CMake build needs cmake on the PATH (pip install cmake, or the system's "
            "package), and a C compiler it finds (Visual Studio's Build Tools on Windows, "
            "Xcode's command line tools on macOS, gcc on Linux)"
        )
    return builder


def cmake_flags() -> str:
    """The compiler flags that keep the C port's arithmetic Python's (no contraction into fused
    multiply-adds, no fast math, libm's functions as called), for CMake's C compiler."""
    if platform.system() == "Windows":
        return "/fp:strict"
    return " ".join(f for f in CFLAGS if f.startswith("-f"))


def cmake_build(root: Path) -> None:
    """FMPy's CMake build of the staged FMU folder `root` (its sources/ and model description)
    into its binaries/ folder for this platform."""
    try:
        import fmpy.build
    except ImportError:
        raise ExportError(
            "FMPy's CMake build is missing: pip install 'carfeel[fmu]' (FMPy 0.3.20 or newer)"
        ) from None
    cmake = shutil.which("cmake") or "cmake"
    project = (Path(fmpy.build.__file__).parent / "c-code").as_posix()
    with tempfile.TemporaryDirectory(prefix="carfeel-cmake-") as build:
        # FMPy's settings (sources, target folder per platform, the model's identifier), and
        # CMake run here with its output kept: shown only when it fails.
        fmpy.build.create_cmake_settings(
            root, build, cmake_options={"CMAKE_C_FLAGS:STRING": cmake_flags()}
        )
        for command in (
            [cmake, "-S", project, "-B", build],
            [cmake, "--build", build, "--target", "install", "--config", "Release"],
        ):
            done = subprocess.run(command, capture_output=True, text=True, check=False)
            if done.returncode != 0:
                raise ExportError(
                    f"FMPy's CMake build of the FMU failed ({' '.join(command)}):\n"
                    f"{(done.stdout + done.stderr).strip()[-3000:]}\nA C compiler CMake finds "
                    "is needed (Visual Studio's Build Tools on Windows, Xcode's command line "
                    "tools on macOS, gcc on Linux)"
                )
    if not any((root / "binaries").rglob("*.*")):
        raise ExportError("FMPy's CMake build produced no binary: this is a bug, please report it")


def build_port_library(folder: Path) -> Path:
    """The C ports alone (cf_engagement.c, cf_steering.c) as a shared library in `folder`,
    compiled as the FMUs are: for driving the C step from Python (tests, benchmarks)."""
    library = folder / "carfeel_port.so"
    compile_library(find_compiler(), c_source_dir(), PORT_SOURCES, library)
    return library
