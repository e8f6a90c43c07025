"""Screens that fit: at 80×24 and 120×40 no line of the start, recording, result or diagnosis
screen is cut where it holds a number (driven by Textual's Pilot, read off the rendered
screen), the title is shortened rather than cut, and wide tables are stacked in blocks of
columns instead of scrolling sideways (hexcal.tui.fit)."""

from __future__ import annotations

import asyncio
import html
import re
import time

import pytest

from hexcal.sim.robots import left_hand
from hexcal.tui.app import HexcalApp
from hexcal.tui.backend import InstantBackend, mock_backend
from hexcal.tui.fit import fit_table, reflow
from hexcal.tui.record import RecordScreen
from hexcal.tui.results import DiagnosisScreen, ResultScreen

SIZES = [(80, 24), (120, 40)]
_TEXT = re.compile(
    r'<text class="[^"]*" x="([\d.]+)" y="[\d.]+" textLength="[\d.]+" '
    r'clip-path="url\(#terminal-(?:\d+-)?line-(\d+)\)">(.*?)</text>'
)
#: Textual's SVG screenshots: one character cell is 12.2 units wide.
CELL = 12.2


def screen_lines(app) -> list[str]:
    """The screen as it is drawn, one string per row, ``size`` wide (from Textual's SVG
    screenshot: each run of text placed at its column)."""
    width, height = app.size
    grid = [[" "] * width for _ in range(height)]
    for m in _TEXT.finditer(app.export_screenshot()):
        col, row = round(float(m.group(1)) / CELL), int(m.group(2))
        for k, ch in enumerate(html.unescape(m.group(3)).replace("\xa0", " ")):
            if row < height and col + k < width:
                grid[row][col + k] = ch
    return ["".join(r).rstrip() for r in grid]


def cut_numbers(lines: list[str]) -> list[str]:
    """Pieces of the screen (between box borders) that end in "…" and hold a number."""
    out = []
    for line in lines:
        for piece in re.split(r"[│┃║]", line):
            piece = piece.strip()
            if piece.endswith("…") and re.search(r"\d", piece):
                out.append(piece)
    return out


async def _until(pilot, cond, timeout_s: float) -> None:
    end = time.monotonic() + timeout_s
    while not cond():
        assert time.monotonic() < end, "timed out"
        await pilot.pause(0.05)


async def _idle(pilot) -> None:
    await pilot.pause()
    await pilot.app.workers.wait_for_complete()
    await _until(pilot, lambda: not getattr(pilot.app.screen, "busy", False), 30)
    await pilot.pause()


