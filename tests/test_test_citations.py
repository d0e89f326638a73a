"""Every doc and docstring that cites a test names one that exists (issue #61): a test file by its path under tests/
or its bare name, a glob of them, or a file and one of its tests joined by ``::``."""

from __future__ import annotations

import re
from pathlib import Path
from typing import List

REPO = Path(__file__).resolve().parent.parent
CITATION = re.compile(r"(?<![\w/.-])(?:tests/)?((?:\w+/)*test_[\w*]+\.py)(?:::(\w+))?")
"""A cited test file (a path under tests/, maybe a glob) and maybe one of its tests."""
CITING = ("README.md", "pyproject.toml", "docs/**/*.md", "results/**/*.md")
CITING += tuple(f"{folder}/**/*{ext}" for folder in ("agrinerf_ns", "dataparsers", "method_configs", "benchmarks",
                                                     "scripts", "tests") for ext in (".py", ".sh", ".md"))  # fmt: skip
"""The files whose text may cite a test."""


def missing_citations(text: str, tests: Path = REPO / "tests") -> List[str]:
    """Citations in ``text`` of a test file that does not exist, or of a test its file does not define."""
    found = []
    for m in CITATION.finditer(text):
        files = [p for p in tests.rglob(m.group(1)) if p.is_file()]
        if not files:
            found.append(f"{m.group(0)}: no such file under tests/")
        elif m.group(2) and not any(
            re.search(rf"^\s*(?:def|class) {m.group(2)}\b", p.read_text(), re.M) for p in files
        ):
            found.append(f"{m.group(0)}: {m.group(1)} defines no {m.group(2)}")
    return found


def test_every_cited_test_exists():
    problems = []
    for pattern in CITING:
        for path in sorted(REPO.glob(pattern)):
            if ".venv" in path.parts or not path.is_file():
                continue
            problems += [f"{path.relative_to(REPO)}: {p}" for p in missing_citations(path.read_text(errors="replace"))]
    assert problems == []


def test_a_citation_of_a_missing_test_fails():
    here = Path(__file__).name
    cited = f"{here}::test_every_cited_test_exists"
    assert missing_citations(f"(tests/{cited})") == []
    assert missing_citations(f"`{here}`, tests/test_quoted_*.py") == []
    planted = ["tests/test_no_such_" + "file.py", "test_no_such_" + "file.py", "tests/test_nothing_" + "*.py"]
    planted.append(f"tests/{here}::test_that_is_" + "not_here")
    for text in planted:
        assert len(missing_citations(f"see ({text}): it shows so")) == 1, text
