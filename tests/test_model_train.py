"""AgriNeRF through the real Nerfstudio trainer on a tiny tri-modal scene (CPU): training lowers the loss, a
checkpoint reloads through `eval_setup` (as ns-eval / ns-render do) with the same eval metrics, and a resume after
an upsampling step continues at the upsampled grid size."""

from __future__ import annotations

import csv
import json
import os
import subprocess
from pathlib import Path
from typing import Dict

import numpy as np
import pytest
import torch
from helpers.bench_script import load_bench_script
from helpers.model_scene import tiny_trainer_config, write_model_scene
from nerfstudio.utils.eval_utils import eval_setup

from agrinerf_ns.model.model import AgriNeRFModel

pytestmark = pytest.mark.slow


def _data_loss(model: AgriNeRFModel, ray_bundle, batch) -> float:
    """Sum of the unweighted data terms on a fixed batch (train mode, fixed sampling seed)."""
    model.train()
    torch.manual_seed(0)
    with torch.no_grad():
        outputs = model(ray_bundle.to(model.device))
        terms = model.get_metrics_dict(outputs, batch)
    return sum(float(v) for k, v in terms.items() if k.endswith("_loss"))


@pytest.fixture(scope="module")
def trained(tmp_path_factory) -> Dict:
    """20 steps of the registered agrinerf-lite config (shrunk) on the tiny scene, through Trainer.train()."""
    root = tmp_path_factory.mktemp("agrinerf_train")
    data = write_model_scene(root / "scene")
    config = tiny_trainer_config(data, root / "outputs", max_num_iterations=20, occupancy_update_iters=(15,))
    config.set_timestamp()
    torch.manual_seed(42)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    ray_bundle, batch = trainer.pipeline.datamanager.next_train(0)
    before = _data_loss(trainer.pipeline.model, ray_bundle, batch)
    trainer.train()
    after = _data_loss(trainer.pipeline.model, ray_bundle, batch)
    config.save_config()
    trainer.pipeline.eval()
    metrics = trainer.pipeline.get_average_eval_image_metrics()
    return dict(config=config, trainer=trainer, before=before, after=after, metrics=metrics, root=root)


def test_twenty_trainer_steps_lower_the_loss(trained: Dict) -> None:
    model = trained["trainer"].pipeline.model
    assert isinstance(model, AgriNeRFModel) and model.plan.modalities == ("rgb", "thermal", "events")
    assert trained["after"] < 0.9 * trained["before"], (trained["before"], trained["after"])  # 0.187 -> 0.159 seen
    assert {"psnr", "ssim", "lpips", "thermal_psnr", "thermal_ssim"} <= set(trained["metrics"])
    assert 0.0 < model.field.occupancy.float().mean().item() <= 1.0


def test_checkpoint_round_trip_reproduces_eval_metrics(trained: Dict) -> None:
    config_path = trained["config"].get_base_dir() / "config.yml"
    _, pipeline, checkpoint, step = eval_setup(config_path, test_mode="test")
    assert checkpoint.exists() and step == 19
    reloaded = pipeline.get_average_eval_image_metrics()
    for key in ("psnr", "ssim", "thermal_psnr", "thermal_ssim"):
        assert reloaded[key] == pytest.approx(trained["metrics"][key], abs=1e-4), key
    original = trained["trainer"].pipeline.model.field.occupancy
    assert torch.equal(pipeline.model.field.occupancy.cpu(), original.cpu())
    assert pipeline.model.field.occupancy_all == bool(original.all())  # the pruning cache follows the loaded grid


