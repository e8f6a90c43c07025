"""CSV files as labs write them: the dialect of a table, found from its first lines.

hexcal writes one dialect (comma-separated, decimal point, UTF-8, ``\\n``); spreadsheets and lab
software write others. :func:`sniff` finds, from a file's first bytes, what it needs to read the
common variants as they are:

- the **encoding**: UTF-8, with or without a byte-order mark, or UTF-16 with its mark (Excel's
  "Unicode Text", tab-separated);
- the **separator**: ``,``, ``;`` (a spreadsheet in a locale whose decimal mark is a comma),
  tab or ``|``; Excel's ``sep=;`` first line is honoured and skipped;
- the **decimal mark**: a comma (``12,5``) where the separator is not one, or in quoted cells;
- **trailing empty columns** (an Excel sheet with formatted columns past the data): dropped
  when they hold nothing.

Line ends (CRLF, CR) and quoting (quoted header names, quoted cells) are the csv module's.
What cannot be read unambiguously is refused by :func:`sniff` with the variant named and the
fix: decimal commas in a file separated by commas.
"""

from __future__ import annotations

import codecs
import csv
import io
import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from hexcal.errors import InputError
from hexcal.io.safe_read import ErrorFactory, decode

#: Separators tried, in order of preference when they tie.
SEPARATORS = (",", ";", "\t", "|")
_NAMES = {",": "commas", ";": "semicolons", "\t": "tabs", "|": "vertical bars"}
#: A number written with a decimal comma: ``12,5``, ``-0,001``, ``1,5e-3``.
DECIMAL_COMMA = re.compile(r"[+-]?[0-9]*,[0-9]+(?:[eE][+-]?[0-9]+)?")
#: Bytes looked at to find the dialect.
HEAD_BYTES = 64 * 1024


@dataclass(frozen=True)
class Dialect:
    """How a table is written: ``delimiter``, ``decimal`` mark, the text ``encoding`` (a codec
    name for :class:`io.TextIOWrapper`) and ``skip`` lines before the header (Excel's
    ``sep=`` line)."""

    delimiter: str = ","
    decimal: str = "."
    encoding: str = "utf-8-sig"
    skip: int = 0
    bom: str = ""
    #: Empty columns at the end of the header and of every row (a spreadsheet's padding)
    padding: int = 0

    @property
    def standard(self) -> bool:
        """Whether this is the dialect hexcal writes (a UTF-8 byte-order mark aside)."""
        return (
            self.delimiter == ","
            and self.decimal == "."
            and self.skip == 0
            and self.padding == 0
            and self.encoding == "utf-8-sig"
        )

    def describe(self) -> str:
        """The variant in words, e.g. ``separated by semicolons, with decimal commas``."""
        parts = [f"separated by {_NAMES.get(self.delimiter, repr(self.delimiter))}"]
        if self.decimal == ",":
            parts.append("with decimal commas")
        if self.encoding == "utf-16":
            parts.append("in UTF-16 (Excel's Unicode text)")
        if self.skip:
            parts.append("after Excel's 'sep=' line")
        if self.padding:
            parts.append(f"padded with {self.padding} empty column(s)")
        return ", ".join(parts)

    def trim(self, fields: list[str], width: int) -> list[str]:
        """A row without the padding (kept whole when its padding cells hold something, or
        its width is not the padded header's: the reader names the problem)."""
        if self.padding and len(fields) == width + self.padding:
            tail = fields[width:]
            if not any(c.strip() for c in tail):
                return fields[:width]
        return fields

    def reader(self, stream: io.TextIOBase) -> Any:
        """A csv reader of ``stream`` in this dialect (the skipped lines read past)."""
        for _ in range(self.skip):
            stream.readline()
        return csv.reader(stream, delimiter=self.delimiter)


class DialectError(InputError):
    """A variant that cannot be read unambiguously; the message names it and the fix."""


def encoding_of(head: bytes) -> tuple[str, str]:
    """(codec, the mark's name) from a file's first bytes."""
    if head.startswith((codecs.BOM_UTF16_LE, codecs.BOM_UTF16_BE)):
        return "utf-16", "UTF-16"
    if head.startswith(codecs.BOM_UTF8):
        return "utf-8-sig", "UTF-8"
    return "utf-8-sig", ""


def _lines(head: bytes, encoding: str) -> list[str]:
    """The first whole lines of ``head`` (what decodes of it)."""
    decoder = codecs.getincrementaldecoder(encoding)("ignore")
    text = decoder.decode(head, final=False)
    lines = text.splitlines()
    if not head.endswith((b"\n", b"\r", b"\n\x00", b"\r\x00")) and len(lines) > 1:
        lines = lines[:-1]  # cut mid-line
    return [ln for ln in lines[:50] if ln.strip()]


def _fields(line: str, delimiter: str) -> list[str]:
    try:
        return next(csv.reader([line], delimiter=delimiter), [])
    except csv.Error:
        return line.split(delimiter)


