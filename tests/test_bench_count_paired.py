"""benchmarks/count_paired.py: two count tables paired capture by capture, the difference with its interval."""

import csv
from pathlib import Path

import pytest
from helpers.bench_script import load_bench_script

FIELDS = ["scene", "lighting", "seed", "label", "f1", "count_error"]


def _table(path: Path, rows) -> Path:
    with open(path, "w", newline="") as handle:
        writer = csv.DictWriter(handle, FIELDS)
        writer.writeheader()
        writer.writerows(dict(zip(FIELDS, row, strict=True)) for row in rows)
    return path


def test_captures_are_paired_and_the_difference_has_an_interval(tmp_path: Path) -> None:
    script = load_bench_script("count_paired")
    a = _table(tmp_path / "a.csv", [("garden", "bright", "100", "run", 0.5, -0.3), ("orchard", "bright", "100", "run", 0.4, -0.2),
                                    ("garden", "dusk", "100", "run", 0.3, -0.5), ("garden", "bright", "100", "oracle", 0.9, 0.0),
                                    ("garden", "bright", "101", "run", 0.6, 0.1)])  # fmt: skip
    b = _table(tmp_path / "b.csv", [("garden", "bright", "100", "bodies", 0.7, -0.1), ("orchard", "bright", "100", "bodies", 0.5, 0.0),
                                    ("garden", "dusk", "100", "bodies", 0.2, -0.4)])  # fmt: skip
    out = tmp_path / "paired.md"
    text = script.main(
        script.PairedArgs(a=f"trained={a}:run", b=f"bodies={b}", out=out, measures=("f1", "count_error"))
    )
    rows = {line.split(" | ")[0].strip("| "): line.split(" | ") for line in text.splitlines() if line.startswith("| ")}
    bright = rows["bright"]
    assert bright[1] == "2" and bright[2:4] == ["0.45", "0.60"] and bright[4].startswith("+0.15 [+0.10, +0.20]")
    assert rows["dusk"][4].startswith("-0.10 [-0.10, -0.10]")
    assert rows["all"][1] == "3"
    assert "garden:bright:101" in text  # held by one table only
    assert out.read_text() == text
    with pytest.raises(ValueError, match="two rows of"):
        script.main(script.PairedArgs(a=f"all={a}", b=f"bodies={b}", out=out))
    with pytest.raises(ValueError, match="no rows labelled 'nothing'"):
        script.main(script.PairedArgs(a=f"x={a}:nothing", b=f"bodies={b}", out=out))