def test_resume_after_upsampling_continues_at_the_upsampled_size(tmp_path: Path) -> None:
    data = write_model_scene(tmp_path / "scene", views=6)
    first = tiny_trainer_config(data, tmp_path / "outputs", max_num_iterations=6, rays=64, upsampling_iters=(3,))
    first.set_timestamp()
    torch.manual_seed(0)
    trainer = first.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    assert trainer.pipeline.model.field.density_encoding.resolution == (24, 24, 24)

    # Nerfstudio runs max_num_iterations more steps after a resume: 6-9, before the box fit at step 10 reshapes the grid
    second = tiny_trainer_config(data, tmp_path / "outputs", max_num_iterations=4, rays=64, upsampling_iters=(3,))
    second.timestamp = first.timestamp + "-resumed"
    second.load_dir = trainer.checkpoint_dir
    resumed = second.setup(local_rank=0, world_size=1)
    resumed.setup()  # loads step 5: the volumes take the checkpoint's sizes, then the optimizers are re-pointed
    model = resumed.pipeline.model
    assert {v.resolution for v in model.field.volumes().values()} == {(24, 24, 24)}
    groups = model.get_param_groups()
    for name, optimizer in resumed.optimizers.optimizers.items():
        params = optimizer.param_groups[0]["params"]
        assert [id(p) for p in params] == [id(p) for p in groups[name]]
        for p in params:  # the checkpoint's Adam moments are attached to the live, upsampled Parameters
            assert optimizer.state[p]["exp_avg"].shape == p.shape
    plane = model.field.density_encoding.plane_table
    saved = plane.detach().clone()
    resumed.train()  # steps 6-9
    assert model.field.density_encoding.plane_table.shape == (3 * 24 * 24, 4)
    assert not torch.equal(model.field.density_encoding.plane_table.detach(), saved)  # the grid keeps learning


def test_ns_eval_and_ns_render_load_the_checkpoint(trained: Dict, tmp_path: Path) -> None:
    """The real commands: `ns-eval` reports the training-time metrics, `ns-render dataset` renders the thermal output."""
    config_path = trained["config"].get_base_dir() / "config.yml"
    env = {**os.environ, "PYTHONWARNINGS": "ignore"}
    out_json = tmp_path / "eval.json"
    subprocess.run(
        ["ns-eval", "--load-config", str(config_path), "--output-path", str(out_json)], check=True, env=env, timeout=600
    )
    results = json.loads(out_json.read_text())["results"]
    assert results["psnr"] == pytest.approx(trained["metrics"]["psnr"], abs=1e-3)
    assert results["thermal_psnr"] == pytest.approx(trained["metrics"]["thermal_psnr"], abs=1e-3)
    renders = tmp_path / "renders"
    cmd = ["ns-render", "dataset", "--load-config", str(config_path), "--output-path", str(renders)]
    cmd += ["--split", "test", "--rendered-output-names", "thermal", "rgb"]
    subprocess.run(cmd, check=True, env=env, timeout=600)
    thermal = sorted(p for p in renders.rglob("*") if p.is_file() and "thermal" in str(p.relative_to(renders)))
    rgb = sorted(p for p in renders.rglob("*") if p.is_file() and "rgb" in str(p.relative_to(renders)))
    assert thermal and rgb and len(thermal) == len(rgb)


def test_render_chunk_benchmark_renders_the_same_image_at_every_chunk_size(trained: Dict, tmp_path: Path) -> None:
    """benchmarks/bench_render_chunks.py: one process per chunk size, the renders agree, the table is written."""
    bench = load_bench_script("bench_render_chunks")
    config_path = trained["config"].get_base_dir() / "config.yml"
    args = bench.Args(config=config_path, out=tmp_path / "out", chunks=(4096, 100), views=1, rounds=1)
    bench.main(args)
    with open(tmp_path / "out" / "render_chunks.csv") as handle:
        rows = list(csv.DictReader(handle))
    assert [int(r["chunk"]) for r in rows] == [4096, 100]
    assert all(float(r["seconds"]) > 0 and float(r["peak_mib"]) >= float(r["loaded_mib"]) > 0 for r in rows)
    assert all(int(r["pixels"]) == 64 * 48 for r in rows)
    assert all(float(r["max_abs_diff"]) < 1e-4 for r in rows), rows  # 100 does not divide 3072: a ragged last chunk
    with np.load(rows[1]["npz"]) as renders:
        assert {"0_rgb", "0_thermal"} <= set(renders.files)
    table = (tmp_path / "out" / "render_chunks.md").read_text()
    assert "| 4096 |" in table and "| 100 |" in table and "| 1.000 |" in table
