"""The docs name tests by path (``tests/...py`` and ``tests/...py::test_name``) as the evidence for
what they say: each named file and test must exist. The frozen lab notebook is history and keeps
the paths of its day."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = re.compile(r"(tests/[A-Za-z0-9_/]+\.py)(?:::([A-Za-z0-9_]+))?")


def _pages() -> list[Path]:
    return [ROOT / "README.md", *(p for p in (ROOT / "docs").rglob("*.md") if "notebook" not in p.parts)]


def test_every_test_the_docs_name_exists():
    missing = []
    for page in _pages():
        for path, name in REFERENCE.findall(page.read_text(encoding="utf-8")):
            target = ROOT / path
            if not target.is_file():
                missing.append(f"{page.relative_to(ROOT)}: {path}")
            elif name and not re.search(rf"^\s*(async\s+)?def {name}\b", target.read_text(encoding="utf-8"), re.M):
                missing.append(f"{page.relative_to(ROOT)}: {path}::{name}")
    assert not missing, "docs name tests that do not exist:\n" + "\n".join(missing)


def test_the_pages_name_some_tests():
    # the check above is only as good as its pattern: the pages do cite tests by path
    assert sum(len(REFERENCE.findall(p.read_text(encoding="utf-8"))) for p in _pages()) > 20
