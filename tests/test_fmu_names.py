"""A preset's name in an exported FMU is data, never code (issue 24): hostile names (comment
terminators, newlines, preprocessor lines, quotes, backslashes, trigraphs, control characters,
10 kB) either export to an FMU whose generated files hold the name only as an escaped C string
literal, an ElementTree-escaped XML attribute and escaped HTML, or are refused with exit 2.

The property test checks the generated text of many names for every model and FMI version; a
handful of names is compiled, validated by FMPy and run (compiling takes seconds each).
"""

from __future__ import annotations

import functools
import html.parser
import re
import xml.etree.ElementTree as ET
import zipfile
from importlib import resources
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carfeel.cli import main
from carfeel.errors import InputError, PresetError
from carfeel.export import description, fmu
from carfeel.io import presets

FRAGMENTS = (
    "*/", "/*", "//", "\n", "\r\n", "\t", "#include </etc/passwd>\n", "\n#define cf_token x\n",
    "#pragma GCC poison f\n", "\\\n", '"', "'", "\\", "??/", "??=", "??'", "\\x41", "\\0", "\x00",
    "\x01", "\x1b[2J", "\x7f", "\x9b", "]]>", "<!--", "-->", "&amp;", "<x a='1'>", "\ufffe",
    "\u2028", "\u00e9", "\U0001f600", "%s%n", " ", "</title><script>alert(1)</script>",
    '*/\n__attribute__((constructor)) static void f(void){ system("id"); }\n/*',
)  # fmt: skip
"""Pieces an attacker (or an unlucky user) puts in a name."""

XML_CHAR = re.compile("[\t\n\r\u0020-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]*")
"""XML 1.0's Char production (section 2.2): what a document can hold at all."""


def refused(name: str) -> bool:
    """The oracle, written apart from the export's own check: refused when XML cannot hold the
    name, when it has DEL or a C1 control (a terminal may obey them), or when it is too long."""
    return (
        not XML_CHAR.fullmatch(name)
        or any(0x7F <= ord(c) <= 0x9F for c in name)
        or len(name) > fmu.MAX_NAME_CHARS
    )


def toml_string(text: str) -> str:
    """`text` as a TOML basic string (control characters as \\u escapes, as TOML wants)."""
    out = []
    for c in text:
        if c in '"\\':
            out.append("\\" + c)
        elif ord(c) < 0x20 or ord(c) == 0x7F:
            out.append(f"\\u{ord(c):04x}")
        else:
            out.append(c)
    return '"' + "".join(out) + '"'


@functools.cache
def shipped(kind: str, name: str) -> str:
    return resources.files("carfeel.presets").joinpath(kind, f"{name}.toml").read_text()


def preset_text(kind: str, name: str) -> str:
    base = "paper-first-gear" if kind == "shift" else "b-segment"
    text = shipped(kind, base)
    return re.sub(r"^name = .*$", lambda _: f"name = {toml_string(name)}", text, count=1,
                  flags=re.M)  # fmt: skip


KINDS = ("shift", "steering", "physical")


def spec_of(kind: str, name: str) -> fmu.ModelSpec:
    table = "shift" if kind == "shift" else "steering"
    preset = presets.from_toml(table, "preset", preset_text(table, name))
    assert preset.name == name  # the TOML carried it whole
    if kind == "shift":
        return fmu.shift_spec(preset)
    return fmu.steering_spec(preset) if kind == "steering" else fmu.physical_steering_spec(preset)


