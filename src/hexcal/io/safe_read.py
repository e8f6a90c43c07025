"""Reading input files safely: size, nesting and value limits, and messages that name the file.

Every file hexcal reads goes through here (docs/formats.md, "Limits on what is read"), so a
damaged or hostile file is refused with one clean message — naming the file and the line or
field, and saying what to do — instead of exhausting memory or the stack:

- **Size.** Each kind of file has a maximum size (:data:`KINDS`), checked before it is read;
  an over-long file (``/dev/zero``, a file still growing) is cut at the limit, never read whole.
- **Text.** Files are UTF-8; a leading byte-order mark is dropped. An undecodable byte is named
  by its offset and line.
- **Nesting.** JSON and TOML may nest at most :data:`MAX_DEPTH` levels (objects, arrays, tables
  and dotted keys together). TOML text is scanned *before* it reaches ``tomllib``, because a
  dotted key of many parts (``a.a.a…``) costs ``tomllib`` time and memory quadratic in its length
  (a 200 KB file took 23 GB); JSON's C decoder stops at the interpreter's recursion limit, and the
  parsed tree is then held to the limit.
- **Numbers.** Every number must be finite: JSON's non-standard ``NaN``/``Infinity`` tokens,
  TOML's ``nan``/``inf`` and decimals beyond ±1.8e308 (which parse as infinity) are refused with
  the field that holds them. Each reader's pydantic model then bounds the values it uses to a
  stated range (:data:`MAX_COORDINATE_MM` and the other limits here).
"""

from __future__ import annotations

import codecs
import io
import json
import math
import re
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

from pydantic import BeforeValidator, Field
from pydantic_core import PydanticCustomError

from hexcal.errors import InputError
from hexcal.io.capacity import MAX_SESSION_BYTES

if sys.version_info >= (3, 11):
    import tomllib
else:  # Python 3.10
    import tomli as tomllib

KB = 1024
MB = 1024 * KB
GB = 1024 * MB

#: Deepest nesting accepted in a JSON or TOML file: objects/tables, arrays and the parts of a
#: dotted key each count one level. hexcal's own files nest at most 6 levels.
MAX_DEPTH = 32

# -- Limits on values (used by the pydantic models of every reader) ---------------------------

#: Largest coordinate, length, reading or offset, mm (1 km): far beyond any hexapod, while
#: squares and sums of squares of such values stay far from overflow.
MAX_COORDINATE_MM = 1e6
#: Largest time, s (about 31 years): session times and host monotonic clocks stay far below it.
MAX_TIME_S = 1e9
#: Structure temperature range, degC.
MIN_TEMPERATURE_C = -273.15
MAX_TEMPERATURE_C = 1000.0
#: Pose ids are 1 .. 2**53 − 1: exact as a double (spreadsheets, JSON readers in JavaScript)
#: and in every integer type a rig's software may use for them, 64-bit or epoch-millisecond.
MAX_POSE_ID = 2**53 - 1
#: Largest count of poses, samples or steps a file may state.
MAX_COUNT = 2**31 - 1


def _refuse_bool(value: Any) -> Any:
    """JSON's ``true``/``false`` where a number belongs: pydantic would read it as 1 or 0."""
    if isinstance(value, bool):
        raise PydanticCustomError("bool_not_number", "expected a number, not a boolean")
    return value


#: Refuses a boolean where a number belongs (JSON ``true`` would otherwise read as 1.0).
NotBool = BeforeValidator(_refuse_bool)
#: A finite float (no NaN, no infinity).
Finite = Annotated[float, Field(allow_inf_nan=False), NotBool]
#: A coordinate, length or reading in mm: finite, |x| ≤ :data:`MAX_COORDINATE_MM`.
Millimetres = Annotated[
    float, Field(ge=-MAX_COORDINATE_MM, le=MAX_COORDINATE_MM, allow_inf_nan=False), NotBool
]
#: A time in s: finite, |t| ≤ :data:`MAX_TIME_S`.
Seconds = Annotated[float, Field(ge=-MAX_TIME_S, le=MAX_TIME_S, allow_inf_nan=False), NotBool]
#: A temperature in degC, from absolute zero to :data:`MAX_TEMPERATURE_C`.
Celsius = Annotated[
    float, Field(ge=MIN_TEMPERATURE_C, le=MAX_TEMPERATURE_C, allow_inf_nan=False), NotBool
]
#: A quaternion component (scalar first); the norm is checked where the quaternion is used.
QuaternionPart = Annotated[float, Field(ge=-2.0, le=2.0, allow_inf_nan=False), NotBool]
#: A pose id, 1 .. :data:`MAX_POSE_ID`.
PoseId = Annotated[int, Field(ge=1, le=MAX_POSE_ID), NotBool]
#: A count, 0 .. :data:`MAX_COUNT`.
Count = Annotated[int, Field(ge=0, le=MAX_COUNT), NotBool]


