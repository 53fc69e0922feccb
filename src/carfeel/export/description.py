"""The FMU's XML and HTML: modelDescription.xml (FMI 2.0 or 3.0, by xml.etree), an FMI 3
FMU's sources/buildDescription.xml, the documentation page, and the token both the description
and the binary carry.
"""

from __future__ import annotations

import hashlib
import math
import xml.etree.ElementTree as ET

from carfeel import __version__
from carfeel.export.build import CFLAGS
from carfeel.export.csource import c_files
from carfeel.export.variables import (
    FMI_UNITS,
    INTEGER_MAX,
    MODEL_STEP_S,
    ExportError,
    ModelSpec,
    Variable,
    check_fmi_version,
    fmi_unit,
    value_reference,
)


def _number(value: float | int) -> str:
    return str(value) if isinstance(value, int) else repr(float(value))


def token_of(spec: ModelSpec, fmi_version: int) -> str:
    """A GUID-shaped token of everything the binary and the description must agree on."""
    digest = hashlib.sha256(
        repr((__version__, fmi_version, spec.identifier, spec.variables, spec.defaults)).encode()
    ).hexdigest()
    return f"{{{digest[:8]}-{digest[8:12]}-{digest[12:16]}-{digest[16:20]}-{digest[20:32]}}}"


def model_description(spec: ModelSpec, fmi_version: int, token: str) -> str:
    """modelDescription.xml of the FMU, FMI 2.0 or 3.0."""
    check_fmi_version(fmi_version)
    fmi3 = fmi_version == 3
    root = ET.Element("fmiModelDescription")
    root.set("fmiVersion", "3.0" if fmi3 else "2.0")
    root.set("modelName", spec.title)
    root.set("instantiationToken" if fmi3 else "guid", token)
    root.set("description", spec.description)
    root.set("generationTool", f"carfeel {__version__}")
    root.set("version", __version__)
    root.set("variableNamingConvention", "structured")
    if not fmi3:
        root.set("numberOfEventIndicators", "0")
    _co_simulation(root, spec, fmi3)
    _unit_definitions(root, spec, fmi3)
    _type_definitions(root, spec, fmi3)
    categories = ET.SubElement(root, "LogCategories")
    for name, doc in (
        ("logStatusError", "errors: bad values, calls out of order, refused steps"),
        ("logStatusWarning", "warnings"),
    ):
        ET.SubElement(categories, "Category", name=name, description=doc)
    ET.SubElement(
        root, "DefaultExperiment", startTime="0.0", stopTime="10.0", stepSize=repr(MODEL_STEP_S)
    )
    _model_variables(root, spec, fmi_version)
    _model_structure(root, spec, fmi3)
    ET.indent(root)
    text: str = ET.tostring(root, encoding="unicode", xml_declaration=False)
    document = '<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n"
    try:  # a strict parser (expat) reads it back: an importer must be able to
        ET.fromstring(document.encode("utf-8"))
    except ET.ParseError as exc:  # pragma: no cover - checked_name keeps the text well-formed
        raise ExportError(
            f"the model description is not well-formed XML ({exc}): this is a bug in carfeel's "
            "FMU export; please report it"
        ) from None
    return document


def _co_simulation(root: ET.Element, spec: ModelSpec, fmi3: bool) -> None:
    """The CoSimulation element: the capabilities (and FMI 2's list of C files)."""
    cs = ET.SubElement(root, "CoSimulation")
    cs.set("modelIdentifier", spec.identifier)
    cs.set("canHandleVariableCommunicationStepSize", "true")
    if fmi3:
        cs.set("canGetAndSetFMUState", "true")
        cs.set("canSerializeFMUState", "true")
        cs.set("hasEventMode", "false")
    else:
        cs.set("canGetAndSetFMUstate", "true")
        cs.set("canSerializeFMUstate", "true")
        cs.set("canNotUseMemoryManagementFunctions", "true")
        files = ET.SubElement(cs, "SourceFiles")
        for name in c_files(spec, 2):
            ET.SubElement(files, "File").set("name", name)


def _unit_definitions(root: ET.Element, spec: ModelSpec, fmi3: bool) -> None:
    """The units the variables use (and FMI 3's time, s), with their base units."""
    units = sorted({v.unit for v in spec.variables if v.unit} | ({"s"} if fmi3 else set()))
    if units:
        definitions = ET.SubElement(root, "UnitDefinitions")
        for unit in units:
            name, base = FMI_UNITS[unit]
            element = ET.SubElement(definitions, "Unit", name=name)
            ET.SubElement(element, "BaseUnit", {k: str(v) for k, v in base.items()})


def _type_definitions(root: ET.Element, spec: ModelSpec, fmi3: bool) -> None:
    """The enumeration types, their items numbered 0, 1, ..."""
    types = ET.SubElement(root, "TypeDefinitions") if spec.enumerations else root
    for type_name, items in spec.enumerations:
        if fmi3:
            enum = ET.SubElement(types, "EnumerationType", name=type_name)
        else:
            enum = ET.SubElement(ET.SubElement(types, "SimpleType", name=type_name), "Enumeration")
        for value, (item, doc) in enumerate(items):
            ET.SubElement(enum, "Item", name=item, value=str(value), description=doc)