def c_code_and_literals(source: str) -> tuple[str, list[bytes]]:
    """The C text with every string and character literal replaced by a placeholder and every
    comment by a space (as translation phase 3 does), and the string literals' bytes, decoded
    by C's escape rules. A name outside a literal shows in the code; inside one, not."""
    code: list[str] = []
    literals: list[bytes] = []
    i = 0
    while i < len(source):
        c = source[i]
        if source.startswith("/*", i):
            end = source.index("*/", i + 2)
            code.append(" ")
            i = end + 2
        elif source.startswith("//", i):
            end = source.find("\n", i)
            code.append(" ")
            i = len(source) if end < 0 else end
        elif c in "\"'":
            value = bytearray()
            i += 1
            while source[i] != c:
                assert source[i] != "\n", "a newline inside a literal"
                if source[i] == "\\":
                    octal = re.match(r"[0-7]{1,3}", source[i + 1 :])
                    assert octal, f"an escape other than octal: {source[i : i + 4]!r}"
                    value.append(int(octal.group(), 8))
                    i += 1 + len(octal.group())
                else:
                    value += source[i].encode()
                    i += 1
            i += 1
            code.append("<S>" if c == '"' else "<C>")
            if c == '"':
                literals.append(bytes(value))
        else:
            code.append(c)
            i += 1
    return "".join(code), literals


class _Tags(html.parser.HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, Any]] = []
        self.title = ""
        self._in_title = False

    def handle_starttag(self, tag: str, attrs: Any) -> None:
        self.tags.append((tag, attrs))
        self._in_title = tag == "title"

    def handle_endtag(self, tag: str) -> None:
        self.tags.append(("/" + tag, None))
        self._in_title = False

    def handle_data(self, data: str) -> None:
        if self._in_title:
            self.title += data


def html_of(text: str) -> _Tags:
    parser = _Tags()
    parser.feed(text)
    parser.close()
    return parser


@functools.cache
def neutral(kind: str, version: int) -> tuple[str, list[bytes], ET.Element, list[Any]]:
    """The generated files with a harmless name: what every other name must match outside its
    own literal and attribute."""
    spec = spec_of(kind, "plain")
    code, literals = c_code_and_literals(fmu.generated_c(spec, fmu.token_of(spec, version)))
    root = ET.fromstring(fmu.model_description(spec, version, "T").encode())
    return code, literals, root, html_of(description.documentation(spec, version)).tags


def check_generated(kind: str, version: int, name: str) -> None:
    spec = spec_of(kind, name)
    code, literals = c_code_and_literals(fmu.generated_c(spec, fmu.token_of(spec, version)))
    plain_code, plain_literals, plain_root, plain_tags = neutral(kind, version)
    # Outside its literals the C is the neutral name's, character for character: no comment,
    # preprocessor line or code holds any of the name.
    assert code == plain_code
    # cf_preset's literal decodes to the name's bytes; every other literal is the neutral
    # name's (the header's, the token, the version, the variables' names and units).
    at = plain_literals.index(b"plain")
    assert literals[at] == name.encode()
    assert literals[:at] + literals[at + 1 :] == plain_literals[:at] + plain_literals[at + 1 :]
    # The description: well-formed for a strict parser, the name only in modelName.
    document = fmu.model_description(spec, version, "T")
    root = ET.fromstring(document.encode())
    assert root.get("modelName") == spec.title
    attributes = [(e.tag, sorted(e.attrib.items())) for e in root.iter()]
    expected = [(e.tag, sorted(e.attrib.items())) for e in plain_root.iter()]
    title = ("modelName", spec.title)
    assert [(t, [a for a in items if a != title]) for t, items in attributes] == [
        (t, [a for a in items if a[0] != "modelName"]) for t, items in expected
    ]
    # The documentation: the same tags, the name as the page's text only.
    page = html_of(description.documentation(spec, version))
    assert page.tags == plain_tags
    assert page.title == spec.title


