"""The HTML report in a real browser (headless Chromium; skipped without one): no table header
breaks a word across lines, nothing is wider than the page, and the page renders to a
screenshot. The layout is measured by the browser itself: a script added to a copy of the
report walks every header word with a DOM Range (a word split across lines has two boxes) and
writes what it found into the page, which ``--dump-dom`` returns."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

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
});
</script>
"""


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    assert BROWSER is not None
    cmd = [BROWSER, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=True)


def _layout(page: Path, width: int) -> dict[str, object]:
    checked = page.with_name(f"checked-{width}.html")
    checked.write_text(page.read_text(encoding="utf-8").replace("</body>", CHECK + "</body>"))
    dom = _run(
        f"--window-size={width},900", "--virtual-time-budget=5000", "--dump-dom", checked.as_uri()
    )
    found = re.search(r'<pre id="layout-check">(.*?)</pre>', dom.stdout, re.S)
    assert found, "the browser did not run the layout check"
    return json.loads(found.group(1).replace("&quot;", '"'))


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
        assert found["scrolled"] > 0  # the wide tables scroll in their boxes there
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
