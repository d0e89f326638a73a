"""The fruit head: fruit masks reach the batch (and bad ones are refused before training), the head trains on a tiny
scene to a rendered mask that overlaps the true fruit, and a dataset without masks builds no head."""

from __future__ import annotations

import json
import random
from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.fruit_masks import add_fruit_masks, cap_mask
from helpers.model_scene import tiny_trainer_config, write_model_scene
from PIL import Image

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataError, AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.agrinerf_dataset import AgriNeRFDataset
from agrinerf_ns.model.fruit_head import fruit_depth, fruit_iou, fruit_loss


def test_masks_reach_the_batch_with_unknown_pixels_apart(tmp_path: Path) -> None:
    data = add_fruit_masks(write_model_scene(tmp_path / "scene", views=6, modalities=("rgb",)))
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    assert len(outputs.metadata["fruit_mask_filenames"]) == len(outputs.image_filenames)
    item = AgriNeRFDataset(outputs)[0]
    index = int(Path(outputs.image_filenames[0]).stem.split("_")[-1])
    mask = cap_mask(index, 6, 64, 48)
    assert item["fruit"].shape == (48, 64, 1) and item["fruit_known"].shape == (48, 64, 1)
    np.testing.assert_array_equal(item["fruit"][..., 0].numpy(), (mask == 255).astype(np.float32))
    np.testing.assert_array_equal(item["fruit_known"][..., 0].numpy(), (mask != 128).astype(np.float32))
    assert 0 < int((mask == 255).sum()) and 0 < int((mask == 128).sum())


