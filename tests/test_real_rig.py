"""docs/real-rig.md, followed on the mock rig: its command blocks run in order, in an empty
directory with only the installed hexcal (the console script beside this Python), each block's
`<!-- mock: ... -->` line standing in for it where the doc gives one, and every "You should see"
line found in what the commands print (`…` stands for what differs from rig to rig)."""

from __future__ import annotations

import os
import re
import shlex
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

DOC = Path(__file__).parents[1] / "docs" / "real-rig.md"
HEXCAL = Path(sys.executable).with_name("hexcal")
BLOCK = re.compile(r"```(\w+)\n(.*?)```(?:\n<!-- mock: (.*?) -->)?", re.S)


@dataclass
class Step:
    commands: list[str]
    expected: list[str] = field(default_factory=list)


def steps(text: str) -> list[Step]:
    """The doc's bash blocks (or their mock lines), each with the text block that follows it
    under "You should see" (before the next bash block)."""
    out: list[Step] = []
    for m in BLOCK.finditer(text):
        kind, body, mock = m.group(1), m.group(2), m.group(3)
        if kind == "bash":
            lines = [ln.strip() for ln in body.splitlines() if ln.strip()]
            out.append(Step([mock] if mock else lines))
        elif kind == "text" and out and "You should see" in text[: m.start()][-200:]:
            out[-1].expected += [ln.strip() for ln in body.splitlines() if ln.strip()]
    return out


def found(expected: str, output: str) -> bool:
    """Whether the line ``expected`` is in ``output``: its pieces between "…" in order,
    whitespace (and line wrapping) ignored."""
    flat = " ".join(output.split())
    at = 0
    for piece in (" ".join(p.split()) for p in expected.split("…")):
        if not piece:
            continue
        at = flat.find(piece, at)
        if at < 0:
            return False
        at += len(piece)
    return True


def test_the_doc_is_read_as_the_test_reads_it():
    s = steps(DOC.read_text(encoding="utf-8"))
    assert len(s) >= 9 and all(step.commands for step in s)
    assert all(c.startswith(("hexcal ", "cp ")) for step in s for c in step.commands)
    # Every step but the last two (which print what the next one shows) says what to expect.
    assert sum(1 for step in s if step.expected) >= 8
    assert found("reading … mm done", "reading 59.19 mm\n  done")
    assert not found("a … c", "c then a")


@pytest.mark.skipif(not HEXCAL.exists(), reason=f"no installed console script at {HEXCAL}")
def test_the_real_rig_page_on_the_mock_rig(tmp_path):
    env = {k: v for k, v in os.environ.items() if not k.startswith("HEXCAL_")}
    env["HEXCAL_SESSIONS"] = str(tmp_path / "sessions")
    env["OPENBLAS_NUM_THREADS"] = "1"
    for step in steps(DOC.read_text(encoding="utf-8")):
        printed = ""
        for command in step.commands:
            argv = shlex.split(command)
            if argv[0] == "cp":
                shutil.copy(tmp_path / argv[1], tmp_path / argv[2])
                continue
            done = subprocess.run(
                [str(HEXCAL), *argv[1:]],
                cwd=tmp_path,
                env=env,
                capture_output=True,
                text=True,
                timeout=600,
            )
            assert done.returncode == 0, (command, done.stdout[-2000:], done.stderr[-2000:])
            printed += done.stdout + done.stderr
        missing = [line for line in step.expected if not found(line, printed)]
        assert not missing, (step.commands, missing, printed[-3000:])
