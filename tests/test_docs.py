"""The README is a front page and the rest lives in docs/: every relative link in them must
lead to a file that exists (a moved section must not leave a dead link behind)."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LINK = re.compile(r"\]\(([^)\s#]+)(?:#[^)]*)?\)")


def test_every_relative_link_in_the_readme_and_docs_resolves():
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
    dead = [
        f"{page.relative_to(ROOT)}: {target}"
        for page in pages
        for target in LINK.findall(page.read_text(encoding="utf-8"))
        if not target.startswith(("http://", "https://", "mailto:"))
        and not (page.parent / target).exists()
    ]
    assert len(pages) >= 8 and not dead, dead


def test_the_readme_is_a_front_page():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 250
    for page in ("guide", "diagnosis", "devices", "methods", "formats", "performance"):
        assert f"(docs/{page}.md)" in text


#: The library's folders that are stages of the flow: their modules are named one by one.
STAGE_FOLDERS = ("io", "model", "estimate", "acquire", "procedure", "sim", "app")


def test_the_readme_layout_names_every_module():
    """The layout (docs/layout.md, linked from the README) matches the tree: every module of the
    library, the drivers and the mocks is named there."""
    assert "(docs/layout.md)" in (ROOT / "README.md").read_text(encoding="utf-8")
    layout = (ROOT / "docs" / "layout.md").read_text(encoding="utf-8")
    missing = [
        str(path.relative_to(ROOT))
        for folder in ("src/hexcal", "drivers", "mock_hw")
        for path in sorted((ROOT / folder).rglob("*.py"))
        if path.name != "__init__.py"
        and path.name not in layout
        # a folder below a stage may be named as a whole (solvers/, commands/, diagnosis/...)
        and not (path.parent.name not in STAGE_FOLDERS and f"{path.parent.name}/" in layout)
    ]
    assert not missing, missing
    for stage in STAGE_FOLDERS:
        assert f"\n  {stage}/" in layout, f"the stage folder {stage}/ is not in the layout"
