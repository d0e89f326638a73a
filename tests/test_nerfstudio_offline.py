"""Stock Nerfstudio commands, with the plugin installed and no network: ns-train nerfacto, ns-render, ns-eval."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
from helpers.tiny_scene import write_tiny_scene

from agrinerf_ns.ns_commands import ns_eval, ns_render_dataset, ns_train


@pytest.mark.slow
def test_nerfacto_train_render_eval_offline(tmp_path: Path) -> None:
    data = write_tiny_scene(tmp_path / "scene", views=10, width=64, height=48)
    run = ns_train(
        "nerfacto",
        data,
        tmp_path / "outputs",
        "tiny",
        max_steps=6,
        rays_per_batch=256,
        extra_args=["--pipeline.model.eval-num-rays-per-chunk", "4096"],
    )
    config = run.config
    assert [step for step, _ in run.checkpoints()] == [5], "one checkpoint, at the last step"
    assert run.peak_rss_mb > 100 and run.wall_s > 0 and run.s_per_step > 0

    renders = ns_render_dataset(config, tmp_path / "renders", outputs=["rgb"], split="test")
    assert list(renders.rglob("*.jpg")) or list(renders.rglob("*.png")), "ns-render wrote images"

    results = ns_eval(config, tmp_path / "metrics.json")
    assert math.isfinite(results["psnr"]) and results["psnr"] > 5.0
    assert "lpips" in results  # NaN offline without cached AlexNet weights, a real value with them
