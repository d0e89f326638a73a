"""``agrinerf-count --path bodies``: fruit counted from the thermal bodies a dataset holds, with no run; its outputs
are the views path's (fruits.csv, fruits.ply, fruit_map.png, count.json), and a dataset without bodies is named."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from agrinerf_ns.count.cli import CountArgs, main
from agrinerf_ns.dataset_format import FRUIT_BODIES, TRANSFORMS

FRUIT = np.array([[0.0, 2.0, 1.0], [0.3, 2.0, 1.1], [0.6, 2.1, 0.9]])


def _dataset(root: Path, rng: np.random.Generator) -> Path:
    """Six cameras along x; every fruit sighted from each, scattered by 5 mm, plus one lone false sighting."""
    frames, sightings = [], []
    for k, x in enumerate(np.linspace(-0.3, 0.3, 6)):
        c2w = np.eye(4)
        c2w[:3, 3] = [x, 0.0, 0.8]
        name = f"images/{k:06d}.png"
        frames.append({"file_path": name, "transform_matrix": c2w.tolist()})
        for centre in FRUIT:
            sightings.append({"frame": name, "centre": (centre + rng.normal(0, 0.005, 3)).tolist(),
                              "diameter": 0.07, "temperature": 18.0})  # fmt: skip
    sightings.append({"frame": frames[0]["file_path"], "centre": [2.0, 2.0, 0.2], "diameter": 0.07, "temperature": 25})
    root.mkdir()
    (root / TRANSFORMS).write_text(json.dumps({"frames": frames}))
    (root / FRUIT_BODIES).write_text(json.dumps({"sightings": sightings}))
    return root


def test_the_bodies_path_counts_a_dataset_without_a_run(tmp_path: Path) -> None:
    data = _dataset(tmp_path / "data", np.random.default_rng(0))
    result = main(CountArgs(out=tmp_path / "count", path="bodies", data=data))
    assert len(result.fruit) == len(FRUIT)  # the lone sighting (one frame) is no fruit
    counted = np.stack(sorted((f.centre for f in result.fruit), key=lambda c: c[0]))
    assert np.abs(counted - FRUIT).max() < 0.01
    assert all(f.views == 6 and f.temperature == pytest.approx(18.0) for f in result.fruit)
    report = json.loads((tmp_path / "count" / "count.json").read_text())
    assert report["path"] == "bodies" and report["fruit"] == len(FRUIT) and report["detections"] == 19
    assert report["cluster"]["merge_fraction"] == 1.2
    with open(tmp_path / "count" / "fruits.csv") as handle:
        assert len(list(csv.DictReader(handle))) == len(FRUIT)
    assert (tmp_path / "count" / "fruit_map.png").stat().st_size > 0


def test_a_dataset_without_bodies_is_named_before_any_output(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    data = _dataset(tmp_path / "data", np.random.default_rng(0))
    (data / FRUIT_BODIES).unlink()
    with pytest.raises(SystemExit) as exit_info:
        main(CountArgs(out=tmp_path / "count", path="bodies", data=data))
    assert exit_info.value.code == 2
    assert f"{data / FRUIT_BODIES}: no fruit bodies" in capsys.readouterr().out.replace("\n", "")
    assert not (tmp_path / "count").exists()
