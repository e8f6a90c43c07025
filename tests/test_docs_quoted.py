"""The outputs README.md and docs/ quote are today's: docs/quoted.py makes them again from the
shipped examples and the walkthrough's sessions (cog fills the blocks between its markers;
the walkthrough's whole outputs are files), and any difference fails here with its diff. After
a deliberate change of an output: ``python docs/quoted.py`` writes them anew."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

pytest.importorskip("cogapp")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "docs"))
import quoted


def test_every_quoted_output_is_what_hexcal_prints_today():
    drift = quoted.check()
    assert drift == [], "\n".join(drift) + "\n(python docs/quoted.py writes them anew)"


def test_the_jugglebots_quotes_tell_the_whole_chain_and_the_step():
    """The drift the issue found: the chain was quoted as gain → compliance → none with leg 1
    5.5 % off; the run adds zero_step and says 6.4 %, and its headline names the step."""
    text, out = quoted.jugglebot()
    assert [s["verdict"] for s in out["steps"]][-2:] == ["zero_step", "none"]
    headline = " ".join(quoted._headline(text).split())
    assert "zero stepped" in headline and "leg 1's encoder reads 6.4 % long" in headline
    diagnosis = (quoted.ROOT / "docs" / "diagnosis.md").read_text(encoding="utf-8")
    readme = (quoted.ROOT / "README.md").read_text(encoding="utf-8")
    assert "then `zero_step` (372 → 362 µm), then `none`" in " ".join(diagnosis.split())
    assert "up to 6.4 % off, a step in the zero of legs 1 and 2" in " ".join(readme.split())
