"""The HTML report in a real browser (headless Chromium; skipped without one): no table header
breaks a word across lines, nothing is wider than the page, and the page renders to a
screenshot. The layout is measured by the browser itself: a script added to a copy of the
report walks every header word with a DOM Range (a word split across lines has two boxes) and
writes what it found into the page, which ``--dump-dom`` returns."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from hexcal.diagnosis.report import write_report
from hexcal.io.measurements import write_measurements

BROWSER = next(
    (b for b in ("chromium", "chromium-browser", "google-chrome") if shutil.which(b)), None
)
pytestmark = pytest.mark.skipif(BROWSER is None, reason="no headless Chromium on this machine")

#: Finds header words split over two lines and elements wider than the page; the result goes
#: into <pre id="layout-check"> for --dump-dom to return.
CHECK = """
<script>
window.addEventListener('load', () => {
  const broken = [], headerBroken = [];
  const walker = document.createTreeWalker(document.querySelector('main'), NodeFilter.SHOW_TEXT);
  for (let node = walker.nextNode(); node; node = walker.nextNode()) {
    const el = node.parentElement;
    if (!el || el.closest('.h-full, style, script')) continue;
    const re = /[^\\s\\u2014\\u2013-]+/g;
    let m;
    while ((m = re.exec(node.data)) !== null) {
      const r = document.createRange();
      r.setStart(node, m.index);
      r.setEnd(node, m.index + m[0].length);
      const lines = new Set(Array.from(r.getClientRects()).map(b => Math.round(b.top)));
      if (lines.size > 1) (el.closest('th') ? headerBroken : broken).push(m[0]);
    }
  }
  const page = document.documentElement.clientWidth;
  // Nothing but a table inside its own scrolling box may be wider than the page.
  const wide = Array.from(document.querySelectorAll('main *'))
    .filter(e => !(e.parentElement && e.parentElement.closest('.tbl')))
    .filter(e => !e.closest('.h-full'))
    .filter(e => e.getBoundingClientRect().right > page + 1)
    .map(e => e.id || e.className || e.tagName);
  const boxes = Array.from(document.querySelectorAll('.tbl'));
  const unboxed = Array.from(document.querySelectorAll('table')).filter(t => !t.parentElement.classList.contains('tbl')).length;
  const main = document.querySelector('main').getBoundingClientRect().width;
  const figs = Array.from(document.querySelectorAll('figure img')).map(i => i.getBoundingClientRect().width / main);
  const out = document.createElement('pre');
  out.id = 'layout-check';
  out.textContent = JSON.stringify({broken, headerBroken, wide, unboxed, figs,
    scrolled: boxes.filter(b => b.scrollWidth > b.clientWidth + 1).length,
    headers: document.querySelectorAll('th').length, scrollWidth: document.documentElement.scrollWidth, page});
  document.body.appendChild(out);
  parent.postMessage(out.textContent, '*');
});
</script>
"""


#: What a reader sees, measured on the laid-out boxes: a number and its unit ("22.1 µm"), a
#: label ("leg 1", "Model 42") or a timestamp split over two lines; each table header row's
#: height against the lines of text it holds; a table that makes the page or its own box
#: scroll sideways; and the boxes of tables set side by side (.pair), for their gaps.
MEASURE = r"""
<script>
window.addEventListener('load', () => {
  const main = document.querySelector('main');
  const together = new RegExp([
    '\\d[\\d.,]*[ \\u00a0](?:µm|mm|°|%|ppm|s|K|kg|N|×)(?![\\w])',  // a number and its unit
    '\\b(?:leg|Model|Step|step|pose)[ \\u00a0]\\d+',  // a label
    '\\d{4}-\\d\\d-\\d\\dT[\\d:]+(?:[+-]\\d\\d:\\d\\d|Z)?',  // a timestamp
  ].join('|'), 'g');
  const split = [];
  const walker = document.createTreeWalker(main, NodeFilter.SHOW_TEXT);
  for (let node = walker.nextNode(); node; node = walker.nextNode()) {
    const el = node.parentElement;
    if (!el || el.closest('.h-full, style, script') || !el.getClientRects().length) continue;
    let m;
    together.lastIndex = 0;
    while ((m = together.exec(node.data)) !== null) {
      const r = document.createRange();
      r.setStart(node, m.index);
      r.setEnd(node, m.index + m[0].length);
      const tops = new Set(Array.from(r.getClientRects()).filter(b => b.width > 0).map(b => Math.round(b.bottom)));
      if (tops.size > 1) split.push(m[0]);
    }
  }
  // A header row against its text: the most lines any of its cells' text takes.
  const tall = [];
  for (const tr of main.querySelectorAll('tr')) {
    const ths = Array.from(tr.children).filter(c => c.tagName === 'TH');
    if (!ths.length) continue;
    const h = tr.getBoundingClientRect().height;
    if (h === 0) continue;
    let lines = 0;
    for (const th of ths) {
      const r = document.createRange();
      r.selectNodeContents(th);
      const tops = new Set(Array.from(r.getClientRects()).filter(b => b.width > 0).map(b => Math.round(b.top)));
      lines = Math.max(lines, tops.size);
    }
    const line = parseFloat(getComputedStyle(ths[0]).lineHeight) || 20;
    tall.push({row: tr.textContent.slice(0, 40), height: h, text: lines * line, lines});
  }
  const page = document.documentElement.clientWidth;
  const sideways = Array.from(main.querySelectorAll('.tbl'))
    .filter(b => b.scrollWidth > b.clientWidth + 1).map(b => b.textContent.slice(0, 40));
  const pairs = Array.from(main.querySelectorAll('.pair')).map(p => Array.from(p.children).map(c => {
    const b = c.getBoundingClientRect(); return [b.left, b.top, b.right, b.bottom]; }));
  const nested = main.querySelectorAll('table table').length;
  const out = document.createElement('pre');
  out.id = 'layout-check';
  out.textContent = JSON.stringify({split, tall, sideways, pairs, nested, page,
    scrollWidth: document.documentElement.scrollWidth});
  document.body.appendChild(out);
  parent.postMessage(out.textContent, '*');
});
</script>
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    assert BROWSER is not None
    cmd = [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True)


