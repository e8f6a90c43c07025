"""Text that fits the screen: the result and diagnosis screens show the command line's text
(:mod:`hexcal.app.report_text`, :mod:`hexcal.diagnosis.text`) in a box of any width. Prose is
wrapped at spaces, never inside a number; a table wider than the box is cut between its columns
into blocks stacked one under the other, each led by the table's first column (the leg, the
model), so no number is cut and nothing needs scrolling sideways."""

from __future__ import annotations

import re
import textwrap

#: A table row: two gaps of two spaces or more between words.
_GAP = re.compile(r"\S {2,}(?=\S)")


def _gaps(line: str) -> int:
    return len(_GAP.findall(line.strip()))


def _is_row(lines: list[str], i: int) -> bool:
    """Whether line ``i`` is a table row: two wide gaps, and a neighbour that has them too."""
    return _gaps(lines[i]) >= 2 and any(
        _gaps(lines[j]) >= 2 for j in (i - 1, i + 1) if 0 <= j < len(lines)
    )


#: Characters that join the words on either side of a single space into one cell.
_JOINERS = set("±→×")


def _joins(a: str, b: str) -> bool:
    """Whether a single space between ``a`` and ``b`` lies inside a cell: between words
    ("Model 42", "held-out after") or around a joiner ("1.2 ± 0.3")."""
    if a == " " or b == " ":
        return False
    return a.isalpha() or b.isalpha() or a in _JOINERS or b in _JOINERS


def _columns(rows: list[str]) -> list[tuple[int, int]]:
    """The columns of a table, as (start, end) character spans of text: cut where every row
    has two spaces or more at the same place, or one space that no row uses inside a cell (a
    leg number before a negative coordinate: "6 -128.0297")."""
    width = max(len(r) for r in rows)
    padded = [r.ljust(width + 1) for r in rows]
    blank = [all(r[c] == " " for r in padded) for c in range(width)]
    spans: list[tuple[int, int]] = []
    start: int | None = None
    c = 0
    while c < width:
        if not blank[c]:
            start = c if start is None else start
            c += 1
            continue
        run = c
        while run < width and blank[run]:
            run += 1
        cut = run - c >= 2 or not any(_joins(r[c - 1], r[run]) for r in padded if c > 0)
        if start is not None and cut:
            spans.append((start, c))
            start = None
        c = run
    if start is not None:
        spans.append((start, width))
    return spans


def _number(text: str) -> bool:
    try:
        float(text.replace("−", "-"))
    except ValueError:
        return False
    return True


def _families(rows: list[str], cells: list[tuple[int, int]]) -> list[int]:
    """A family number per column, to keep together in one block where they fit: the columns of
    one point (headers ``a.x``, ``a.y``, ``a.z``), and numbers with no header of their own under
    the header before them ("per-leg held-out" over six legs)."""
    out: list[int] = []
    last = ""
    for i, (s, e) in enumerate(cells):
        head = rows[0][s:e].strip()
        values = [r[s:e].strip() for r in rows[1:] if r[s:e].strip()]
        if i and not head and values and all(_number(v) for v in values):
            out.append(out[-1])
            continue
        key = head.split(".")[0] if "." in head else head
        out.append(out[-1] if i and key and key == last else i)
        last = key
    return out


#: The narrowest a wrapped last column may be (characters): below it, the table is left whole.
TAIL_MIN = 20


def _prose_tail(padded: list[str], cell: tuple[int, int], room: int) -> bool:
    """Whether the last column ``cell`` is prose too wide for the ``room`` beside the first
    column (a reason, a note), which may be wrapped there: never a column of numbers."""
    s, e = cell
    values = [r[s:e].strip() for r in padded[1:] if r[s:e].strip()]
    return (
        e - s > room >= TAIL_MIN
        and any(" " in v for v in values)
        and not all(_number(v) for v in values)
    )


def _wrapped_tail(padded: list[str], lead: int, cell: tuple[int, int], width: int) -> list[str]:
    """The last column's block: each row's text wrapped at ``width``, its first line after the
    row's first column, the others under it."""
    s, e = cell
    out: list[str] = []
    for k, r in enumerate(padded):
        text = r[s:e].strip()
        if k and not text:
            continue
        parts = textwrap.wrap(
            text, width - lead, break_long_words=False, break_on_hyphens=False
        ) or [""]
        out.append((r[: lead - 2] + "  " + parts[0]).rstrip())
        out += [" " * lead + part for part in parts[1:]]
    return out


