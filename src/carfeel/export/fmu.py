"""FMU export: the steering torque law or the gear engagement as a self-contained C FMU.

An FMU (FMI 2.0 or 3.0, co-simulation) holds `modelDescription.xml`, the C sources under
`sources/` and a shared library built here from those very sources by the distribution's C
compiler (`binaries/linux64/` for FMI 2, `binaries/x86_64-linux/` for FMI 3). No Python runs in
it: any number of instances of any number of carfeel FMUs run in one process.

    carfeel/export/c/cf_engagement.c  port of models/gearshift/engagement.py (+ mechanics, rng)
    carfeel/export/c/cf_steering.c    port of models/steering/torque.py (+ vehicle/single_track)
    carfeel/export/c/cf_model_*.c     each FMU's model: inputs held over a step, parameter checks
    carfeel/export/c/cf_fmu.c         instances, modes, get/set by value reference, whole steps
    carfeel/export/c/cf_fmi2.c, cf_fmi3.c   the FMI functions over cf_fmu.c
    cf_generated.c (written here)     the variables' table and the preset's values

The FMI headers are the standard's (2-clause BSD), copied from the installed FMPy (the extra
`carfeel[fmu]`), as the standard requires them among an FMU's sources. Parameters, their units
and their ranges come from the preset and its schema (`carfeel.schema`).

The export's modules, each with one job: `variables` (Variable, ModelSpec, parameters from the
schema, FMI units), `specs` (the shift and steering FMUs from their presets), `csource` (the
sources/ folder, cf_generated.c), `description` (modelDescription.xml, buildDescription.xml, the
documentation page), `build` (gcc or FMPy's CMake); this module stages and zips them. Its names
below are the export's interface (the command, the API, tests and benchmarks).
"""

from __future__ import annotations

import shutil
import tempfile
import zipfile
from pathlib import Path

from carfeel.export.build import (
    CFLAGS,
    PLATFORM_FOLDER,
    build_port_library,
    check_platform,
    choose_builder,
    cmake_build,
    compile_library,
    find_compiler,
    fmi_header_dir,
)
from carfeel.export.csource import (
    C_STRUCTS,
    HEADERS,
    PORT_SOURCES,
    c_files,
    c_source_dir,
    c_string,
    generated_c,
    source_files,
)
from carfeel.export.description import (
    build_description,
    documentation,
    model_description,
    token_of,
)
from carfeel.export.specs import (
    MODELS,
    STEERING_MODELS,
    physical_steering_spec,
    shift_spec,
    spec_for,
    steering_spec,
)
from carfeel.export.variables import (
    FMI_VERSIONS,
    INTEGER_MAX,
    MAX_NAME_CHARS,
    ExportError,
    ModelSpec,
    check_fmi_version,
    flat_values,
    signed_seed,
)

__all__ = [
    "CFLAGS",
    "C_STRUCTS",
    "FMI_VERSIONS",
    "HEADERS",
    "INTEGER_MAX",
    "MAX_NAME_CHARS",
    "MODELS",
    "PLATFORM_FOLDER",
    "PORT_SOURCES",
    "STEERING_MODELS",
    "ExportError",
    "ModelSpec",
    "build_port_library",
    "c_source_dir",
    "c_string",
    "choose_builder",
    "compile_library",
    "export_fmu",
    "find_compiler",
    "flat_values",
    "generated_c",
    "model_description",
    "physical_steering_spec",
    "shift_spec",
    "signed_seed",
    "spec_for",
    "steering_spec",
    "token_of",
]


def export_fmu(spec: ModelSpec, fmi_version: int, out: Path, builder: str = "auto") -> list[str]:
    """Build the FMU of `spec` into the file `out` (written in one piece: a zip archive), its
    binary by `builder` (BUILDERS).

    Returns the files it holds. Raises ExportError when the platform, the compiler or FMPy's
    headers are missing, before anything is written."""
    check_fmi_version(fmi_version)
    builder = choose_builder(builder)
    compiler = ""
    if builder == "gcc":
        check_platform()
        compiler = find_compiler()
    headers = fmi_header_dir()
    token = token_of(spec, fmi_version)
    with tempfile.TemporaryDirectory(prefix="carfeel-fmu-") as scratch:
        root = Path(scratch)
        sources = _stage_sources(spec, fmi_version, token, headers, root)
        (root / "modelDescription.xml").write_text(
            model_description(spec, fmi_version, token), encoding="utf-8"
        )
        if builder == "gcc":
            binaries = root / "binaries" / PLATFORM_FOLDER[fmi_version]
            binaries.mkdir(parents=True)
            c_names = c_files(spec, fmi_version)
            compile_library(compiler, sources, c_names, binaries / f"{spec.identifier}.so")
        else:
            cmake_build(root)
        documents = root / "documentation"
        documents.mkdir()
        main_page = "index.html" if fmi_version == 3 else "_main.html"  # each standard's name
        (documents / main_page).write_text(documentation(spec, fmi_version), "utf-8")
        return _zip(root, out)


def _stage_sources(
    spec: ModelSpec, fmi_version: int, token: str, headers: Path, root: Path
) -> Path:
    """The FMU's sources/ folder in `root`: carfeel's C files, cf_generated.c, FMPy's FMI
    headers (from `headers`) and FMI 3's buildDescription.xml."""
    sources = root / "sources"
    sources.mkdir()
    ours = c_source_dir()
    for name in source_files(spec, fmi_version):
        if name == "cf_generated.c":
            (sources / name).write_text(generated_c(spec, token), encoding="utf-8")
        elif name in HEADERS[fmi_version]:
            shutil.copyfile(headers / name, sources / name)
        else:
            shutil.copyfile(ours / name, sources / name)
    if fmi_version == 3:
        (sources / "buildDescription.xml").write_text(build_description(spec), "utf-8")
    return sources


def _zip(root: Path, out: Path) -> list[str]:
    names = sorted(p.relative_to(root).as_posix() for p in root.rglob("*") if p.is_file())
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        for name in names:
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = (0o755 if name.endswith(".so") else 0o644) << 16
            archive.writestr(info, (root / name).read_bytes())
    return names