async def _pages(pilot, seen: list[list[str]]) -> None:
    """Every page of a scrolling screen, from the top: End, then Page Up until the top."""
    scroll = pilot.app.screen.query_one("VerticalScroll")
    scroll.scroll_home(animate=False)
    await pilot.pause()
    while True:
        seen.append(screen_lines(pilot.app))
        if scroll.scroll_y >= scroll.max_scroll_y:
            return
        scroll.scroll_page_down(animate=False)
        await pilot.pause()


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_no_number_is_cut_on_the_main_screens(tmp_path, size):
    """Start, recording (a clamped step: its monitor and next best pose), result and diagnosis
    (every page), on the instant mock rig: no piece of a line ending in "…" holds a number."""
    backend = InstantBackend(
        left_hand(), "instant mock rig (a robot hiding gain)", simulated=True, seed=2
    )
    app = HexcalApp(backend, session_path=tmp_path / "s.json", poses_per_step=5, free_poses=12)
    seen: dict[str, list[list[str]]] = {"start": [], "record": [], "result": [], "diagnosis": []}

    async def run() -> None:
        async with app.run_test(size=size) as pilot:
            seen["start"].append(screen_lines(app))
            await pilot.press("enter")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 10)
            await pilot.press("r")
            await _idle(pilot)
            await pilot.press("n", "c")
            for _ in range(5):
                await pilot.press("m", "r")
                await _idle(pilot)
            seen["record"].append(screen_lines(app))
            await pilot.press("A")
            await _until(pilot, lambda: app.guided.finished and not app.screen.busy, 60)
            seen["record"].append(screen_lines(app))
            await pilot.press("k")
            await _until(pilot, lambda: isinstance(app.screen, ResultScreen), 5)
            await _idle(pilot)
            await _until(pilot, lambda: app.screen._text != "calibrating…", 60)
            await _pages(pilot, seen["result"])
            await pilot.press("d")
            await _until(pilot, lambda: isinstance(app.screen, DiagnosisScreen), 5)
            await _until(pilot, lambda: len(app.screen.history) == 1, 60)
            await _idle(pilot)
            await _pages(pilot, seen["diagnosis"])
            # After `a`, the new verdict is on screen wherever the view was scrolled to.
            assert app.screen.history[-1].verdict == "gain"
            app.screen.query_one("VerticalScroll").scroll_end(animate=False)
            await pilot.pause()
            await pilot.press("a")
            await _until(pilot, lambda: len(app.screen.history) == 2, 60)
            await _idle(pilot)
            seen["after a"] = [screen_lines(app)]

    asyncio.run(run())
    # Plain words first: the pose error against its floor is on the first page of the result
    # and diagnosis screens, without scrolling; after `a`, the new verdict is in view.
    for name in ("result", "diagnosis"):
        first = " ".join(" ".join(seen[name][0]).split())
        assert re.search(r"pose error \S+ µm|Pose error \(position RMS", first), (name, first)
        assert "the instruments allow" in first, (name, first)
    after = " ".join(" ".join(seen["after a"][0]).split())
    assert "Nothing is missing" in after and "verdict: none" in after, after
    for name, pages in seen.items():
        assert pages, name
        for lines in pages:
            assert len(lines) == size[1], name
            assert not cut_numbers(lines), (name, cut_numbers(lines))
    # The tables were stacked, not left to scroll sideways: every page fits its width.
    result = "\n".join(line for page in seen["result"] for line in page)
    assert "a table is wider than the window" not in result
    assert re.search(r"leg +b\.x +b\.y +b\.z", result), "the b points' block"


@pytest.mark.parametrize("size", SIZES, ids=lambda s: f"{s[0]}x{s[1]}")
def test_the_live_lines_keep_their_numbers_through_the_drivers(tmp_path, size, quick_pilot):
    """On the mock rig through the real drivers: the title is the short one, whole; the bus
    line (state, sets, flagged) wraps under its label instead of being cut; the clamp monitor
    shows its numbers whole."""
    app = HexcalApp(
        mock_backend(seed=7, window_s=0.1), session_path=tmp_path / "s.json", poses_per_step=4
    )

    async def run() -> list[str]:
        async with app.run_test(size=size) as pilot:
            await pilot.press("enter")
            await _until(pilot, lambda: isinstance(app.screen, RecordScreen), 30)
            g = app.guided
            # The pilot's idle wait is cut on the mock rig (quick_pilot): a key may not be
            # handled yet when press returns, so each wait is for the state the next key needs.
            await pilot.press("r")
            await _until(pilot, lambda: g.n_poses == 1 and not app.screen.busy, 30)
            await pilot.press("n", "c")
            await _until(pilot, lambda: g.index == 1 and g.clamped, 30)
            for i in range(4):
                await pilot.press("m", "r")
                await _until(pilot, lambda i=i: g.n_poses == i + 1 and not app.screen.busy, 30)
            await pilot.pause(0.3)  # the live panel's next refresh
            return screen_lines(app)

    lines = asyncio.run(run())
    assert "hexcal — mock rig, seed 7" in lines[0] and "…" not in lines[0], lines[0]
    assert not cut_numbers(lines), cut_numbers(lines)
    live = " ".join(p.strip() for line in lines for p in re.split(r"[│]", line)[3:4] if p.strip())
    assert re.search(r"legs +ACTIVE, \d+ sets \(\d+ flagged\)", live), live
    assert re.search(r"clamp length [+-]\d\.\d{4} mm since the first pose", live), live
    assert re.search(r"point \d\.\d{3} mm off the step's fit \(≤ \d\.\d{3}\)", live), live


