"""benchmarks/bench_step_interleaved.py: every run's real Nerfstudio pipeline steps in turn in its own worker process,
at the grids of the step it names, table and CSV written."""

from __future__ import annotations

import csv
import math
import re
from pathlib import Path

import pytest
from helpers.bench_script import load_bench_script
from helpers.model_scene import write_model_scene


def _load():
    return load_bench_script("bench_step_interleaved")


def test_interleaved_steps_of_runs_at_their_grids(tmp_path: Path) -> None:
    bench = _load()
    data = write_model_scene(tmp_path / "scene", views=6)
    this_tree = Path(__file__).resolve().parents[1]
    runs = ("agrinerf-lite", "tensorf", "here:agrinerf-lite@1000%num_fine_samples=8")
    args = bench.Args(data=data, out=tmp_path / "out", runs=runs, trees=(f"here={this_tree}",), steps=2, warmup=1,
                      rays_per_batch=128)  # fmt: skip
    bench.main(args)
    with open(tmp_path / "out" / "step_speed.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["round"], r["run"]) for r in rows] == [
        ("0", "tensorf"),
        ("0", "here:agrinerf-lite@1000%num_fine_samples=8"),
        ("0", "agrinerf-lite"),
        ("1", "here:agrinerf-lite@1000%num_fine_samples=8"),
        ("1", "agrinerf-lite"),
        ("1", "tensorf"),
    ]  # fmt: skip  (round 0 of the timed ones is the second overall: its order is rotated)
    assert all(float(r["seconds"]) > 0 for r in rows)
    table = (tmp_path / "out" / "step_speed.md").read_text()
    assert "| agrinerf-lite | AgriNeRF-lite | 0 | (32, 32, 32) |" in table and "| TensoRF |" in table
    final = re.search(
        r"\| here:agrinerf-lite@1000%num_fine_samples=8 \| AgriNeRF-lite \| 1000 \| \((\d+), (\d+), (\d+)\) \|", table
    )
    assert final is not None  # the lite preset's final grids: a 96^3 voxel budget over the fitted box
    assert math.prod(int(v) for v in final.groups()) == pytest.approx(96**3, rel=0.1)
    assert "Command:" in table and "| 1.000 |" in table  # the first run's ratio to itself


def test_unknown_methods_and_trees_are_refused() -> None:
    bench = _load()
    with pytest.raises(SystemExit, match="unknown method"):
        bench.parse_runs(("agrinerf-huge",), ())
    with pytest.raises(SystemExit, match="not in --trees"):
        bench.parse_runs(("old:agrinerf",), ("new=/tmp",))
    with pytest.raises(SystemExit, match="is not JSON"):
        bench.parse_runs(("agrinerf%event_rays_per_batch=x",), ())
    with pytest.raises(SystemExit, match="is not FIELD=VALUE"):
        bench.parse_runs(("agrinerf%event_rays_per_batch",), ())
    run = bench.parse_runs(("old:agrinerf@7000%event_rays_per_batch=0",), ("old=/tmp",))[0]
    assert run.at_step == 7000 and run.tree == Path("/tmp").resolve() and run.overrides == {"event_rays_per_batch": 0}
