"""``benchmarks/count_placement_error.py``: counted fruit against their nearest true fruit, the offset along the
capture's axes (y: the depth from the rig), on a count folder laid out as ``agrinerf-count --truth`` writes it."""

from __future__ import annotations

import csv
import json
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from count_placement_error import PlacementArgs, main, offsets  # noqa: E402

TRUTH = np.array([[0.0, 2.0, 1.0], [0.5, 2.0, 1.0], [1.0, 2.0, 1.0], [3.0, 2.0, 1.0]])


def _count(folder: Path, raw: Path, counted: np.ndarray) -> None:
    (raw / "truth").mkdir(parents=True)
    fruits = [{"id": i, "center": c.tolist(), "radii": [0.03] * 3} for i, c in enumerate(TRUTH)]  # as agrinerf-synth
    (raw / "truth" / "fruits.json").write_text(json.dumps(fruits))
    folder.mkdir()
    (folder / "count.json").write_text(json.dumps({"truth": str(raw)}))
    with open(folder / "fruits.csv", "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["id", "x_capture", "y_capture", "z_capture"])
        writer.writerows([[i, *c] for i, c in enumerate(counted)])


def test_the_offsets_are_split_along_the_depth_and_across_it(tmp_path: Path) -> None:
    counted = TRUTH[:3] + np.array([[0.0, 0.06, 0.01], [0.0, -0.06, -0.01], [0.0, 0.0, 0.0]])
    counted = np.vstack([counted, [[10.0, 2.0, 1.0]]])  # no true fruit near: not paired
    off = offsets(counted, TRUTH, 0.15)
    assert off.shape == (3, 3) and np.allclose(off[:, 0], 0.0)
    _count(tmp_path / "c", tmp_path / "raw", counted)
    main(PlacementArgs(counts=[f"run={tmp_path / 'c'}"], out=tmp_path / "p.md"))
    row = (tmp_path / "p.md").read_text().splitlines()[2]
    cells = [c.strip() for c in row.strip("|").split("|")]
    assert cells[:4] == ["run", "4", "3", "0.061"]  # the median of 0.0608, 0.0608 and 0
    assert cells[5] == f"0.000 / {np.std([0.06, -0.06, 0.0]):.3f} / {np.std([0.01, -0.01, 0.0]):.3f}"


def test_a_count_without_capture_columns_is_named(tmp_path: Path) -> None:
    folder = tmp_path / "c"
    folder.mkdir()
    (folder / "fruits.csv").write_text("id,x,y,z\n0,1,2,3\n")
    with pytest.raises(ValueError, match="fruits.csv: no capture-frame columns"):
        main(PlacementArgs(counts=[f"run={folder}"], out=tmp_path / "p.md"))