# -- the text layout itself ---------------------------------------------------------------------
GEOMETRY = "\n".join(
    [
        "  leg" + "".join(f"{h:>19}" for h in ("a.x", "a.y", "a.z", "b.x", "b.y", "b.z", "offset")),
        "    1  -96.9881 ± 0.0973    90.9335 ± 0.0676    -0.4488 ± 0.2735   -30.4011 ± 0.0270"
        "    72.4488 ± 0.0255    -0.0986 ± 0.0382   153.3250 ± 0.2883",
        "    6 -128.0297 ± 0.0805    38.8881 ± 0.1007    -0.7118 ± 0.2864   -77.9099 ± 0.0259"
        "   -10.7596 ± 0.0257    -0.0309 ± 0.0428   153.3159 ± 0.3039",
    ]
)

ERRORS = "\n".join(
    [
        "model                               held-out   blocked   floor      pose      p95"
        "  angle °   per-leg held-out",
        "design (drawing, all poses)           676.00                     2560.81  3045.33   1.1739",
        "Model 42                               22.10     22.73   10.54     52.24    86.02   0.0224"
        "    27.9  15.4  27.5  19.8  22.2  16.5   → backlash",
        "Model 42 + backlash                    10.31     10.36   10.54     17.77    26.94   0.0047"
        "     9.9   9.7  10.1  10.8  10.7  10.6   → none",
    ]
)


def _cells(text: str) -> list[str]:
    return sorted(re.findall(r"[−-]?\d+\.\d+(?: ± \d+\.\d+)?|→ \w+", text))


@pytest.mark.parametrize("width", [76, 116])
def test_a_wide_table_is_stacked_in_blocks_that_fit_and_lose_nothing(width):
    """The geometry table (152 columns): blocks no wider than the box, each led by the leg
    column; a point's x, y, z stay in one block; every value appears once, whole."""
    rows = GEOMETRY.split("\n")
    out = fit_table(rows, width)
    assert max(len(x) for x in out) <= width
    assert _cells("\n".join(out)) == _cells(GEOMETRY)
    blocks = "\n".join(out).split("\n\n")
    assert len(blocks) == (3 if width == 76 else 2)
    for block in blocks:
        head, *body = block.split("\n")
        assert head.lstrip().startswith("leg") and [b.split()[0] for b in body] == ["1", "6"]
    heads = [b.split("\n")[0].split()[1:] for b in blocks]
    assert heads[0] == ["a.x", "a.y", "a.z"]
    assert ["b.x", "b.y", "b.z"] == heads[1][:3]


def test_the_per_leg_columns_stay_under_their_header():
    """The error table: the six legs' values, which have no header of their own, stay with
    "per-leg held-out"; the verdict arrow, not a number, may go to a block of its own."""
    out = "\n".join(fit_table(ERRORS.split("\n"), 76))
    assert max(len(x) for x in out.split("\n")) <= 76
    assert _cells(out) == _cells(ERRORS)
    legs = [b for b in out.split("\n\n") if "per-leg held-out" in b]
    assert len(legs) == 1 and "27.9  15.4  27.5  19.8  22.2  16.5" in legs[0]


def test_a_table_that_fits_and_prose_are_left_as_they_are_or_wrapped_between_words():
    narrow = "  leg   a\n    1   2.5\n    2   3.5"
    assert fit_table(narrow.split("\n"), 76) == narrow.split("\n")
    prose = "pose error, held-out: position 0.0522 mm RMS (95 % 0.0860 mm, max 0.1137 mm), " * 2
    out = reflow(prose.strip(), 40).split("\n")
    assert max(len(x) for x in out) <= 40
    assert " ".join(x.strip() for x in out) == prose.strip()  # broken between words only


CANDIDATES = "\n".join(
    [
        "  effect        score Δχ²      ΔBIC  explains  held-out after  identifiable",
        "  balljoint          14.7      27.4         —        11.39 µm  yes",
        "  drift               0.0         —         —               —  n/a: the poses span 15 s:"
        " too short a time to show a drift",
        "  zero_step           0.0         —         —               —  n/a: no change of a leg's"
        " zero was located (hexcal diagnose searches each leg's residual in recording order;"
        " robot.json zero_steps states one)",
    ]
)


