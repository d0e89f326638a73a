"""The loss-routing benchmark's report: which runs stand for the default routing, and the spread it states."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from helpers.bench_script import load_bench_script
from PIL import Image


def _load():
    return load_bench_script("bench_loss_routing")


def _scene(root: Path, scene: str, level: float) -> None:
    images = root / scene / "data" / "images"
    images.mkdir(parents=True)
    for k in range(3):
        Image.fromarray(np.full((8, 8, 3), round(level * 255), np.uint8)).save(images / f"{k:06d}.png")


def _row(scene: str, method: str, psnr: float) -> dict:
    return {"scene": scene, "method": method, "step": "500", "psnr_clean": str(psnr), "psnr_clean_per_view": ""}


def test_default_borrows_rgb_geometry_only_where_the_low_light_rule_cannot_fire(tmp_path: Path) -> None:
    bench = _load()
    _scene(tmp_path, "orchard-dusk", 0.17)  # above the low-light level
    _scene(tmp_path, "orchard-dark", 0.012)  # below it: the default routes the thermal geometry
    rows = [
        _row(scene, f"rgb-geometry:{s}", 20.0) for scene in ("orchard-dusk", "orchard-dark") for s in bench.SETS
    ] + [_row("orchard-dark", "default:all", 21.0)]
    merged, borrowed = bench.default_rows(rows, tmp_path)
    methods = {(r["scene"], r["method"]): r["psnr_clean"] for r in merged}
    assert borrowed == ["orchard-dusk"]
    assert all(methods[("orchard-dusk", f"default:{s}")] == "20.0" for s in bench.SETS)
    # in the dark, only RGB+Events (no thermal frames) is the rgb-geometry run; the measured default run stays
    assert methods[("orchard-dark", "default:rgb-events")] == "20.0"
    assert ("orchard-dark", "default:rgb-thermal") not in methods
    assert methods[("orchard-dark", "default:all")] == "21.0"
    assert sum(1 for r in merged if (r["scene"], r["method"]) == ("orchard-dark", "default:all")) == 1


def test_without_the_scenes_nothing_is_borrowed_but_rgb_events(tmp_path: Path) -> None:
    bench = _load()
    rows = [_row("garden-dusk", f"rgb-geometry:{s}", 20.0) for s in bench.SETS]
    merged, borrowed = bench.default_rows(rows, tmp_path / "absent")
    assert borrowed == []
    assert {r["method"] for r in merged if r["method"].startswith("default:")} == {"default:rgb-events"}