@dataclass(frozen=True)
class FileKind:
    """What hexcal knows about one kind of input file: what it is called in messages, its
    largest size in bytes, and what to do when it is missing or damaged."""

    what: str
    max_bytes: int
    missing: str  #: the message after the path when the file does not exist
    damaged: str = "fix the file (docs/formats.md describes it)"


#: Every kind of file hexcal reads, with its size limit.
KINDS: dict[str, FileKind] = {
    "robot": FileKind(
        "robot description", 1 * MB, "no such file; pass the robot description with --robot"
    ),
    "instruments": FileKind(
        "instruments' noise file", 1 * MB, "no such file; check the path to the instruments' noise"
    ),
    "procedure": FileKind("procedure file", 1 * MB, "no such procedure file"),
    "devices": FileKind(
        "device configuration",
        1 * MB,
        "no such file; pass the rig's device configuration with --config",
    ),
    "session": FileKind(
        "session file",
        MAX_SESSION_BYTES,
        "no such session file",
        "the file is damaged; it is left untouched. Restore it from a backup, or start a new "
        "session under another name",
    ),
    # Read row by row into typed arrays: memory stays about the file's size.
    "measurements": FileKind(
        "measurement table", 1 * GB, "no such file; check the path to the measurement table"
    ),
    # hexcal predict keeps every cell of its table as text to write it back.
    "table": FileKind("prediction table", 64 * MB, "no such file"),
}

ErrorFactory = Callable[[str], Exception]


class InputFileError(InputError):
    """A file could not be read; the message names it and says what to do."""


def _size_text(n: int) -> str:
    for unit, size in (("GB", GB), ("MB", MB), ("KB", KB)):
        if n >= size:
            return f"{n / size:.3g} {unit}"
    return f"{n} bytes"


def _kind(kind: str | FileKind) -> FileKind:
    return kind if isinstance(kind, FileKind) else KINDS[kind]


def open_binary(path: str | Path, kind: str | FileKind, error: ErrorFactory) -> io.BufferedReader:
    """The file opened for reading in binary, after its size is checked against the kind's
    limit; errors (``error(message)``) name the file and say what to do."""
    k = _kind(kind)
    path = Path(path)
    try:
        fh = path.open("rb")
    except FileNotFoundError:
        raise error(f"{path}: {k.missing}") from None
    except IsADirectoryError:
        raise error(f"{path}: is a directory; pass the {k.what} itself") from None
    except OSError as exc:
        raise error(
            f"{path}: cannot be read ({exc.strerror or exc}); check the path and its permissions"
        ) from None
    try:
        size = path.stat().st_size
    except OSError:
        size = 0
    if size > k.max_bytes:
        fh.close()
        raise error(_too_big(path, k, size))
    return fh


def _too_big(path: Path, k: FileKind, size: int | None) -> str:
    limit = _size_text(k.max_bytes)
    if size is None:
        return f"{path}: longer than {limit}, the most a {k.what} may have; is it the right file?"
    return (
        f"{path}: {_size_text(size)}, more than the {limit} a {k.what} may have; is it the "
        "right file?"
    )


def read_bytes(path: str | Path, kind: str | FileKind, error: ErrorFactory) -> bytes:
    """The file's bytes, at most the kind's limit (a longer file is refused)."""
    k = _kind(kind)
    with open_binary(path, k, error) as fh:
        try:
            raw = fh.read(k.max_bytes + 1)
        except OSError as exc:
            raise error(f"{path}: cannot be read ({exc.strerror or exc})") from None
    if len(raw) > k.max_bytes:  # a device or a file that grew after stat
        raise error(_too_big(Path(path), k, None))
    return raw


