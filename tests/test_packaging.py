"""Every package under src/hexcal is listed in pyproject.toml, so a non-editable install (what CI
tests) ships it."""

from __future__ import annotations

from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_all_subpackages_are_in_the_wheel():
    tomllib = pytest.importorskip("tomllib")
    if not (ROOT / "pyproject.toml").exists():
        pytest.skip("not running from the repository")
    cfg = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    listed = set(cfg["packages"])
    found = {
        "hexcal" + "".join(f".{p}" for p in init.parent.relative_to(ROOT / "src" / "hexcal").parts)
        for init in (ROOT / "src" / "hexcal").rglob("__init__.py")
    }
    assert found <= listed, sorted(found - listed)
