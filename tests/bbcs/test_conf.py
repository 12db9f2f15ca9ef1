"""The .conf parser: the SPEC §4 example, the old reader's failures, errors with lines, typing, fuzzing."""

from __future__ import annotations

import pickle
from typing import Annotated

import msgspec
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bbcs.conf import ConfDocument, ConfError, ConfGroup, load_conf, parse_conf
from bbcs.errors import BbcsError

SPEC_EXAMPLE = """\
Dato1: 25            # comment
Grupo: grupo1 {
    dato1: 42
    dato2: 35
}
PID: PITCH
{
    Kp=1  Ki=2  Kd=3
    valor_int=4   # integral accumulator (without Ki)
    max_awu=5  min_awu=4   # anti wind-up limits
    referencia=3  offset=2  sat_encima=9  sat_deb=8
}
"""

PITCH = {"Kp": "1", "Ki": "2", "Kd": "3", "valor_int": "4", "max_awu": "5", "min_awu": "4",
         "referencia": "3", "offset": "2", "sat_encima": "9", "sat_deb": "8"}


def summary(doc: ConfDocument) -> tuple[dict, list]:
    """Everything a document says, without positions, to compare two spellings of one file."""
    return ({k: e.value for k, e in doc.entries.items()},
            [(g.type, g.name, {k: e.value for k, e in g.entries.items()}) for g in doc.groups])


class Pid(msgspec.Struct, frozen=True, kw_only=True):
    Kp: float
    Ki: float
    Kd: float
    valor_int: float
    max_awu: float
    min_awu: float
    referencia: float
    offset: float
    sat_encima: float
    sat_deb: float


def test_spec_example_parses_to_the_expected_values() -> None:
    doc = parse_conf(SPEC_EXAMPLE, path="uav.conf")
    assert doc.path == "uav.conf"
    assert doc.get("Dato1") == "25"
    assert doc.entries["Dato1"].line == 1 and doc.entries["Dato1"].column == 1
    assert [(g.type, g.name) for g in doc.groups] == [("Grupo", "grupo1"), ("PID", "PITCH")]
    grupo = doc.group("Grupo", "grupo1")
    assert grupo.get("dato1") == "42" and grupo.get("dato2") == "35"
    assert (grupo.line, grupo.entries["dato2"].line) == (2, 4)
    pitch = doc.group("PID", "PITCH")
    assert {k: e.value for k, e in pitch.entries.items()} == PITCH
    assert pitch.line == 6
    assert (pitch.entries["Ki"].line, pitch.entries["Ki"].column) == (8, 11)
    assert pitch.to_struct(Pid) == Pid(Kp=1, Ki=2, Kd=3, valor_int=4, max_awu=5, min_awu=4, referencia=3,
                                       offset=2, sat_encima=9, sat_deb=8)
    assert [g.name for g in doc.groups_of("PID")] == ["PITCH"]
    assert doc.groups_of("Nada") == []


def _blank_lines(text: str) -> str:
    return "\n\n" + text.replace("\n", "\n\n   \n")


def _trailing_spaces(text: str) -> str:
    return text.replace("\n", "   \n")


def _crlf(text: str) -> str:
    return text.replace("\n", "\r\n")


def _comments_everywhere(text: str) -> str:
    return "# header\n" + text.replace("\n", "  # note: {x} = [y] ()\n")


def _reordered(text: str) -> str:
    return """\
PID: PITCH {
    sat_deb=8 sat_encima=9 offset=2 referencia=3
    min_awu=4 max_awu=5 valor_int=4 Kd=3 Ki=2 Kp=1
}
Grupo: grupo1 { dato2: 35  dato1: 42 }
Dato1 = 25
"""


def _tabs(text: str) -> str:
    return text.replace("    ", "\t").replace("  ", "\t\t").replace(": ", ":\t")


def _old_mac_cr(text: str) -> str:
    return text.replace("\n", "\r")


def _bom(text: str) -> str:
    return "\ufeff" + text


@pytest.mark.parametrize("mangle", [_blank_lines, _trailing_spaces, _crlf, _comments_everywhere, _reordered,
                                    _tabs, _old_mac_cr, _bom], ids=lambda f: f.__name__.strip("_"))
def test_what_broke_the_old_reader_parses(mangle) -> None:
    expected = summary(parse_conf(SPEC_EXAMPLE))
    got = summary(parse_conf(mangle(SPEC_EXAMPLE)))
    if mangle is _reordered:
        got = (got[0], sorted((t, n, dict(sorted(e.items()))) for t, n, e in got[1]))
        expected = (expected[0], sorted((t, n, dict(sorted(e.items()))) for t, n, e in expected[1]))
    assert got == expected