def decode(raw: bytes, where: str, error: ErrorFactory) -> str:
    """UTF-8 text of ``raw``; a leading byte-order mark is dropped. An undecodable byte is
    named by its offset (from 0) and line."""
    skip = len(codecs.BOM_UTF8) if raw.startswith(codecs.BOM_UTF8) else 0
    try:
        return raw[skip:].decode("utf-8")
    except UnicodeDecodeError as exc:
        at = exc.start + skip
        line = raw.count(b"\n", 0, at) + 1
        raise error(
            f"{where}: byte {at} (line {line}, 0x{raw[at]:02x}) is not UTF-8 text; save the "
            f"file as UTF-8{legacy_hint(raw[at : at + 4])}"
        ) from None


def legacy_hint(fragment: bytes) -> str:
    """What an undecodable byte suggests: text in a Western 8-bit code page, as a spreadsheet's
    plain "CSV" and older lab software save it ('' when nothing clear)."""
    if fragment and fragment[0] >= 0x80 and not fragment.startswith((b"\xff\xfe", b"\xfe\xff")):
        return (
            " (it reads as Windows-1252 or Latin-1 text, as a spreadsheet's plain 'CSV' saves "
            "it: choose 'CSV UTF-8')"
        )
    return ""


def read_text(path: str | Path, kind: str | FileKind, error: ErrorFactory = InputFileError) -> str:
    """The file's text: size-limited, UTF-8, byte-order mark dropped."""
    return decode(read_bytes(path, kind, error), str(path), error)


# -- JSON -----------------------------------------------------------------------------------


class _DuplicateKey(Exception):
    """An object of the JSON text names a key twice."""


def _unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out = dict(pairs)
    if len(out) != len(pairs):
        raise _DuplicateKey
    return out


def parse_json(
    text: str, where: str, error: ErrorFactory = InputFileError, damaged: str = ""
) -> Any:
    """The JSON value of ``text``, held to :data:`MAX_DEPTH`, to finite numbers and to unique
    keys in every object (a repeated key is refused, naming it and its line: JSON readers
    differ on which value wins, and hexcal will not guess)."""
    hint = f"; {damaged}" if damaged else ""
    try:
        data = json.loads(text, object_pairs_hook=_unique_keys)
    except _DuplicateKey:
        raise error(duplicate_key_message(text, where)) from None
    except json.JSONDecodeError as exc:
        raise error(
            f"{where}: line {exc.lineno}, column {exc.colno}: not valid JSON ({exc.msg}){hint}"
        ) from None
    except RecursionError:
        # The C decoder gives up at the interpreter's recursion limit (~1000 levels), long
        # before the stack is at risk; anything that deep is far beyond MAX_DEPTH anyway.
        raise error(_too_deep(where, None)) from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise error(f"{where}: {_digits_message(exc)}") from None
    check_tree(data, where, error, "JSON has no NaN or Infinity")
    return data


_JSON_TOKEN = re.compile(r'"(?:[^"\\]|\\.)*"|[{}\[\],:]')


def duplicate_key_message(text: str, where: str) -> str:
    """The message for the first key that an object of ``text`` (valid JSON) repeats: the key,
    the field it belongs to, its line and the line it was first given on."""
    # A small scan of the tokens that matter (strings and punctuation): a stack of the open
    # objects' keys with their lines, and the path to name the field by.
    stack: list[dict[str, int] | None] = []  # an object's keys (with lines), None for a list
    path: list[Any] = []
    expect_key = False
    for m in _JSON_TOKEN.finditer(text):
        tok = m.group()
        if tok == "{":
            stack.append({})
            path.append(None)
            expect_key = True
        elif tok == "[":
            stack.append(None)
            path.append(0)
            expect_key = False
        elif tok in "}]":
            stack.pop()
            path.pop()
            expect_key = False
        elif tok == ",":
            top = stack[-1] if stack else None
            if top is None and path:
                path[-1] += 1
            expect_key = top is not None
        elif tok == ":":
            expect_key = False
        elif expect_key and stack and stack[-1] is not None:
            key = json.loads(tok)
            line = text.count("\n", 0, m.start()) + 1
            keys = stack[-1]
            path[-1] = key
            if key in keys:
                field = field_name(path[:-1])
                inside = "" if not path[:-1] else f" (in field {field})"
                return (
                    f"{where}: line {line}: key {key!r}{inside} is given twice (first on line "
                    f"{keys[key]}); JSON readers differ on which one counts, so hexcal takes "
                    "neither: delete one"
                )
            keys[key] = line
            expect_key = False
    return f"{where}: an object gives a key twice; delete one"  # pragma: no cover


