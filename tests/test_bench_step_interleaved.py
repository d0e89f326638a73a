"""benchmarks/bench_step_interleaved.py: every method's real Nerfstudio pipeline steps in turn, table and CSV written."""

from __future__ import annotations

import csv
from pathlib import Path

from helpers.bench_script import load_bench_script
from helpers.model_scene import write_model_scene


def _load():
    return load_bench_script("bench_step_interleaved")


def test_interleaved_steps_of_agrinerf_lite_and_tensorf(tmp_path: Path) -> None:
    bench = _load()
    data = write_model_scene(tmp_path / "scene", views=6)
    args = bench.Args(data=data, out=tmp_path / "out", methods=("agrinerf-lite", "tensorf"), steps=3, warmup=1,
                      rays_per_batch=128)  # fmt: skip
    bench.main(args)
    with open(tmp_path / "out" / "step_speed.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [(r["round"], r["method"]) for r in rows] == [
        ("0", "tensorf"),
        ("0", "agrinerf-lite"),
        ("1", "agrinerf-lite"),
        ("1", "tensorf"),
        ("2", "tensorf"),
        ("2", "agrinerf-lite"),
    ]  # fmt: skip  (round 0 of the timed ones is the second overall: its order is rotated)
    assert all(float(r["seconds"]) > 0 for r in rows)
    table = (tmp_path / "out" / "step_speed.md").read_text()
    assert "| AgriNeRF-lite |" in table and "| TensoRF |" in table and "Command:" in table
    assert "| 1.000 |" in table  # the first method's ratio to itself