def _typed_attributes(v: Variable, fmi_version: int) -> dict[str, str]:
    """A variable's start, unit, min, max and declared type, as FMI writes them."""
    typed: dict[str, str] = {}
    if v.start is not None:
        typed["start"] = _number(v.start)
    if v.unit:
        typed["unit"] = fmi_unit(v.unit)
    # FMI's min and max are inclusive: an open bound is the next value inside it.
    low, high = v.low, v.high
    if v.is_real and not v.low_inclusive:
        low = math.nextafter(low, math.inf)
    if v.is_real and not v.high_inclusive:
        high = math.nextafter(high, -math.inf)
    if v.kind == "integer" and math.isfinite(high):
        high = min(high, INTEGER_MAX[fmi_version])  # FMI 2's Integer is 32 bits
    if math.isfinite(low) and v.kind in ("real", "integer"):
        typed["min"] = _number(low if v.is_real else int(low))
    if math.isfinite(high) and v.kind in ("real", "integer"):
        typed["max"] = _number(high if v.is_real else int(high))
    if v.kind not in ("real", "integer"):
        typed["declaredType"] = v.kind
    return typed


def _model_variables(root: ET.Element, spec: ModelSpec, fmi_version: int) -> None:
    """ModelVariables: FMI 3's time (value reference 0), then the variables 1..n."""
    fmi3 = fmi_version == 3
    variables = ET.SubElement(root, "ModelVariables")
    if fmi3:
        ET.SubElement(
            variables, "Float64", name="time", valueReference="0", causality="independent",
            variability="continuous", description="Simulation time", unit="s",
        )  # fmt: skip
    for index, v in enumerate(spec.variables):
        attributes = {
            "name": v.name,
            "valueReference": str(value_reference(index)),
            "description": v.description,
            "causality": v.causality,
            "variability": v.variability,
        }
        typed = _typed_attributes(v, fmi_version)
        enumerated = v.kind not in ("real", "integer")
        if fmi3:
            tag = "Float64" if v.is_real else ("Enumeration" if enumerated else v.fmi3_integer)
            ET.SubElement(variables, tag, {**attributes, **typed})
        else:
            scalar = ET.SubElement(variables, "ScalarVariable", attributes)
            tag = "Real" if v.is_real else ("Enumeration" if enumerated else "Integer")
            ET.SubElement(scalar, tag, typed)


def _model_structure(root: ET.Element, spec: ModelSpec, fmi3: bool) -> None:
    """ModelStructure: the outputs and the initial unknowns, none depending on an input."""
    structure = ET.SubElement(root, "ModelStructure")
    outputs = [(i, v) for i, v in enumerate(spec.variables) if v.causality == "output"]
    if fmi3:
        # No output changes with an input before the next step: no direct dependencies.
        for i, _ in outputs:
            ET.SubElement(structure, "Output", valueReference=str(value_reference(i)),
                          dependencies="")  # fmt: skip
        for i, _ in outputs:
            ET.SubElement(structure, "InitialUnknown", valueReference=str(value_reference(i)))
    else:
        listed = ET.SubElement(structure, "Outputs")
        for i, _ in outputs:
            ET.SubElement(listed, "Unknown", index=str(i + 1), dependencies="")
        initial = ET.SubElement(structure, "InitialUnknowns")
        for i, _ in outputs:
            ET.SubElement(initial, "Unknown", index=str(i + 1))


def build_description(spec: ModelSpec) -> str:
    """sources/buildDescription.xml of an FMI 3 FMU: what to compile, and how."""
    root = ET.Element("fmiBuildDescription", fmiVersion="3.0")
    config = ET.SubElement(root, "BuildConfiguration", modelIdentifier=spec.identifier)
    files = ET.SubElement(
        config, "SourceFileSet", language="C99", compiler="gcc",
        compilerOptions=" ".join(flag for flag in CFLAGS if not flag.startswith("-W")),
    )  # fmt: skip
    for name in c_files(spec, 3):
        ET.SubElement(files, "SourceFile", name=name)
    ET.SubElement(config, "Library", name="m")
    ET.indent(root)
    text: str = ET.tostring(root, encoding="unicode")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + text + "\n"


def documentation(spec: ModelSpec, fmi_version: int) -> str:
    """The FMU's documentation page: what it is, how it steps, the table of its variables."""
    from html import escape

    rows = "\n".join(
        f"<tr><td>{escape(v.name)}</td><td>{v.causality}</td><td>{escape(v.unit)}</td>"
        f"<td>{'' if v.start is None else escape(_number(v.start))}</td>"
        f"<td>{escape(v.description)}</td></tr>"
        for v in spec.variables
    )
    return f"""<!DOCTYPE html>
<html><head><meta charset="utf-8"><title>{escape(spec.title)}</title></head><body>
<h1>{escape(spec.title)}</h1>
<p>{escape(spec.description)}</p>
<p>FMI {fmi_version}.0 co-simulation, exported by carfeel {escape(__version__)} from the preset
{escape(spec.preset)}. Each communication step is a whole number of model steps
(<code>model_step_s</code>) with the inputs held over it; any other step is refused. An output
reflects the inputs set before the step that computed it: an importer sees the effect of an
input one communication step later.</p>
<table border="1"><tr><th>name</th><th>causality</th><th>unit</th><th>start</th>
<th>description</th></tr>
{rows}
</table></body></html>
"""
