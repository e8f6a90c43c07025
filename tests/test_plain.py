"""Plain words first (hexcal.app.plain): calibrate, diagnose and validate open with the verdict in
words and the pose error against what the instruments allow, before any statistic; --verbose
shows what the short form leaves out."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from hexcal.app.cli import main
from hexcal.app.plain import STATISTICS

EXAMPLES = Path(__file__).parents[1] / "examples"
#: Terms of the statistics, which must not come before the plain words.
STATS = re.compile(r"χ²|chi²|ΔBIC|Mahalanobis|eq\. 19|degrees of freedom|Type II")


def _inputs(name: str) -> list[str]:
    d = EXAMPLES / name
    return [
        str(d / "measurements.csv"),
        "--robot",
        str(d / "robot.json"),
        "--instruments",
        str(d / "instruments.json"),
    ]


def _opening(text: str) -> str:
    """What comes before the statistics' heading (which must be there), its lines joined."""
    assert f"\n{STATISTICS}\n" in text, text[:500]
    head = text.split(f"\n{STATISTICS}\n")[0]
    assert not STATS.search(head), head
    return " ".join(head.split())


@pytest.fixture(scope="module")
def backlash_auto(tmp_path_factory) -> tuple[str, Path]:
    out = tmp_path_factory.mktemp("plain") / "calibrated.json"
    import contextlib
    import io

    buf = io.StringIO()
    with contextlib.redirect_stdout(buf):
        assert main(["diagnose", *_inputs("left-hand-backlash"), "--auto", "--out", str(out)]) == 0
    return buf.getvalue(), out


def test_diagnose_opens_with_the_verdict_and_the_error_falling_to_the_floor(backlash_auto):
    head = _opening(backlash_auto[0])
    assert "play when it reverses" in head  # the effect found, in words
    assert "Nothing else is missing" in head
    m = re.search(r"Pose error \(position RMS, held-out poses\): the drawing ([\d.]+) mm → ", head)
    assert m, head
    assert "Model 42 + backlash" in head and "the instruments allow" in head
    ratio = float(re.search(r"\(([\d.]+)× that now\)", head).group(1))
    assert ratio <= 1.15  # the example's error falls to the floor (tested in test_examples too)
    # The earlier step of the chain is left to --verbose.
    assert "earlier step(s) in full: --verbose" in backlash_auto[0]


def test_diagnose_verbose_shows_every_step(capsys):
    assert main(["diagnose", *_inputs("left-hand-backlash"), "--auto", "--verbose"]) == 0
    text = capsys.readouterr().out
    assert text.count("hexcal diagnose: Model 42") == 2  # Model 42, then + backlash
    assert "--verbose" not in text


def test_a_clean_example_says_nothing_is_missing(capsys):
    assert main(["diagnose", *_inputs("left-hand-sim")]) == 0
    text = capsys.readouterr().out
    head = _opening(text)
    # Nothing was ever missing: no "else" (that is for after an effect was found or added).
    assert head.startswith("Nothing is missing: the model is at the noise floor"), head
    assert "Nothing else" not in head and "the instruments allow" in head
    # The ranked table carries its legend in the terminal too, right under it.
    table = text.split("missing effects, ranked:")[1].split("verdict:")[0]
    legend = " ".join(table.split("legend:")[1].split())
    for column in ("score Δχ²:", "ΔBIC:", "explains:", "held-out after:", "—:"):
        assert column in legend, legend


def test_calibrate_opens_with_what_to_do_and_hides_the_correlations(capsys):
    assert main(["calibrate", *_inputs("left-hand-backlash")]) == 0
    text = capsys.readouterr().out
    head = _opening(text)
    assert "still misses something" in head and "hexcal diagnose" in head and "--auto" in head
    assert "Pose error (position RMS, held-out poses): the drawing" in head
    assert "strongest correlations" not in text and "--verbose lists them" in text
    assert main(["calibrate", *_inputs("left-hand-backlash"), "--verbose"]) == 0
    assert "strongest correlations" in capsys.readouterr().out


def test_calibrate_with_the_effect_is_at_the_floor(capsys):
    assert main(["calibrate", *_inputs("left-hand-backlash"), "--add", "backlash"]) == 0
    head = _opening(capsys.readouterr().out)
    assert "as good as the instruments can tell" in head


def test_validate_on_the_own_session_says_it_is_no_validation(backlash_auto, capsys):
    _, model = backlash_auto
    csv = EXAMPLES / "left-hand-backlash" / "measurements.csv"
    assert main(["validate", str(model), str(csv)]) == 0
    head = _opening(capsys.readouterr().out)
    assert head.startswith("This is not a validation")
