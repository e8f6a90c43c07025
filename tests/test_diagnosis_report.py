"""The HTML report: one self-contained file with the verdict, provenance, every step's tables and
plots, and the before/after comparison between steps."""

from __future__ import annotations

import base64
import hashlib
import re
from html.parser import HTMLParser

import pytest

import hexcal
import hexcal.diagnosis.plots as plots_mod
import hexcal.diagnosis.report as report_mod
from hexcal.diagnosis.plots import PLOT_NAMES
from hexcal.diagnosis.report import REPORT_PLOTS, write_report
from hexcal.diagnosis.report_tables import param_rows
from hexcal.estimate.effect_fit import ParamRow
from hexcal.io.measurements import write_measurements


@pytest.fixture(scope="module")
def session(backlash_diagnoses, tmp_path_factory):
    """A backlash session on disk, diagnosed with Model 42 and Model 42 + backlash."""
    before, after, meas, _ = backlash_diagnoses
    csv = tmp_path_factory.mktemp("data") / "measurements.csv"
    write_measurements(meas, csv)
    return before, after, csv


#: Plots drawn per step in the report test: drawing is most of a report's time, and every plot
#: is drawn and checked by test_diagnosis_plots; here only embedding and layout are at stake.
DRAWN = ("per_leg_rms.png", "residuals_vs_time.png")


@pytest.fixture(scope="module")
def report(session, tmp_path_factory):
    """The two-step report written once, drawing only :data:`DRAWN` of each step's plots."""
    before, after, csv = session
    out = tmp_path_factory.mktemp("report")
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(
            report_mod,
            "plot_jobs",
            lambda d, outdir: plots_mod.plot_jobs(d, outdir, only=DRAWN),
        )
        path = write_report([before, after], out / "report.html", {"measurements": csv})
    # The words as read: a number and its unit are joined by a non-breaking space on the page
    # (tests/test_report_browser.py measures that they stay on one line).
    return out, path, path.read_text(encoding="utf-8").replace("\u00a0", " ")


def test_report_is_one_file(report):
    out, path, _ = report
    assert path.exists()
    assert [p.name for p in out.iterdir()] == ["report.html"]  # no side files, no leftover temp


def test_report_has_no_external_resources(report):
    _, _, text = report
    assert 'src="http' not in text
    assert 'href="http' not in text
    assert "<link" not in text and "<script" not in text and "@import" not in text
    # Every link is an anchor within the page.
    for href in re.findall(r'href="([^"]*)"', text):
        assert href.startswith("#"), href
    ids = set(re.findall(r'id="([^"]+)"', text))
    for href in re.findall(r'href="#([^"]*)"', text):
        assert href in ids, href


def test_report_shows_verdict_provenance_and_images(report, session):
    _, _, text = report
    before, after, csv = session
    # A sentence first, then the last step's verdict word beside its label.
    assert text.index('<p class="lead">') < text.index('<span class="badge">none</span>')
    assert 'class="verdict v-none"' in text
    assert "backlash" in text
    assert hashlib.sha256(csv.read_bytes()).hexdigest() in text
    assert hexcal.__version__ in text
    assert before.fit.model_name in text and after.fit.model_name in text
    # The drawn plots of both steps, the before/after figure and the pose-error map; the
    # others hold their place.
    assert text.count("data:image/png;base64,") == 2 * len(DRAWN) + 2
    assert '<section id="accuracy"><h2>Pose accuracy</h2>' in text
    assert "design (drawing)" in text and "noise floor" in text
    assert text.count('class="skipped"') == 2 * (len(PLOT_NAMES) - len(DRAWN))
    for png in re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", text):
        assert base64.b64decode(png).startswith(b"\x89PNG")


def test_report_has_the_before_after_section(report, session):
    _, _, text = report
    before, after, _ = session
    assert 'id="change-1-2"' in text
    assert 'id="change-1-2-figure"' in text
    line = f"held-out RMS {before.fit.cv_rms_mm * 1e3:.1f} → {after.fit.cv_rms_mm * 1e3:.1f} µm"
    assert line in text


def test_sections_have_stable_ids_in_a_fixed_order(report):
    _, _, text = report
    ids = re.findall(r'<(?:section|header|div|figure|nav)[^>]* id="([^"]+)"', text)
    expected_step = ["fit", "legs", "candidates", "where", "params"]
    for i in (1, 2):
        got = [x.removeprefix(f"step-{i}-") for x in ids if x.startswith(f"step-{i}-")]
        assert got[:5] == expected_step
        plots = [x for x in got if x.startswith("plot-")]
        assert plots == ["plot-" + n.removesuffix(".png") for n, _, _ in REPORT_PLOTS]
    top = [x for x in ids if not x.startswith("step-") and not x.startswith("change-")]
    # The pose accuracy first; the provenance at the end, before the glossary.
    assert top[:4] == ["verdict", "summary", "contents", "accuracy"]
    assert top[-2:] == ["provenance", "glossary"]
    assert ids.index("step-1") < ids.index("change-1-2") < ids.index("step-2")


def test_report_html_is_well_formed(report):
    _, _, text = report

    void = {"meta", "img", "br", "col", "hr", "input", "link", "wbr"}

    class Check(HTMLParser):
        def __init__(self):
            super().__init__()
            self.stack: list[str] = []

        def handle_starttag(self, tag, attrs):
            if tag not in void:
                self.stack.append(tag)

        def handle_endtag(self, tag):
            assert self.stack and self.stack[-1] == tag, (tag, self.stack[-5:])
            self.stack.pop()

    c = Check()
    c.feed(text)
    assert c.stack == []


