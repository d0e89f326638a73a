"""Every measured figure README.md and docs/results.md quote equals its committed results file (issue #51)."""

import re
import shutil

import pytest
from helpers import figures

DOCS = ["README.md", "docs/results.md"]


@pytest.fixture(scope="module")
def registry():
    return figures.load()


def test_every_registered_figure_is_quoted_as_its_file_gives_it(registry):
    assert figures.check(registry) == []


def test_every_source_records_command_commit_machine_and_date(registry):
    problems = [p for name, source in registry["sources"].items() for p in figures.provenance(name, source)]
    assert problems == []


def test_every_source_file_is_committed_under_its_record_folder(registry):
    for entry in registry["figures"]:
        folder = (figures.ROOT / registry["sources"][entry["source"]]["record"]).parent.parent
        for sel in entry["values"]:
            while sel:
                path = next(sel[k] for k in ("csv", "json", "paired", "ratio") if k in sel)
                assert path.startswith("results/") and (figures.ROOT / path).is_relative_to(folder), path
                sel = sel.get("minus") or sel.get("over")


def test_no_measured_figure_in_the_docs_is_unregistered(registry):
    assert figures.unregistered(registry, DOCS) == []


def test_a_planted_stale_figure_fails(registry, tmp_path):
    for doc in DOCS:
        (tmp_path / doc).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(figures.ROOT / doc, tmp_path / doc)
    (tmp_path / "results").symlink_to(figures.ROOT / "results")
    assert figures.check(registry, tmp_path) == []
    quoted = figures.render(next(e for e in registry["figures"] if e["doc"] == "README.md"), tmp_path)
    stale = re.sub(r"\d(?=\D*$)", lambda m: str((int(m.group(0)) + 1) % 10), quoted, count=1)
    readme = tmp_path / "README.md"
    readme.write_text(readme.read_text().replace(quoted, stale))
    problems = figures.check(registry, tmp_path)
    assert len(problems) == 1 and repr(quoted) in problems[0]
    assert figures.unregistered(registry, ["README.md"], tmp_path) != []
