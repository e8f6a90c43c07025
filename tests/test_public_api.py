"""The curated public API: every name in ``hexcal.__all__`` resolves and is documented, and the
example in docs/library.md runs."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import hexcal

ROOT = Path(__file__).resolve().parents[1]


def test_every_public_name_resolves_and_has_a_docstring():
    names = [n for n in hexcal.__all__ if n != "__version__"]
    assert {"calibrate", "diagnose", "read_measurements", "Robot"} <= set(names)
    undocumented = [n for n in names if not (getattr(hexcal, n).__doc__ or "").strip()]
    assert not undocumented, undocumented
    assert set(names) <= set(dir(hexcal))
    assert set(names) == set(hexcal._HOMES)  # __all__ and the lazy table agree


def test_import_hexcal_loads_no_numerical_stack():
    """The names load on first use: a bare ``import hexcal`` imports neither numpy nor scipy."""
    code = "import sys, hexcal; print('numpy' in sys.modules, 'scipy' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def test_the_library_example_in_the_docs_runs():
    text = (ROOT / "docs" / "library.md").read_text(encoding="utf-8")
    (code,) = re.findall(r"```python\n(.*?)```", text, re.S)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, env=env
    )
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert lines[0].startswith("Model 42: leg-length RMS")
    assert lines[1].startswith("verdict: none")
    assert lines[2].startswith("pose error (in-sample):")


def test_the_command_lines_help_loads_no_numerical_stack():
    """``hexcal --help`` and the parser every command builds import neither numpy nor scipy
    (their import is most of a calibration's start-up; docs/performance.md)."""
    code = (
        "import sys\n"
        "from hexcal.app.cli import build_parser\n"
        "build_parser().format_help()\n"
        "print('numpy' in sys.modules, 'scipy' in sys.modules, 'matplotlib' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False", "False"]