def read_json(path: str | Path, kind: str | FileKind, error: ErrorFactory = InputFileError) -> Any:
    """Read a JSON file of ``kind`` (see :data:`KINDS`): size, UTF-8, syntax, depth and finite
    numbers checked; every error (``error(message)``) names the file and the line or field."""
    k = _kind(kind)
    text = read_text(path, k, error)
    return parse_json(text, str(path), error, k.damaged)


def _digits_message(exc: ValueError) -> str:
    if "digits" in str(exc):
        return "a number has more than 4300 digits; give numbers of ordinary size"
    return f"cannot be read ({exc})"


# -- TOML -----------------------------------------------------------------------------------

# The characters the scan below looks at; everything else is skipped in one regex step.
_TOML_SPECIAL = re.compile(r"[\"'#\[\]{}=,.\n]")
_TOML_BASIC = re.compile(r'"(?:[^"\\\n]|\\.)*"')
_TOML_ML_BASIC_END = re.compile(r'(?:[^"\\]|\\.|"(?!""))*"""(?:""?)?', re.DOTALL)
_TOML_ML_LITERAL_END = re.compile(r"(?:[^']|'(?!''))*'''(?:''?)?", re.DOTALL)


def scan_toml(text: str, where: str, error: ErrorFactory = InputFileError) -> None:
    """Refuse TOML text that nests deeper than :data:`MAX_DEPTH`, before any parser sees it.

    A linear scan that skips strings and comments and measures (1) the bracket depth of arrays,
    inline tables and table headers and (2) the parts of each dotted key: the dots between two
    of ``= , [ ] { }`` or a line end (a value such as ``1.5`` or a date has at most one dot, so
    a valid file is never refused for its numbers). Malformed text passes to the parser, which
    reports it.
    """
    depth = dots = 0
    line = 1
    pos, n = 0, len(text)
    while pos < n:
        m = _TOML_SPECIAL.search(text, pos)
        if m is None:
            return
        i, c = m.start(), m.group()
        pos = i + 1
        if c == ".":
            dots += 1
            if dots >= MAX_DEPTH:
                raise error(
                    f"{where}: line {line}: a dotted key has more than {MAX_DEPTH} parts; "
                    "hexcal's files use a few: is it the right file?"
                )
            continue
        if c in "[{":
            depth += 1
            if depth > MAX_DEPTH:
                raise error(_too_deep(where, line))
        elif c in "]}":
            depth = max(depth - 1, 0)
        elif c == "\n":
            line += 1
        elif c == "#":
            end = text.find("\n", pos)
            pos = n if end < 0 else end
            continue
        elif c in "\"'":
            end = _toml_string_end(text, i, c)
            if end < 0:
                return  # unterminated: the parser says where
            line += text.count("\n", i, end)
            pos = end
            continue
        dots = 0  # = , [ ] { } and line ends separate keys and values


def _toml_string_end(text: str, i: int, quote: str) -> int:
    """The index after the string that starts at ``i``, -1 if it never ends."""
    if text.startswith(quote * 3, i):
        pattern = _TOML_ML_BASIC_END if quote == '"' else _TOML_ML_LITERAL_END
        m = pattern.match(text, i + 3)
        return -1 if m is None else m.end()
    if quote == '"':
        m = _TOML_BASIC.match(text, i)
        return -1 if m is None else m.end()
    end = text.find("'", i + 1)
    newline = text.find("\n", i + 1)
    if end < 0 or 0 <= newline < end:
        return -1
    return end + 1


def parse_toml(text: str, where: str, error: ErrorFactory = InputFileError) -> dict[str, Any]:
    """The TOML table of ``text``: scanned for depth first, then parsed, then held to finite
    numbers; errors name ``where`` and the line or field."""
    scan_toml(text, where, error)
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(_toml_message(text, where, exc)) from None
    except RecursionError:  # not reached after the scan; kept as a last guard
        raise error(_too_deep(where, None)) from None
    except ValueError as exc:  # an integer of more than 4300 digits
        raise error(f"{where}: {_digits_message(exc)}") from None
    check_tree(data, where, error, "TOML's nan and inf are not accepted")
    return data