names = st.one_of(
    st.lists(st.sampled_from(FRAGMENTS) | st.text(max_size=12), max_size=24).map("".join),
    st.builds(
        lambda piece, n: (piece * n)[:10_240], st.sampled_from(FRAGMENTS), st.integers(1, 10_240)
    ),
).filter(str.strip)  # the preset loader wants a name with something in it


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(name=names, kind=st.sampled_from(KINDS), version=st.sampled_from(fmu.FMI_VERSIONS))
def test_a_hostile_name_is_data_in_every_generated_file_or_refused(name, kind, version):
    if refused(name):
        with pytest.raises(
            (InputError, PresetError)
        ) as refusal:  # the preset's reader or the FMU's
            spec_of(kind, name)
        message = str(refusal.value)
        assert "name" in message and ("U+" in message or str(fmu.MAX_NAME_CHARS) in message)
        return
    check_generated(kind, version, name)


ATTACK = (
    "*/\n__attribute__((constructor)) static void f(void){ extern int system(const char *); "
    'system("touch {marker}"); }}\n/* #include "/etc/hostname"\n#include </etc/hostname>\n'
    "??/\n\"' \\ \\x41 ??= \u00e9\U0001f600 ]]> <!-- &amp; </title><script>alert(1)</script>"
)
"""The review's attack (a constructor that runs a command when the library loads) with the
other hostile pieces: it must export, validate and load without running anything."""


@pytest.mark.needs_tools  # a C compiler (gcc on Linux x86-64, else cmake's)
@pytest.mark.parametrize("model", fmu.MODELS)
@pytest.mark.parametrize("version", fmu.FMI_VERSIONS)
def test_the_attack_name_exports_validates_and_runs_nothing(tmp_path, model, version):
    from fmpy import read_model_description, simulate_fmu
    from fmpy.validation import validate_fmu

    marker = tmp_path / "ran"
    name = ATTACK.replace("{marker}", str(marker)).replace("}}", "}")
    kind = "shift" if model == "shift" else "steering"
    preset = tmp_path / "hostile.toml"
    preset.write_text(preset_text(kind, name), encoding="utf-8")
    out = tmp_path / "hostile.fmu"
    args = ["export", "fmu", model, "--preset", str(preset), "--fmi", str(version)]
    assert main([*args, "--out", str(out)]) == 0
    assert validate_fmu(str(out)) == []
    assert read_model_description(str(out)).modelName == f"carfeel {model} ({name})"
    simulate_fmu(str(out), stop_time=0.01, output_interval=1e-3)  # loads the library
    assert not marker.exists(), "the name ran as code"
    with zipfile.ZipFile(out) as archive:
        generated = archive.read("sources/cf_generated.c").decode()
    assert "__attribute__" not in c_code_and_literals(generated)[0]


@pytest.mark.parametrize("version", fmu.FMI_VERSIONS)
@pytest.mark.parametrize(
    ("name", "said"),
    [("bell\x07", "U+0007"), ("escape\x1b[31m", "U+001B"), ("csi\x9b2J", "U+009B"),
     ("x" * 10_240, f"at most {fmu.MAX_NAME_CHARS}")],
)  # fmt: skip
def test_a_name_an_fmu_cannot_carry_is_refused_with_exit_2(tmp_path, capsys, version, name, said):
    preset = tmp_path / "bad.toml"
    preset.write_text(preset_text("shift", name), encoding="utf-8")
    out = tmp_path / "bad.fmu"
    args = ["export", "fmu", "shift", "--preset", str(preset), "--fmi", str(version)]
    assert main([*args, "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert said in err and "name" in err and "Traceback" not in err
    assert not out.exists() and list(tmp_path.iterdir()) == [preset]


def test_c_string_escapes_everything_but_plain_characters():
    assert fmu.c_string("ab 1_") == '"ab 1_"'
    assert fmu.c_string('*/"\\\n??/') == '"\\052\\057\\042\\134\\012\\077\\077\\057"'
    assert fmu.c_string("\u00e9") == '"\\303\\251"'  # UTF-8 bytes
    # An octal escape has three digits: a digit after it is a character of its own.
    assert c_code_and_literals(fmu.c_string("\n1") + ";")[1] == [b"\n1"]