def test_single_step_report_has_no_before_after(session, tmp_path):
    before, _, csv = session
    path = write_report([before], tmp_path / "r.html", {"measurements": csv}, plots=False)
    text = path.read_text(encoding="utf-8")
    assert "change-1-2" not in text
    assert 'class="verdict v-effect"' in text and '<span class="badge">backlash</span>' in text
    assert "data:image/png" not in text


def test_text_is_escaped_and_missing_inputs_reported(session, tmp_path):
    before, _, _ = session
    path = write_report(
        [before], tmp_path / "r.html", {"<robot & co>": tmp_path / "absent.json"}, plots=False
    )
    text = path.read_text(encoding="utf-8")
    assert "&lt;robot &amp; co&gt;" in text and "<robot & co>" not in text
    assert "not readable" in text


def test_flagged_parameters_are_red_with_their_note():
    rows = [
        ParamRow("gain.g1", 9000.0, 10.0, 20.0, "ppm", (-2000.0, 2000.0), "ok"),
        ParamRow("a1.x", 1.0, 0.1, 0.2, "mm", None, "not separable"),
        ParamRow("a1.y", 1.0, 0.1, 0.2, "mm", None, "ok"),
    ]
    notes = [
        "gain.g1 = 9000 ppm is outside its plausible range",
        "a1.x is not separable from a1.xy",
    ]
    text = param_rows(rows, notes)
    assert text.count('class="bad"') == 2 and text.count('class="note"') == 2
    assert "outside its plausible range" in text and "is not separable" in text
    assert "9000 ± 20" in text


def test_no_diagnosis_is_refused(tmp_path):
    with pytest.raises(ValueError, match="at least one"):
        write_report([], tmp_path / "r.html", {})


def test_report_opens_in_plain_words_before_any_statistic(report):
    """The verdict card says what the robot has (the fitted play per leg, in µm) and where the
    platform then is, before χ², ΔBIC or any other statistic; a glossary closes the page."""
    _, _, text = report
    summary = text[
        text.index('<div id="summary">') : text.index("</div>", text.index('<div id="summary">'))
    ]
    assert re.search(r"leg \d has [\d.]+ µm of play when it reverses", summary)
    assert re.search(
        r"the platform is within \d+ µm of where the controller believes it is", summary
    )
    assert "χ²" not in summary and "BIC" not in summary
    assert text.index('id="summary"') < text.index("χ²")
    glossary = text[text.index('<section id="glossary">') :]
    for term in ("held-out", "noise floor", "χ²/dof", "ΔBIC", "identifiable"):
        assert f"<dt>{term}</dt>" in glossary


def test_gain_in_words_says_which_way_the_encoder_reads():
    """gain g > 0: the true length is (1 + g)·reading, so the encoder reads short."""
    from hexcal.diagnosis.summary import _in_words

    row = ParamRow("gain.g3", 2000.0, 100.0, 196.0, "ppm", None, "")
    assert _in_words(row) == "leg 3's encoder reads 0.2 % short"
    assert _in_words(ParamRow("gain.g1", -870.0, 50.0, 98.0, "ppm", None, "")) == (
        "leg 1's encoder reads 0.087 % long"
    )
    assert _in_words(ParamRow("a3.x", 1.0, 0.1, 0.2, "mm", None, "")) is None


def test_figure_count_is_the_number_of_figures_drawn(session, tmp_path):
    before, after, _ = session
    for diags in ([before], [before, after]):
        jobs = report_mod.figure_jobs(diags, tmp_path)
        assert report_mod.figure_count(diags) == len(jobs)
        # the map, one before/after per change, each step's plots
        assert len(jobs) == 1 + (len(diags) - 1) + sum(len(plots_mod.plot_names(d)) for d in diags)


def test_the_page_is_made_for_any_width():
    """for_any_width, without a browser: a number keeps its unit and a label its number
    (non-breaking spaces), a timestamp is one unbreakable piece, and a table's cells carry
    their column's header for the phone's card layout (a two-column table keeps its rows)."""
    from hexcal.diagnosis.report_html import for_any_width

    page = for_any_width(
        "<p>leg 1 reads 22.1 µm long, Model 42 at 2026-11-28T06:48:59+00:00</p>"
        '<table><tr><th>leg</th><th class="num">RMS µm</th></tr>'
        '<tr><td>leg 2</td><td class="num">9.8</td></tr>'
        '<tr class="note"><td colspan="2">a note</td></tr></table>'
        '<table class="narrow"><tr><th>figure</th><th>value</th></tr><tr><td>a</td><td>1</td></tr>'
        "</table>"
    )
    assert "leg\u00a01 reads 22.1\u00a0µm long, Model\u00a042" in page
    assert '<time class="nowrap">2026-11-28T06:48:59+00:00</time>' in page
    assert '<table class="cards"><tr class="head">' in page
    assert '<td data-label="leg"><div class="v">leg\u00a02</div></td>' in page
    assert '<td class="num" data-label="RMS µm"><div class="v">9.8</div></td>' in page
    assert '<td colspan="2">a note</td>' in page  # a note across the row keeps no label
    assert '<table class="narrow"><tr><th>' in page and "<td>a</td>" in page
    assert page.count('<div class="tbl">') == 2