def test_crlf_keeps_line_numbers() -> None:
    doc = parse_conf(_crlf(SPEC_EXAMPLE))
    assert doc.group("PID", "PITCH").entries["sat_deb"].line == 11


@pytest.mark.parametrize("line", [
    "ip: 172.16.1.65",
    "ip: 172.16.1.65\r",
    "ip: 172.16.1.65   \t",
    "ip:172.16.1.65#x",
    "  ip = 172.16.1.65 # gcs address",
    'ip: "172.16.1.65"',
])
def test_an_ip_stays_exact(line: str) -> None:
    assert parse_conf(line + "\nnext: 1\n").get("ip") == "172.16.1.65"


def test_values_keep_their_text() -> None:
    doc = parse_conf('a: 1,2\nb: -0.45e-3\nc: "tcp/127.0.0.1:7447"\nd: "has # and { }"\ne: ""\nf: x/y.z*?\n')
    assert doc.get("a") == "1,2"
    assert doc.get("b") == "-0.45e-3"
    assert doc.get("c") == "tcp/127.0.0.1:7447"
    assert doc.get("d") == "has # and { }"
    assert doc.get("e") == ""
    assert doc.get("f") == "x/y.z*?"
    assert doc.get("missing") is None and doc.get("missing", "dflt") == "dflt"


def test_lists_in_brackets_commas_optional_and_across_lines() -> None:
    doc = parse_conf("""\
fields: [roll pitch, yaw,
         "alt m"   # a comment inside the list
         speed,]
lever_arm: (-0.45 -0.04 0)
none: []
""")
    assert doc.get("fields") == ["roll", "pitch", "yaw", "alt m", "speed"]
    assert doc.get("lever_arm") == ["-0.45", "-0.04", "0"]
    assert doc.get("none") == []


def test_group_names_and_headers() -> None:
    doc = parse_conf('Bus = "main link"\n# between\n\n{ endpoint: "tcp/10.0.0.1:7447" }\nPID:ROLL{Kp=1}\n')
    assert doc.group("Bus", "main link").get("endpoint") == "tcp/10.0.0.1:7447"
    assert doc.group("PID", "ROLL").get("Kp") == "1"
    assert doc.group("PID", "ROLL").label == "PID: ROLL"
    assert doc.entries == {}


MALFORMED = [
    ("a: 1\nb: 2\na: 3\n", 3, 1, "duplicate key 'a' (first at line 1)"),
    ("G: g {\n  k: 1\n\n  k = 2\n}\n", 4, 3, "duplicate key 'k' in group 'G: g' (first at line 2)"),
    ("G: g {}\nH: h {}\nG: g {}\n", 3, 1, "duplicate group 'G: g' (first at line 1)"),
    ("a: 1\n\nPID: PITCH {\n  Kp=1\n", 3, 12, "group 'PID: PITCH' is never closed"),
    ("PID: PITCH {\n  Kp=1\nPID: ROLL {\n  Kp=2\n}\n", 3, 1,
     "expected '}' to close group 'PID: PITCH' opened at line 1 before group 'PID: ROLL'"),
    ("a: 1\nb:\nc: 3\n", 2, 2, "missing value after ':' for key 'b'"),
    ("a: 1\nb = # nothing\n", 2, 3, "missing value after '=' for key 'b'"),
    ("a: 1\n}\n", 2, 1, "unexpected '}': no group is open"),
    ("G: g {\n a: 1\n}\n}\n", 4, 1, "unexpected '}': no group is open"),
    ("a: 1\n\nendpoint: tcp/10.0.0.1:7447\n", 3, 23, "unexpected ':' after the value of 'endpoint'"),
    ("name: two words\n", 1, 11, "unexpected 'words' after the value of 'name'"),
    ("a: 1\nb 2\n", 2, 1, "expected ':' or '=' after key 'b'"),
    ("a\n: 2\n", 1, 1, "expected ':' or '=' after key 'a'"),
    ("{\n", 1, 1, "unexpected '{'"),
    ('a: 1\n"k": 2\n', 2, 1, "expected a key"),
    ('a: "open\nb: 2\n', 1, 4, "unterminated quoted value"),
    ("x: 0\nf: [a b\n", 2, 4, "the list of 'f' is never closed"),
    ("f: [a b\nc: 3]\n", 2, 2, "expected ']' to close the list of 'f' opened at line 1"),
    ("f: [a, , b]\n", 1, 8, "empty item in the list of 'f'"),
    ("f: [a [b]]\n", 1, 7, "lists do not nest"),
    ("f: (a b]\n", 1, 8, "expected ')'"),
    ("G: [a b] {\n}\n", 1, 10, "the name of group 'G' must be one value"),
]


