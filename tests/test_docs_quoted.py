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


def test_the_jugglebots_quotes_tell_the_whole_chain():
    """The drift the issue found: the chain was quoted as gain → compliance → none while the
    run named more. The docs' chain names every verdict of today's run in its order, the
    README's worst scale is today's, and a zero step is said exactly when the chain names
    one (today, after the explorer's bending curve: leg 2's)."""
    text, out = quoted.jugglebot()
    verdicts = [s["verdict"] for s in out["steps"]]
    assert verdicts[-1] == "none"
    diagnosis = " ".join((quoted.ROOT / "docs" / "diagnosis.md").read_text("utf-8").split())
    readme = " ".join((quoted.ROOT / "README.md").read_text(encoding="utf-8").split())
    chain = diagnosis[diagnosis.index("**The verdict chain:**") :][:600]
    at = [chain.index(f"`{v}`") for v in verdicts]
    assert at == sorted(at), (verdicts, chain)
    assert f"up to {quoted.jugglebot_worst()} off" in readme
    stepped = "zero_step" in verdicts
    assert ("a step in the zero of" in readme) == stepped
    headline = " ".join(quoted._headline(text).split())
    assert ("zero stepped" in headline) == stepped