#: Headless Chromium lays a page out at least 500 px wide, whatever --window-size says: the
#: page is measured in a frame of the width asked for, which is its viewport (media queries
#: included), and its check posts what it found to this host page.
FRAME = """<!DOCTYPE html><html><body style="margin:0">
<iframe src="{src}" style="border:0;width:{width}px;height:900px"></iframe>
<script>
window.addEventListener('message', e => {{
  const out = document.createElement('pre');
  out.id = 'layout-check';
  out.textContent = e.data;
  document.body.appendChild(out);
}});
</script></body></html>"""


def _layout(page: Path, width: int, check: str = CHECK) -> dict[str, Any]:
    checked = page.with_name(f"checked-{width}.html")
    checked.write_text(page.read_text(encoding="utf-8").replace("</body>", check + "</body>"))
    host = page.with_name(f"frame-{width}.html")
    host.write_text(FRAME.format(src=checked.name, width=width))
    dom = _run(
        f"--window-size={max(width, 500) + 20},1000",
        "--virtual-time-budget=8000",
        "--allow-file-access-from-files",
        "--dump-dom",
        host.as_uri(),
    )
    found = re.search(r'<pre id="layout-check">(.*?)</pre>', dom.stdout, re.S)
    assert found, "the browser did not run the layout check"
    result = json.loads(html.unescape(found.group(1)))
    assert result["page"] == width, result["page"]  # measured at the width asked for
    return result


@pytest.fixture(scope="module")
def page(backlash_diagnoses, tmp_path_factory) -> Path:
    before, after, meas, _ = backlash_diagnoses
    out = tmp_path_factory.mktemp("browser")
    write_measurements(meas, out / "measurements.csv")
    return write_report(
        [before, after],
        out / "report.html",
        {"measurements": out / "measurements.csv"},
        plots=False,
    )


@pytest.mark.parametrize("width", [390, 768, 1280])
def test_no_word_or_number_breaks_and_no_table_overflows_its_box(page, width):
    """At a phone's, a tablet's and a desktop's width: no word or number is split across lines
    (headers included), every table sits in its own box and nothing is wider than the page
    (a wide table scrolls inside its box), the page does not scroll sideways, and the plots
    take the width of the page."""
    found = _layout(page, width)
    assert found["headers"] > 20  # the check saw the tables
    assert found["broken"] == [] and found["headerBroken"] == []
    assert found["wide"] == [] and found["unboxed"] == 0
    assert found["scrollWidth"] <= found["page"]
    if width == 390:
        assert found["scrolled"] == 0  # the wide tables reflow there: a card per row
    assert all(f > 0.9 for f in found["figs"]), found["figs"]


def test_the_report_renders_to_a_screenshot(page):
    shot = page.with_name("report.png")
    _run("--window-size=1280,1600", f"--screenshot={shot}", page.as_uri())
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and shot.stat().st_size > 20_000


def test_the_walkthrough_report_with_its_plots_fits_a_phone(tmp_path):
    """docs/walkthrough/report.html (plots drawn; its screenshots at 390, 768 and 1280 px sit
    beside it) at 390 px: the same checks, and each plot as wide as the page allows."""
    doc = Path(__file__).parents[1] / "docs" / "walkthrough" / "report.html"
    page = tmp_path / "report.html"
    page.write_text(doc.read_text(encoding="utf-8"), encoding="utf-8")
    found = _layout(page, 390)
    assert found["broken"] == [] and found["headerBroken"] == [] and found["wide"] == []
    assert len(found["figs"]) >= 10 and all(f > 0.9 for f in found["figs"]), found["figs"]
    for width in (390, 768, 1280):
        assert (doc.parent / f"report-{width}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


#: A header row may take this many lines of text (a short label over a number column wraps to
#: two or three); the row's height, this many lines' and its padding (8 px), 2 px of rounding.
HEADER_LINES = 3.2


@pytest.mark.parametrize("width", [390, 768, 1280])
def test_what_a_reader_sees_at_each_width(page, width):
    """Measured in Chromium on the laid-out boxes, at a phone's, a tablet's and a desktop's
    width: no number split from its unit, no "leg 1" or "Model 42" and no timestamp broken
    over two lines; no header row taller than the text it holds (it was 150 px for one word per
    line) nor holding more than HEADER_LINES lines; no table scrolling sideways, in the page or
    in its own box (the tables reflow); no table inside a table, and the tables set side by side
    on a grid: the same width and top when side by side, the same gap as the page's when
    stacked."""
    found = _layout(page, width, MEASURE)
    assert found["split"] == [], found["split"]
    assert found["tall"] or width < 640, "the check saw no header"  # a phone's: cards
    for row in found["tall"]:
        assert row["lines"] <= HEADER_LINES, row
        assert row["height"] <= row["text"] + 12, row  # its lines, padding and border
    assert found["sideways"] == [] and found["scrollWidth"] <= found["page"], found["sideways"]
    assert found["nested"] == 0 and found["pairs"], found
    for first, second in found["pairs"]:
        if abs(first[1] - second[1]) < 1:  # side by side
            assert abs((first[2] - first[0]) - (second[2] - second[0])) < 2, (first, second)
        else:  # stacked, the gap between them the one between the page's blocks (16 px)
            assert second[1] - first[3] == pytest.approx(16, abs=2), (first, second)