@pytest.mark.parametrize("width", [60, 76])
def test_a_last_column_of_prose_is_wrapped_in_a_block_of_its_own(width):
    """The diagnosis's candidates: the reason a score is n/a, longer than the box, goes to a
    block led by the effect and is wrapped there; every word and number is kept, in order."""
    out = fit_table(CANDIDATES.split("\n"), width)
    assert max(len(x) for x in out) <= width
    assert _cells("\n".join(out)) == _cells(CANDIDATES)
    numbers, reasons = "\n".join(out).split("\n\n")
    assert "identifiable" not in numbers and "11.39 µm" in numbers
    lines = reasons.split("\n")
    assert lines[0].split() == ["effect", "identifiable"]
    assert lines[1].split() == ["balljoint", "yes"]
    zero = lines[lines.index(next(x for x in lines if x.lstrip().startswith("zero_step"))) :]
    assert len(zero) > 1 and all(x.startswith(" " * 13) for x in zero[1:])  # under its cell
    said = " ".join(" ".join(x.split()) for x in zero)
    assert said.endswith("robot.json zero_steps states one)") and said.startswith("zero_step n/a:")


def test_a_last_column_of_numbers_is_never_wrapped():
    rows = ["  leg   a      b", "    1   2.5   " + "3" * 90, "    2   3.5   4"]
    assert fit_table(rows, 40) == rows  # one column wider than the box: left whole


def test_a_path_longer_than_the_box_is_cut_after_a_separator():
    """A session's path deeper than the screen is wide would make the details scroll
    sideways: it is cut after a ``/`` (or ``\\``), nothing lost; prose is wrapped as before."""
    path = "/home/lab/hexapod/calibrations/2026-11-27/left-hand/after-the-new-nut/session.json"
    line = f"  the calibrated model: hexcal diagnose {path} --robot robot.json --auto"
    out = reflow(line, 40).split("\n")
    assert max(len(x) for x in out) <= 40
    assert "".join(out).replace(" ", "") == line.replace(" ", "")  # nothing lost, in order
    pieces = [x.strip() for x in out if "/" in x]
    assert "".join(pieces) == path and len(pieces) >= 3
    assert all(p.endswith("/") for p in pieces[:-1])  # cut after a separator only
    win = "  at C:\\Users\\lab\\hexapod\\calibrations\\2026-11-27\\left-hand\\session.json"
    assert max(len(x) for x in reflow(win, 30).split("\n")) <= 30
    word = "x" * 50  # no separator to cut at: left whole rather than cut inside a word
    assert "  " + word in reflow(f"a {word} b", 30).split("\n")


def test_prose_counts_a_letter_with_a_combining_mark_as_one_column():
    """A sentence as wide as the box, two of its letters with a macron (two characters, one
    column each): left on one line, not wrapped a word early; one column wider, wrapped."""
    line = "B\u0304 and A\u0304 are the mean reversal values of legs 1 and 2, in µm."
    width = len(line) - 2  # the columns it takes on screen
    assert reflow(line, width) == line
    assert reflow(line, width - 1) != line and "".join(reflow(line, width - 1).split()) == "".join(
        line.split()
    )


def test_a_letter_with_a_combining_mark_is_one_column():
    """``B̄`` is two characters and one column: a table that fits the screen is left whole, and
    one cut into blocks keeps every header over its numbers' last digit."""
    import unicodedata

    from hexcal.diagnosis.iso230_2 import LegPositioning, table_lines

    legs = [
        LegPositioning(k, 5, 53, 0.1159, 0.1, 0.1, 0.1084, 0.0648, -0.0565, 0.0031, 0.0656, 0.06,
                       0.06, 0.006)
        for k in (1, 2)
    ]  # fmt: skip
    rows = ["  " + line for line in table_lines(legs)[1:]]

    def columns(line: str) -> str:
        return "".join(c for c in line if not unicodedata.combining(c))

    width = max(len(columns(r)) for r in rows)
    assert width < max(len(r) for r in rows)  # the macron is a character, not a column
    assert fit_table(rows, width) == rows
    for block in "\n".join(fit_table(rows, 50)).split("\n\n"):
        head, row = (columns(x) for x in block.split("\n")[:2])
        for name in {"A", "R", "σ", "E", "M"} & set(head.split()):
            end = head.index(f" {name}") + 1  # σ ends the header of B̄ ± σ, after the macron
            assert row[end] != " " and (end + 1 == len(row) or row[end + 1] == " "), block