def test_a_missing_or_wrongly_sized_mask_is_refused_before_training(tmp_path: Path) -> None:
    data = add_fruit_masks(write_model_scene(tmp_path / "scene", views=6, modalities=("rgb",)))
    meta = json.loads((data / "transforms.json").read_text())
    wrong = data / meta["frames"][2]["fruit_mask_file_path"]
    Image.fromarray(np.zeros((24, 32), np.uint8)).save(wrong)
    with pytest.raises(AgriNeRFDataError, match=f"{wrong.name}.*32x24.*64x48"):
        AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    Image.fromarray(np.zeros((48, 64), np.uint8)).save(wrong)
    del meta["frames"][3]["fruit_mask_file_path"]
    (data / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(AgriNeRFDataError, match=f"{meta['frames'][3]['file_path']} has no fruit_mask_file_path"):
        AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    Image.fromarray(np.zeros((48, 64, 3), np.uint8)).save(wrong)  # an RGB image is not a mask
    meta["frames"][3]["fruit_mask_file_path"] = meta["frames"][2]["fruit_mask_file_path"]
    (data / "transforms.json").write_text(json.dumps(meta))
    with pytest.raises(AgriNeRFDataError, match=f"{wrong.name}.*single-channel"):
        item = AgriNeRFDataset(AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train"))
        for i in range(len(item)):
            item[i]


def test_the_loss_reads_known_pixels_only_and_is_finite_at_the_extremes() -> None:
    rendered = torch.tensor([[0.0], [1.0], [0.5], [1.0]])
    fruit = torch.tensor([[0.0], [1.0], [1.0], [0.0]])
    known = torch.tensor([[1.0], [1.0], [0.0], [0.0]])
    loss = fruit_loss(rendered, fruit, known)
    assert torch.isfinite(loss) and float(loss) < 1e-5  # the two known pixels are right; the wrong ones are unknown
    assert float(fruit_loss(rendered, fruit, torch.ones_like(known))) > 1.0  # a confident wrong pixel costs
    assert float(fruit_loss(rendered, fruit, torch.zeros_like(known))) == 0.0
    assert fruit_iou(rendered, fruit, known) == 1.0 and fruit_iou(torch.zeros(4, 1), torch.zeros(4, 1), known) == 1.0


def test_the_fruit_depth_is_where_the_head_puts_the_fruit_and_nan_where_none() -> None:
    # one ray: a half-opaque fruit at 1.0 in front of a leaf at 2.0 (weights 0.45 / 0.55: the median depth is the
    # leaf's); the head gives the fruit 0.9 and the leaf 0.1. A second ray holds no fruit at all.
    weights = torch.tensor([[[0.45], [0.55]], [[0.5], [0.5]]])
    probability = torch.tensor([[[0.9], [0.1]], [[0.0], [0.0]]])
    distances = torch.tensor([[[1.0], [2.0]], [[1.0], [2.0]]])
    depth = fruit_depth(weights * probability, distances)
    assert depth.shape == (2, 1) and abs(float(depth[0, 0]) - (0.405 + 0.11) / 0.46) < 1e-6  # 1.12, by the fruit
    assert torch.isnan(depth[1, 0])
    tiny = fruit_depth(torch.full((1, 64, 1), 1e-30), torch.linspace(0.1, 1e4, 64).view(1, 64, 1))
    assert torch.isnan(tiny).all()  # vanishing fruit weight: no depth, never an overflow


@pytest.mark.slow
def test_the_fruit_head_trains_to_the_true_fruit_and_no_masks_build_no_head(tmp_path: Path) -> None:
    data = add_fruit_masks(write_model_scene(tmp_path / "scene", views=10, modalities=("rgb",)))
    config = tiny_trainer_config(data, tmp_path / "out", max_num_iterations=150, rays=512, modalities=("rgb",))
    config.set_timestamp()
    # every generator the training draws from, as ns-train seeds them (the machine seed): the worker's earlier tests
    # must not decide which rays are drawn
    random.seed(0)
    np.random.seed(0)
    torch.manual_seed(0)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    model = trainer.pipeline.model
    assert model.plan.has_fruit_head and "fruit_loss" in model.plan.terms and model.fruit_head is not None
    trainer.train()
    model.eval()
    dataset = trainer.pipeline.datamanager.train_dataset
    ious, inside, outside = [], [], []
    for i in range(len(dataset)):  # the training views: the tiny field's held-out views are too poor to judge by
        with torch.no_grad():
            outputs = model.get_outputs_for_camera(dataset.cameras[i : i + 1])
        rendered = outputs["fruit"]
        assert torch.isfinite(outputs["fruit_depth"]).all()  # the rendered depth where the head puts no fruit
        item = dataset[i]
        ious.append(fruit_iou(rendered, item["fruit"], item["fruit_known"]))
        known = item["fruit_known"] > 0.5
        inside.append(float(rendered[known & (item["fruit"] > 0.5)].mean()))
        outside.append(float(rendered[known & (item["fruit"] < 0.5)].mean()))
    # seen: IoU 0.31-0.34, mean probability 0.42 on the fruit against 0.19 off it after 150 steps (untrained: IoU 0,
    # the same probability on and off the fruit); 2026-12-07, AMD EPYC 2 cores, OMP_NUM_THREADS=1: IoU 0.496-0.499
    assert np.mean(ious) > 0.15 and np.mean(inside) > 1.6 * np.mean(outside), (ious, inside, outside)
    metrics = trainer.pipeline.get_average_eval_image_metrics()
    # ns-eval's fruit_iou over the held-out views (poorer than the training views on this tiny field): 0.103 with the
    # generators seeded as above, whatever ran before in the process; unseeded it had ranged 0.035-0.077 with the tests
    # a worker ran first (2026-12-07, AMD EPYC 2 cores, OMP_NUM_THREADS=1); an untrained head scores 0
    assert metrics["fruit_iou"] > 0.04, metrics["fruit_iou"]

    plain = write_model_scene(tmp_path / "plain", views=6, modalities=("rgb",))
    config = tiny_trainer_config(plain, tmp_path / "out_plain", max_num_iterations=3, rays=128, modalities=("rgb",))
    config.set_timestamp()
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    assert trainer.pipeline.model.fruit_head is None and "fruit_loss" not in trainer.pipeline.model.plan.terms
    trainer.train()
    bundle, batch = trainer.pipeline.datamanager.next_train(3)
    assert "fruit" not in trainer.pipeline.model(bundle) and "fruit" not in batch


def test_the_fruit_path_counts_the_fruit_of_a_tiny_field() -> None:
    """Four fruit on a leaf wall above warm ground, the fruit head fitted to which points are fruit: four fruit at
    their centres, of their size and temperature (the ground, warm too, is no fruit to the head)."""
    from helpers.fruit_field import FRUIT_CENTRES, assert_finds_the_known_fruit, fruit_model

    from agrinerf_ns.count.components import ComponentConfig
    from agrinerf_ns.count.field_count import FieldCountConfig, count_model
    from agrinerf_ns.count.render import WorldFrame
    from agrinerf_ns.count.volume import VolumeConfig

    model = fruit_model(steps=300, fruit_head=True)
    config = FieldCountConfig(
        source="fruit",
        volume=VolumeConfig(voxel_size=0.025, density_threshold=10.0),
        components=ComponentConfig(min_diameter=0.1, max_diameter=0.4, min_views=1),
    )
    box = np.array([[-1.0] * 3, [1.0] * 3])
    result, _, info = count_model(model, None, WorldFrame(np.eye(4)[:3], 1.0), config, box=box)
    assert info["source"] == "fruit" and len(result.fruit) == len(FRUIT_CENTRES), info
    assert_finds_the_known_fruit(result.fruit)
    for fruit in result.fruit:
        assert 0.5 <= fruit.score <= 1.0  # the mean fruit probability of its voxels
    plain = fruit_model(steps=5)
    with pytest.raises(Exception, match="no 'fruit' output"):
        count_model(plain, None, WorldFrame(np.eye(4)[:3], 1.0), config, box=box)


def test_touching_fruit_are_split_into_fruit_of_the_given_size() -> None:
    """Two touching solid balls (the counter's diameter convention): one component too large for a fruit, split into
    two parts at the balls."""
    from agrinerf_ns.count.components import DIAMETER_PER_SD, _split

    rng = np.random.default_rng(0)
    centres = np.array([[0.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    points = rng.uniform(-0.05, 0.05, size=(4000, 3))
    ball = points[np.linalg.norm(points, axis=1) <= 0.05][:800]
    xyz = np.concatenate([c + ball[i::2] for i, c in enumerate(centres)])
    spreads = np.sqrt(np.linalg.eigvalsh(np.cov(xyz.T)))[::-1]
    assert DIAMETER_PER_SD * spreads[0] > 0.16  # beyond the default largest fruit
    parts = _split(xyz, spreads, 0.1)
    assert len(parts) == 2
    found = sorted(xyz[p].mean(0)[0] for p in parts)
    assert abs(found[0] - 0.0) < 0.02 and abs(found[1] - 0.1) < 0.02
    assert len(_split(xyz[:400], np.sqrt(np.linalg.eigvalsh(np.cov(xyz[:400].T)))[::-1], 0.1)) == 1  # one ball