def _one_per_column(rows: list[str]) -> tuple[list[str], dict[int, str]]:
    """``rows`` with each letter that carries combining marks (``B̄``: B and a macron, one
    column on screen, two characters) replaced by one private-use character, so that a
    character is a column; and the map back (a :meth:`str.translate` table)."""
    back: dict[int, str] = {}
    seen: dict[str, str] = {}

    def one(m: re.Match) -> str:
        glyph = m.group(0)
        if glyph not in seen:
            seen[glyph] = chr(0xE000 + len(seen))
            back[ord(seen[glyph])] = glyph
        return seen[glyph]

    return [_COMBINED.sub(one, r) for r in rows], back


#: A letter followed by one or more combining marks (U+0300–U+036F).
_COMBINED = re.compile("[^\u0300-\u036f][\u0300-\u036f]+")


def fit_table(rows: list[str], width: int) -> list[str]:
    """``rows`` (a table, its header first) as blocks of columns at most ``width`` wide, each
    led by the first column, a family of columns (a point's x, y, z) kept in one block where it
    fits in one; a last column of prose too wide for one (a reason) wrapped in a block of its
    own; the table as it is when it fits, or when another column alone does not. Columns are
    counted as the screen shows them (a letter with a combining mark is one)."""
    rows, back = _one_per_column(rows)
    return [r.translate(back) for r in _fit_columns(rows, width)]


def _fit_columns(rows: list[str], width: int) -> list[str]:
    """:func:`fit_table` on rows whose characters are columns."""
    if max(len(r) for r in rows) <= width:
        return rows
    spans = _columns(rows)
    if len(spans) < 3:
        return rows
    lead_end = spans[0][1] + 2  # the first column and a gap of two spaces
    padded = [r.ljust(spans[-1][1]) for r in rows]
    cells = spans[1:]
    tail = cells.pop() if _prose_tail(padded, cells[-1], width - lead_end) else None
    families = _families(padded, cells)
    groups: list[list[tuple[int, int]]] = []
    group: list[tuple[int, int]] = []
    used = lead_end
    for i, (s, e) in enumerate(cells):
        if lead_end + (e - s) > width:
            return rows
        gap = s - cells[i - 1][1] if group else 0
        j = i
        while j + 1 < len(cells) and families[j + 1] == families[i]:
            j += 1
        family_width = cells[j][1] - s
        starts_family = i == 0 or families[i - 1] != families[i]
        if group and (
            used + gap + (e - s) > width
            or (
                starts_family
                and used + gap + family_width > width
                and lead_end + family_width <= width
            )
        ):
            groups.append(group)
            group, used, gap = [], lead_end, 0
        group.append((s, e))
        used += gap + (e - s)
    groups.append(group)
    out: list[str] = []
    for g, block in enumerate(groups):
        if g:
            out.append("")
        for k, r in enumerate(padded):
            if k and not any(r[s:e].strip() for s, e in block):
                continue  # a row with nothing in this block's columns
            line, prev = r[: spans[0][1]] + "  ", None
            for s, e in block:
                line += ("" if prev is None else r[prev:s]) + r[s:e]
                prev = e
            out.append(line.rstrip())
    if tail is not None:
        out += ["", *_wrapped_tail(padded, lead_end, tail, width)]
    return out


def _break_paths(line: str, width: int, indent: str) -> list[str]:
    """A wrapped line still wider than ``width`` (a file path longer than the box) cut after a
    path separator, each piece after the first indented as a continuation; a line with no
    separator to cut at stays whole."""
    pieces = []
    while len(line) > width:
        cut = max(line.rfind("/", 0, width), line.rfind("\\", 0, width))
        if cut <= len(indent) + 2:  # no separator past the indent: nothing to cut at
            break
        pieces.append(line[: cut + 1])
        line = indent + "  " + line[cut + 1 :]
    return [*pieces, line]


def reflow(text: str, width: int) -> str:
    """``text`` at ``width`` columns: prose wrapped at spaces (never inside a number or a word;
    a file path longer than the box is cut after a ``/``), tables stacked in blocks of columns
    (:func:`fit_table`). Columns are counted as the screen shows them (a letter with a
    combining mark is one)."""
    lines, back = _one_per_column(text.split("\n"))
    out: list[str] = []
    i = 0
    while i < len(lines):
        if _is_row(lines, i):
            j = i
            while j < len(lines) and _is_row(lines, j):
                j += 1
            out.extend(fit_table(lines[i:j], width))
            i = j
            continue
        line = lines[i]
        i += 1
        if len(line) <= width:
            out.append(line)
            continue
        indent = line[: len(line) - len(line.lstrip())]
        for wrapped in textwrap.wrap(
            line,
            max(20, width),
            subsequent_indent=indent + "  ",
            break_long_words=False,
            break_on_hyphens=False,
        ):
            out.extend(_break_paths(wrapped, max(20, width), indent))
    return "\n".join(out).translate(back)