def sniff(head: bytes, required: Sequence[str] = (), numeric: Sequence[str] = ()) -> Dialect:
    """The dialect of a table from its first bytes (see the module docstring). ``required``
    names the header's expected columns (they decide between separators); ``numeric`` the
    columns holding numbers (where a decimal comma is looked for)."""
    encoding, bom = encoding_of(head)
    lines = _lines(head, encoding)
    skip = 0
    if lines and re.fullmatch(r"\s*sep=(.)\s*", lines[0].lstrip("\ufeff")):
        delimiter = lines[0].lstrip("\ufeff").strip()[4]
        skip, lines = 1, lines[1:]
    else:
        delimiter = _separator(lines, required)
    decimal = _decimal(lines, delimiter, numeric)
    return Dialect(delimiter, decimal, encoding, skip, bom, _padding(lines, delimiter))


def _padding(lines: list[str], delimiter: str) -> int:
    """Empty columns closing the header and every row looked at (a spreadsheet's export of a
    sheet formatted past its data); 0 when a row has something there or another width."""
    if len(lines) < 2:
        return 0
    header = _fields(lines[0], delimiter)
    k = 0
    while k < len(header) and not header[len(header) - 1 - k].strip():
        k += 1
    if k == 0 or k == len(header):
        return 0
    for line in lines[1:]:
        cells = _fields(line, delimiter)
        if len(cells) != len(header) or any(c.strip() for c in cells[len(header) - k :]):
            return 0
    return k


def _separator(lines: list[str], required: Sequence[str]) -> str:
    if not lines:
        return ","
    header = lines[0].lstrip("\ufeff")
    wanted = {c.lower() for c in required}

    def score(d: str) -> tuple[int, int]:
        names = [f.strip().strip("\"'").lower() for f in _fields(header, d)]
        return len(wanted.intersection(names)), len(names)

    best = max(SEPARATORS, key=score)
    return best if score(best)[1] > 1 else ","


def _decimal(lines: list[str], delimiter: str, numeric: Sequence[str]) -> str:
    """``,`` when the numeric columns' cells are written with decimal commas."""
    if len(lines) < 2:
        return "."
    header = [f.strip().lower() for f in _fields(lines[0].lstrip("\ufeff"), delimiter)]
    columns = [i for i, name in enumerate(header) if name in {c.lower() for c in numeric}]
    rows = [_fields(line, delimiter) for line in lines[1:]]
    if delimiter == "," and all(_looks_split(cells, len(header)) for cells in rows):
        raise DialectError(
            "every row has many more cells than the header, all digits: numbers written with "
            "decimal commas in a file separated by commas, which no reader can split apart. "
            "Save it again with ';' as the separator (or '.' as the decimal mark)"
        )
    commas = points = 0
    for cells in rows:
        for i in columns:
            if i < len(cells):
                cell = cells[i].strip()
                commas += bool(DECIMAL_COMMA.fullmatch(cell))
                points += "." in cell
    return "," if commas and not points else "."


def _looks_split(cells: list[str], n: int) -> bool:
    """Whether a row of ``n`` columns looks cut at its numbers' decimal commas: at least three
    cells too many, and most of them bare digits."""
    digits = [c.strip() for c in cells if c.strip()]
    return len(cells) >= n + 3 and sum(c.lstrip("+-").isdigit() for c in digits) > len(cells) // 2


def to_point(cell: str) -> str:
    """A decimal-comma number as a decimal-point one (``12,5`` → ``12.5``); a cell that also
    holds a point (digit grouping, ``1.234,5``) is left as it is, for its reader to refuse."""
    return cell.replace(",", ".") if "," in cell and "." not in cell else cell


def grouping_hint(text: str) -> str:
    """A hint for a number that does not parse because of digit grouping, or ''."""
    if re.fullmatch(r"[+-]?[0-9]{1,3}([.,' ][0-9]{3})+([.,][0-9]+)?", text.strip()):
        return " (digit grouping? save the numbers without thousands separators)"
    return ""


def table_text(
    raw: bytes,
    where: str,
    error: ErrorFactory,
    required: Sequence[str] = (),
    numeric: Sequence[str] = (),
) -> tuple[Dialect, str]:
    """The dialect and the text of a table read whole (``raw``, its bytes); errors
    (``error(message)``) name ``where`` and say what to do."""
    try:
        dialect = sniff(raw[:HEAD_BYTES], required, numeric)
    except DialectError as exc:
        raise error(f"{where}: line 2: {exc}") from None
    if dialect.encoding != "utf-16":
        return dialect, decode(raw, where, error)
    try:
        return dialect, raw.decode("utf-16")
    except UnicodeDecodeError as exc:
        raise error(
            f"{where}: byte {exc.start} is not UTF-16 text, though the file starts as UTF-16 "
            "does; save it as UTF-8"
        ) from None


def table_rows(text: str, dialect: Dialect) -> tuple[list[list[str]], list[int]]:
    """The non-blank rows of a table's text (the header first, padding dropped) and the line
    each starts on (the file's first line is 1). Raises :class:`csv.Error` with the reader's
    line in ``args[1]``."""
    stream = io.StringIO(text, newline="")
    reader = dialect.reader(stream)
    rows: list[list[str]] = []
    lines: list[int] = []
    start = 1
    width = 0
    try:
        for r in reader:
            line, start = start + dialect.skip, reader.line_num + 1
            if not (r and any(c.strip() for c in r)):
                continue
            if not rows:
                width = len(r) - dialect.padding
                r = r[:width]
            else:
                r = dialect.trim(r, width)
            rows.append(r)
            lines.append(line)
    except csv.Error as exc:
        raise csv.Error(str(exc), reader.line_num + dialect.skip) from None
    return rows, lines