@pytest.mark.parametrize(("text", "line", "column", "message"), MALFORMED)
def test_malformed_files_give_conf_error_at_the_right_place(text: str, line: int, column: int,
                                                            message: str) -> None:
    with pytest.raises(ConfError) as info:
        parse_conf(text, path="uav1.conf")
    err = info.value
    assert (err.path, err.line, err.column) == ("uav1.conf", line, column)
    assert message in err.message
    assert str(err).startswith(f"uav1.conf:{line}:{column}: ")


def test_conf_error_is_a_bus_error_and_survives_pickling() -> None:
    err = ConfError("bad", path="x.conf", line=3, column=7)
    assert isinstance(err, BbcsError)
    assert str(err) == "x.conf:3:7: bad"
    back = pickle.loads(pickle.dumps(err))
    assert (back.path, back.line, back.column, back.message) == ("x.conf", 3, 7, "bad")
    assert str(ConfError("gone", path="y.conf")) == "y.conf: gone"
    assert str(ConfError("here", path="y.conf", line=2)) == "y.conf:2: here"


class Top(msgspec.Struct, frozen=True, kw_only=True, rename={"max_speed": "MAX_SPEED"}):
    Dato1: int
    max_speed: Annotated[float, msgspec.Meta(ge=0)] = 1.0
    armed: bool = False
    fields: list[str] = []
    ports: list[int] = []
    lever_arm: tuple[float, float, float] = (0.0, 0.0, 0.0)


def test_to_struct_types_the_text() -> None:
    doc = parse_conf("Dato1: 25\nMAX_SPEED = 2.5\narmed: true\nfields: [roll pitch]\nports: [7447, 7448]\n"
                     "lever_arm: (-0.45 -0.04 0)\nunknown: ignored\n")
    assert doc.to_struct(Top) == Top(Dato1=25, max_speed=2.5, armed=True, fields=["roll", "pitch"],
                                     ports=[7447, 7448], lever_arm=(-0.45, -0.04, 0.0))


@pytest.mark.parametrize(("text", "line", "column", "message"), [
    ("# speed\n\nMAX_SPEED: 2.5x\nDato1: 1\n", 3, 1,
     "key 'MAX_SPEED': invalid value '2.5x': expected `float`"),
    ("Dato1: 1\n  MAX_SPEED: -3\n", 2, 3, "expected `float` >= 0.0"),
    ("Dato1: 172.16.1.65\n", 1, 1, "key 'Dato1': invalid value '172.16.1.65': expected `int`"),
    ("Dato1: 1\narmed: maybe\n", 2, 1, "expected `bool`"),
    ("Dato1: 1\nports: [7447 x7448]\n", 2, 1,
     "key 'ports': invalid value 'x7448' (item 2 of the list): expected `int`"),
    ("Dato1: 1\nfields: roll\n", 2, 1, "expected a list in brackets, got a single value"),
    ("Dato1: [1 2]\n", 1, 1, "got a list"),
    ("Dato1: 1\nlever_arm: (1 2)\n", 2, 1, "key 'lever_arm'"),
])
def test_bad_values_point_at_their_key(text: str, line: int, column: int, message: str) -> None:
    with pytest.raises(ConfError) as info:
        parse_conf(text, path="uav1.conf").to_struct(Top)
    assert (info.value.path, info.value.line, info.value.column) == ("uav1.conf", line, column)
    assert message in info.value.message


def test_group_conversion_errors_name_the_group() -> None:
    doc = parse_conf("x: 1\nPID: PITCH {\n  Kp=1 Ki=2 Kd=3\n  valor_int=4 max_awu=5\n  Ki2=1\n}\n"
                     "PID: ROLL {\n Kp=1 Ki=zwei Kd=3 valor_int=4 max_awu=5 min_awu=4 referencia=3 offset=2\n"
                     " sat_encima=9 sat_deb=8 }\n", path="uav1.conf")
    with pytest.raises(ConfError) as info:
        doc.group("PID", "PITCH").to_struct(Pid)
    assert (info.value.line, info.value.column) == (2, 1)
    assert info.value.message.startswith("missing required key '")
    assert "in group 'PID: PITCH'" in info.value.message
    with pytest.raises(ConfError) as info:
        doc.group("PID", "ROLL").to_struct(Pid)
    assert (info.value.line, info.value.column) == (8, 7)
    assert "key 'Ki' in group 'PID: ROLL': invalid value 'zwei'" in info.value.message


