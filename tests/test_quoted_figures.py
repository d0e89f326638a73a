"""Every number that README.md, docs/*.md and results/*/README.md quote as a result is registered with the file it
comes from (and equals it), or registered as a setting or as unchecked with a reason (issues #51, #61)."""

import json
import re
import shutil

import pytest
from helpers import figures

DOCS = figures.docs()
PLANTED = ["PSNR 27.4", "mAP50 61.3", "F1 0.9", "| 24.1 |", "`0.93`"]
"""Figures that read as results, planted into a copy of every doc, each on a line of its own (issue #61)."""


@pytest.fixture(scope="module")
def registry():
    return figures.load()


def _copy(tmp_path):
    """A copy of the docs under ``tmp_path``, beside links to every other file under results/."""
    for doc in DOCS:
        (tmp_path / doc).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy(figures.ROOT / doc, tmp_path / doc)
    for data in (figures.ROOT / "results").rglob("*"):
        target = tmp_path / data.relative_to(figures.ROOT)
        if data.is_file() and not target.exists():
            target.parent.mkdir(parents=True, exist_ok=True)
            target.symlink_to(data)


def test_every_registered_figure_is_quoted_as_its_file_gives_it(registry):
    assert figures.check(registry) == []


def test_every_quoted_number_is_in_its_file_and_registered_as_often_as_quoted(registry):
    assert figures.check_quoted(registry) == []


def test_every_source_records_command_commit_machine_and_date(registry):
    problems = [p for name, source in registry["sources"].items() for p in figures.provenance(name, source)]
    assert problems == []


def test_every_source_file_is_committed_under_its_record_folder(registry):
    assert [f for entry in registry["figures"] for f in figures.outside(entry, registry["sources"])] == []


def test_a_figure_read_outside_its_record_folder_fails(registry):
    """A top-level record's folder is its own, not results/: an entry may not read another folder's file."""
    entry = next(e for e in registry["figures"] if e["values"][0].get("csv"))
    source = registry["sources"][entry["source"]]
    folder = source["record"].rsplit("/", 1)[0]
    other = next(p for p in sorted((figures.ROOT / "results").glob("*/results.csv")) if folder not in p.as_posix())
    moved = json.loads(json.dumps(entry))
    moved["values"][0]["csv"] = other.relative_to(figures.ROOT).as_posix()
    problems = figures.check({**registry, "figures": [moved]})
    assert len(problems) == 1 and "outside its record's folder" in problems[0], problems


def test_no_figure_in_the_docs_is_unregistered(registry):
    assert figures.unregistered(registry, DOCS) == []


def test_the_figures_that_read_as_results_are_found():
    text = "PSNR 27.4; mAP50 61.3 and F1 0.9\n| run | 24.1 |\n`0.93`, +3% at 0.22x, -7 C in 12 s; 35-43%; IoU 0"
    assert [n for n, _ in figures.figures_in(text)] == ["27.4", "61.3", "0.9", "24.1", "0.93", "3", "0.22", "7"] + [
        "12",
        "35",
        "43",
        "0",
    ]
    settings = (
        "2026-12-04 at 11:35, 96x72, 128^3, torch 2.6.0, `--steps 10`, agrinerf-lite@1000, mAP50-95, 3D, 16 views"
    )
    assert figures.figures_in(settings) == []


def test_each_planted_figure_fails_in_every_doc(registry, tmp_path):
    """Each planted figure is one more occurrence than its doc registers, so each is reported, in every doc."""
    _copy(tmp_path)
    for doc in DOCS:
        path = tmp_path / doc
        original = path.read_text()
        path.write_text(original + "\n\n" + "\n\n".join(PLANTED) + "\n")
        found = figures.unregistered(registry, [doc], tmp_path)
        numbers = sorted(re.search(r": '([\d.]+)'", f).group(1) for f in found)
        assert numbers == ["0.9", "0.93", "24.1", "27.4", "61.3"], (doc, found)
        path.write_text(original)


def test_a_planted_stale_figure_fails(registry, tmp_path):
    _copy(tmp_path)
    quoted = figures.render(next(e for e in registry["figures"] if e["doc"] == "README.md"), tmp_path)
    stale = re.sub(r"\d(?=\D*$)", lambda m: str((int(m.group(0)) + 1) % 10), quoted, count=1)
    readme = tmp_path / "README.md"
    readme.write_text(readme.read_text().replace(quoted, stale))
    problems = [p for p in figures.check(registry, tmp_path) if p.startswith("README.md")]
    assert len(problems) == 1 and repr(quoted) in problems[0]
    assert figures.unregistered(registry, ["README.md"], tmp_path) != []


def test_a_number_its_file_does_not_hold_fails(registry):
    doc, by_file = next(iter(registry["quoted"].items()))
    name, numbers = next(iter(by_file.items()))
    wrong = {doc: {name: [numbers[0] + "7"]}}
    problems = figures.check_quoted({**registry, "quoted": wrong, "settings": {}, "unchecked": {}})
    assert any(f"is not in {name}" in p for p in problems), problems