_TOML_AT = re.compile(r"\(at line (\d+), column \d+\)")


def _toml_message(text: str, where: str, exc: Exception) -> str:
    """tomllib's error in words; a key or table given twice is named with its line."""
    msg = str(exc)
    at = _TOML_AT.search(msg)
    if at and ("Cannot overwrite a value" in msg or "Cannot declare" in msg):
        number = int(at.group(1))
        lines = text.splitlines()
        line = lines[number - 1].strip() if 0 < number <= len(lines) else ""
        name = line.split("=", 1)[0].strip() if "=" in line else line
        what = "table" if name.startswith("[") else "key"
        return (
            f"{where}: line {number}: {what} {name!r} is given twice (or a key is set again "
            f"after its table); a TOML {what} may be given once: delete or merge one"
        )
    return f"{where}: not valid TOML ({msg}); fix the file there"


def read_toml(
    path: str | Path, kind: str | FileKind, error: ErrorFactory = InputFileError
) -> dict[str, Any]:
    """Read a TOML file of ``kind`` (see :data:`KINDS`): size, UTF-8, depth (scanned before
    parsing), syntax and finite numbers checked; errors name the file and the line or field."""
    return parse_toml(read_text(path, kind, error), str(path), error)


# -- The parsed tree ------------------------------------------------------------------------


def _too_deep(where: str, line: int | None, field: str | None = None) -> str:
    at = f"line {line}: " if line is not None else ""
    inside = f" (at field {field})" if field else ""
    return (
        f"{where}: {at}nested more than {MAX_DEPTH} levels deep{inside}; hexcal's files nest a "
        "few levels: is it the right file?"
    )


def check_tree(data: Any, where: str, error: ErrorFactory, nonfinite_hint: str) -> None:
    """Refuse a parsed JSON/TOML value nested deeper than :data:`MAX_DEPTH` or holding a
    non-finite float; the message names the field (``steps.2.tolerance_mm``)."""
    # A fast pass with no paths (a session holds millions of numbers); the paths are built
    # only to name the culprit once one is known to exist.
    stack: list[tuple[Any, int]] = [(data, 1)] if type(data) in (dict, list) else []
    bad = False
    while stack and not bad:
        node, depth = stack.pop()
        values = node.values() if type(node) is dict else node
        for v in values:
            t = type(v)
            if t is float:
                if v - v != 0.0:  # NaN or ±inf: inf − inf and NaN − NaN are NaN
                    bad = True
                    break
            elif t is dict or t is list:
                if depth >= MAX_DEPTH:
                    bad = True
                    break
                stack.append((v, depth + 1))
    if not bad and type(data) is float and not math.isfinite(data):
        bad = True
    if bad:
        raise error(_locate_problem(data, where, nonfinite_hint))


def _locate_problem(data: Any, where: str, nonfinite_hint: str) -> str:
    stack: list[tuple[Any, tuple[Any, ...]]] = [(data, ())]
    while stack:
        node, path = stack.pop()
        if type(node) is float and not math.isfinite(node):
            return (
                f"{where}: field {field_name(path)}: {_float_text(node)} is not a finite number; "
                f"give a number ({nonfinite_hint}, and a decimal beyond ±1.8e308 reads as "
                "infinite)"
            )
        if type(node) in (dict, list):
            if len(path) >= MAX_DEPTH:
                return _too_deep(where, None, field_name(path[:6]) + ".…")
            items = node.items() if type(node) is dict else enumerate(node)
            # Reversed so that the first problem in file order is found first.
            stack.extend((v, (*path, k)) for k, v in reversed(list(items)))
    return f"{where}: cannot be read"  # pragma: no cover - check_tree found a problem


def _float_text(x: float) -> str:
    if math.isnan(x):
        return "NaN"
    return "Infinity" if x > 0 else "-Infinity"


def field_name(path: tuple[Any, ...] | list[Any]) -> str:
    """``base_points.2.0``: a location inside a file, dot-separated, list indices from 0."""
    return ".".join(str(p) for p in path) or "(top level)"