def test_forbidding_unknown_keys_points_at_the_unknown_one() -> None:
    class Strict(msgspec.Struct, forbid_unknown_fields=True):
        a: int = 0

    with pytest.raises(ConfError) as info:
        parse_conf("a: 1\n\n  typo: 2\n").to_struct(Strict)
    assert (info.value.line, info.value.column) == (3, 3)
    assert info.value.message == "unknown key 'typo'"


def test_missing_top_level_key_names_the_file() -> None:
    doc = parse_conf("other: 1\n", path="robot.conf")
    with pytest.raises(ConfError) as info:
        doc.to_struct(Top)
    assert str(info.value) == "robot.conf: missing required key 'Dato1'"


def test_require_and_group_lookups() -> None:
    doc = parse_conf("host: 10.0.0.2\nfields: [a b]\nG: g { k: v }\n", path="robot.conf")
    assert doc.require("host") == "10.0.0.2"
    assert doc.group("G", "g").require("k") == "v"
    with pytest.raises(ConfError, match=r"^robot\.conf: missing required key 'port'$"):
        doc.require("port")
    with pytest.raises(ConfError, match=r"^robot\.conf:2:1: key 'fields' must be a single value"):
        doc.require("fields")
    with pytest.raises(ConfError, match=r"^robot\.conf:3:1: missing required key 'x' in group 'G: g'$"):
        doc.group("G", "g").require("x")
    with pytest.raises(ConfError, match=r"^robot\.conf: missing group 'G: h'$"):
        doc.group("G", "h")


def test_load_conf_reads_files_and_names_them_in_errors(tmp_path) -> None:
    good = tmp_path / "uav.conf"
    good.write_bytes(_crlf(SPEC_EXAMPLE).encode())
    doc = load_conf(good)
    assert doc.path == str(good)
    assert summary(doc) == summary(parse_conf(SPEC_EXAMPLE))
    bad = tmp_path / "uav1.conf"
    bad.write_text("a: 1\nPID: PITCH {\n Kp=1\n")
    with pytest.raises(ConfError) as info:
        load_conf(str(bad))
    assert str(info.value).startswith(f"{bad}:2:12: group 'PID: PITCH' is never closed")
    with pytest.raises(ConfError) as info:
        load_conf(tmp_path / "absent.conf")
    assert info.value.path == str(tmp_path / "absent.conf") and info.value.line is None
    assert "cannot read the file" in str(info.value)
    with pytest.raises(ConfError):
        load_conf(tmp_path)
    latin = tmp_path / "latin.conf"
    latin.write_bytes(b"a: 1\nname: Se\xf1or\n")
    with pytest.raises(ConfError) as info:
        load_conf(latin)
    assert (info.value.line, info.value.column, info.value.message) == (2, 9, "not valid UTF-8 text")


# --- fuzzing -------------------------------------------------------------------------------------------

def _check_only_conf_error(text: str) -> None:
    try:
        doc = parse_conf(text, path="fuzz.conf")
    except ConfError as err:
        assert err.path == "fuzz.conf"
        lines = text.replace("\r\n", "\n").replace("\r", "\n").count("\n") + 1
        assert err.line is not None and 1 <= err.line <= lines
        assert err.column is not None and err.column >= 1
        assert str(err).startswith(f"fuzz.conf:{err.line}:{err.column}: ")
    else:
        assert isinstance(doc, ConfDocument)
        assert all(isinstance(g, ConfGroup) for g in doc.groups)


@settings(deadline=None)
@given(st.text())
def test_arbitrary_text_raises_nothing_but_conf_error(text: str) -> None:
    _check_only_conf_error(text)


SEPARATOR_HEAVY = st.text(alphabet=":={}[](),#\"\r\n\t =ab1.", min_size=1, max_size=6)
VALID_FILES = [SPEC_EXAMPLE, _crlf(SPEC_EXAMPLE), 'f: [a, "b c"]\nB: "x y" { e: "tcp/1.2.3.4:1" }\n']


