"""The documentation stays true: docs/design.md's module map names every module, and the README
points to it."""

from __future__ import annotations

import re

from cli_tools import PACKAGES, ROOT, package_modules

DESIGN = ROOT / "docs" / "design.md"
ROW = re.compile(r"^\| `([\w/]+\.py)` \| (.*) \|$")


def module_map(text: str) -> dict[str, str]:
    """``{path: what it is for}`` from the "## Module map" section of a Markdown page."""
    section = text.split("\n## Module map", 1)[1].split("\n## ", 1)[0]
    rows = [ROW.match(line) for line in section.splitlines()]
    return {m.group(1): m.group(2).strip() for m in rows if m}


def test_the_module_map_lists_every_module_and_nothing_else():
    listed = module_map(DESIGN.read_text())
    actual = {str(path.relative_to(ROOT)) for path in package_modules().values()}
    missing, extra = sorted(actual - set(listed)), sorted(set(listed) - actual)
    assert not missing, f"modules missing from docs/design.md's module map: {missing}"
    assert not extra, f"docs/design.md's module map lists modules that do not exist: {extra}"
    assert all(listed.values()), [path for path, job in listed.items() if not job]


def test_the_module_map_reader_sees_every_row():
    """The parser above on a two-row map (so an empty map cannot pass unnoticed)."""
    text = "# t\n## Module map\n| module | job |\n|---|---|\n| `a/b.py` | x |\n| `a/c.py` | y |\n" \
           "## Next\n| `a/d.py` | z |\n"
    assert module_map(text) == {"a/b.py": "x", "a/c.py": "y"}


def test_readme_points_to_the_design_page_and_lists_the_packages():
    readme = (ROOT / "README.md").read_text()
    assert "docs/design.md" in readme and DESIGN.exists()
    assert "DESIGN.md" not in readme.replace("docs/design.md", "")
    table = re.findall(r"^\| `(\w+)` \|", readme, flags=re.MULTILINE)
    assert table[: len(PACKAGES)] == list(PACKAGES), table