@st.composite
def mutated_files(draw) -> str:
    text = draw(st.sampled_from(VALID_FILES))
    for _ in range(draw(st.integers(1, 4))):
        size = len(text)
        at = draw(st.integers(0, size))
        kind = draw(st.sampled_from(["delete", "insert", "duplicate", "truncate", "swap"]))
        if kind == "delete":
            text = text[:at] + text[at + draw(st.integers(1, 8)):]
        elif kind == "insert":
            text = text[:at] + draw(SEPARATOR_HEAVY) + text[at:]
        elif kind == "duplicate":
            text = text[:at] + text[at:at + draw(st.integers(1, 30))] + text[at:]
        elif kind == "truncate":
            text = text[:at]
        else:
            lines = text.split("\n")
            i, j = draw(st.integers(0, len(lines) - 1)), draw(st.integers(0, len(lines) - 1))
            lines[i], lines[j] = lines[j], lines[i]
            text = "\n".join(lines)
    return text


@settings(deadline=None, max_examples=300)
@given(mutated_files())
def test_mutated_valid_files_raise_nothing_but_conf_error(text: str) -> None:
    _check_only_conf_error(text)


WORD = st.text(alphabet="abcXYZ019_.-+/*,", min_size=1, max_size=8)
LIST_WORD = st.text(alphabet="abcXYZ019_.-+/*", min_size=1, max_size=8)
QUOTED = st.text(alphabet=st.characters(blacklist_characters='"\r\n', blacklist_categories=("Cs",)),
                 max_size=10)
KEY = st.text(alphabet="abcXYZ019_.-", min_size=1, max_size=6)
VALUE = st.one_of(WORD, QUOTED, st.lists(st.one_of(LIST_WORD, QUOTED), max_size=4))
ENTRIES = st.dictionaries(KEY, VALUE, max_size=5)


def _render_value(draw, value: str | list[str], bare: str = "abcXYZ019_.-+/*,") -> str:
    if isinstance(value, list):
        sep = draw(st.sampled_from([" ", ", ", ",\n  ", "\t"]))
        return "[" + sep.join(_render_value(draw, v, bare.replace(",", "")) for v in value) + "]"
    quote = not value or any(c not in bare for c in value) or draw(st.booleans())
    return f'"{value}"' if quote else value


def _render_entries(draw, entries: dict) -> str:
    out = []
    for key, value in entries.items():
        sep = draw(st.sampled_from([":", ": ", " = ", "=", "\t:\t"]))
        out.append(draw(st.sampled_from(["", "  ", "\t"])) + key + sep + _render_value(draw, value))
        out.append(draw(st.sampled_from(["\n", "\r\n", "  ", "   # note\n", "\n\n"])))
    return "".join(out)


@st.composite
def documents(draw) -> tuple[str, dict, list]:
    entries = draw(ENTRIES)
    groups = draw(st.dictionaries(st.tuples(KEY, st.one_of(WORD, QUOTED)), ENTRIES, max_size=3))
    parts = [_render_entries(draw, entries), "\n"]
    for (typ, name), body in groups.items():
        brace = draw(st.sampled_from([" {\n", "{", "\n{\n", " # g\r\n{ "]))
        parts.append(f"{typ}: {_render_value(draw, name)}{brace}{_render_entries(draw, body)}\n}}\n")
    return "".join(parts), entries, [(t, n, b) for (t, n), b in groups.items()]


@settings(deadline=None, max_examples=200)
@given(documents())
def test_any_valid_rendering_parses_back_to_what_was_written(case: tuple[str, dict, list]) -> None:
    text, entries, groups = case
    assert summary(parse_conf(text)) == (entries, groups)


class _Strict(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    speed: Annotated[float, msgspec.Meta(gt=0)]
    count: int
    name: str = "x"


def test_errors_for_reports_every_key_not_only_the_first() -> None:
    doc = parse_conf("speed: -1\ncount: many\nextra: 1\n", path="r.conf")
    errors = [str(e) for e in doc.errors_for(_Strict)]
    assert errors == ["r.conf:1:1: key 'speed': invalid value '-1': expected `float` > 0.0",
                      "r.conf:2:1: key 'count': invalid value 'many': expected `int`",
                      "r.conf:3:1: unknown key 'extra'"]
    with pytest.raises(ConfError, match="r.conf:1:1"):
        doc.to_struct(_Strict)


def test_errors_for_names_missing_keys_and_is_empty_when_to_struct_succeeds() -> None:
    doc = parse_conf("G: g {\n  speed: 2\n}\n", path="r.conf")
    group = doc.group("G", "g")
    assert [str(e) for e in group.errors_for(_Strict)] == ["r.conf:1:1: missing required key 'count' in group 'G: g'"]
    ok = parse_conf("speed: 2\ncount: 3\n").errors_for(_Strict)
    assert ok == []
