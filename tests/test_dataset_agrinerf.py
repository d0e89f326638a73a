"""AgriNeRFDataset and the real Nerfstudio datamanager + pixel sampler on tiny tri-modal datasets."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from helpers.dataset_fixtures import HEIGHT, WIDTH, assert_batch_matches_dataset, write_tridata
from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManager
from nerfstudio.data.datamanagers.parallel_datamanager import ParallelDataManager
from PIL import Image

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataError, AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.agrinerf_dataset import AgriNeRFDataset, agrinerf_datamanager_config, load_aligned_frame

EXTRA = ("thermal", "thermal_mask", "event", "event_mask")


def _png(path: Path) -> torch.Tensor:
    return torch.from_numpy(np.asarray(Image.open(path)).astype(np.float32))


def _datamanager(root: Path, rays: int = 512, parallel: bool = False, **dataparser):
    dataparser.setdefault("train_split_fraction", 0.75)
    config = agrinerf_datamanager_config(
        parallel=parallel,
        dataparser=AgriNeRFDataParserConfig(data=root, **dataparser),
        train_num_rays_per_batch=rays,
        eval_num_rays_per_batch=rays,
    )
    return config.setup(device="cpu")


def test_metadata_values_from_files(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    outputs = AgriNeRFDataParserConfig(data=root).setup().get_dataparser_outputs("train")
    dataset = AgriNeRFDataset(outputs)
    data = dataset[5]
    for key in EXTRA:
        assert data[key].shape == (HEIGHT, WIDTH, 1) and data[key].dtype == torch.float32
    name = outputs.image_filenames[5].name
    assert torch.equal(data["thermal"][..., 0], _png(root / "thermal" / name) / 255.0)
    assert torch.equal(data["event"][..., 0], _png(root / "events" / name) / 255.0)
    assert torch.equal(data["thermal_mask"][..., 0], (_png(root / "thermal_masks" / name) == 255).float())
    assert 0.5 < data["event_mask"].mean() < 0.95  # the fixture's masks are about 80 % valid
    assert dataset.modalities == ("rgb", "thermal", "events")


def test_missing_masks_are_all_valid(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, masks=False)
    dataset = AgriNeRFDataset(AgriNeRFDataParserConfig(data=root).setup().get_dataparser_outputs("train"))
    data = dataset[0]
    assert torch.equal(data["thermal_mask"], torch.ones(HEIGHT, WIDTH, 1))
    assert torch.equal(data["event_mask"], torch.ones(HEIGHT, WIDTH, 1))


def test_sampled_batch_matches_images(tmp_path: Path) -> None:
    """The pixel sampler returns thermal, event and masks at the same pixels as RGB."""
    torch.manual_seed(0)
    datamanager = _datamanager(write_tridata(tmp_path))
    assert isinstance(datamanager, VanillaDataManager)
    assert type(datamanager.train_dataset) is AgriNeRFDataset
    for step in range(3):
        ray_bundle, batch = datamanager.next_train(step)
        assert set(batch) == {"image", "indices", *EXTRA}
        assert ray_bundle.shape == (512,)
        for key in EXTRA:
            assert batch[key].shape == (512, 1)
        assert_batch_matches_dataset(batch, datamanager.train_dataset, ("image", *EXTRA))
    # eval: ray batches and full images carry the same keys
    _, eval_batch = datamanager.next_eval(0)
    assert_batch_matches_dataset(eval_batch, datamanager.eval_dataset, ("image", *EXTRA))
    camera, image_batch = datamanager.next_eval_image(0)
    assert camera.shape == (1,)
    for key in EXTRA:
        assert image_batch[key].shape == (HEIGHT, WIDTH, 1)
    assert torch.equal(image_batch["thermal"], datamanager.eval_dataset[image_batch["image_idx"]]["thermal"])


@pytest.mark.parametrize(
    ("modalities", "present"),
    [(("rgb",), ()), (("rgb", "thermal"), ("thermal", "thermal_mask")), (("rgb", "events"), ("event", "event_mask"))],
)
def test_absent_modalities_absent_from_batches(tmp_path: Path, modalities: tuple, present: tuple) -> None:
    datamanager = _datamanager(write_tridata(tmp_path, modalities=modalities), rays=64)
    _, batch = datamanager.next_train(0)
    assert set(batch) == {"image", "indices", *present}
    _, image_batch = datamanager.next_eval_image(0)
    assert set(image_batch) == {"image", "image_idx", *present}
    assert_batch_matches_dataset(batch, datamanager.train_dataset, ("image", *present))


def test_config_modalities_drop_loaded_keys(tmp_path: Path) -> None:
    datamanager = _datamanager(write_tridata(tmp_path), rays=64, modalities=("rgb", "thermal"))
    _, batch = datamanager.next_train(0)
    assert set(batch) == {"image", "indices", "thermal", "thermal_mask"}


def _thermal_from_red_channel(root: Path) -> None:
    """Overwrites every thermal frame with its RGB frame's red channel, so the two must stay pixel-aligned."""
    for thermal in (root / "thermal").glob("*.png"):
        red = np.asarray(Image.open(root / "images" / thermal.name))[..., 0]
        Image.fromarray(np.ascontiguousarray(red)).save(thermal)


def test_camera_res_scale_factor_resizes_like_the_image(tmp_path: Path) -> None:
    root = write_tridata(tmp_path)
    _thermal_from_red_channel(root)
    config = agrinerf_datamanager_config(
        dataparser=AgriNeRFDataParserConfig(data=root, train_split_fraction=0.75),
        camera_res_scale_factor=0.5,
        train_num_rays_per_batch=128,
    )
    datamanager = config.setup(device="cpu")
    for index in range(len(datamanager.train_dataset)):
        data = datamanager.train_dataset[index]
        assert data["image"].shape == (HEIGHT // 2, WIDTH // 2, 3)
        for key in EXTRA:
            assert data[key].shape == (HEIGHT // 2, WIDTH // 2, 1)
        assert set(torch.unique(data["thermal_mask"]).tolist()) <= {0.0, 1.0}
        # resized exactly like the image: equal to the resized red channel up to the image's 8-bit rounding
        assert (data["thermal"][..., 0] - data["image"][..., 0]).abs().max() <= 1.0 / 255 + 1e-6
    _, batch = datamanager.next_train(0)
    assert_batch_matches_dataset(batch, datamanager.train_dataset, ("image", *EXTRA))


def test_dataparser_downscale_folder(tmp_path: Path) -> None:
    """With images_2/ (as ns-process-data writes), full-resolution thermal frames are resized to the image."""
    root = write_tridata(tmp_path, downscaled_images=(2,))
    _thermal_from_red_channel(root)
    datamanager = _datamanager(root, rays=64, downscale_factor=2)
    assert datamanager.train_dataset.cameras.width[0].item() == WIDTH // 2
    data = datamanager.train_dataset[1]
    assert data["image"].shape == (HEIGHT // 2, WIDTH // 2, 3)
    assert data["event"].shape == (HEIGHT // 2, WIDTH // 2, 1)
    assert (data["thermal"][..., 0] - data["image"][..., 0]).abs().max() <= 1.0 / 255 + 1e-6


@pytest.mark.parametrize(
    "fill",
    [
        {"rgb": 0, "thermal": 0, "event": 0, "mask": 0},
        {"rgb": 255, "thermal": 255, "event": 255, "mask": 255},
        {"rgb": 0, "thermal": 128, "event": 128},
    ],
    ids=["all-black-empty", "saturated-full", "constant"],
)
def test_extreme_frames_load(tmp_path: Path, fill: dict) -> None:
    """Black/saturated RGB, constant thermal, empty/flooded event frames and all-invalid masks load exactly."""
    datamanager = _datamanager(write_tridata(tmp_path, fill=fill), rays=64)
    _, batch = datamanager.next_train(0)
    for key, value in batch.items():
        assert torch.isfinite(value.float()).all(), key
    assert torch.all(batch["image"] == fill["rgb"] / 255.0)
    assert torch.all(batch["thermal"] == fill["thermal"] / 255.0)
    assert torch.all(batch["event"] == fill["event"] / 255.0)
    if "mask" in fill:
        assert torch.all(batch["thermal_mask"] == fill["mask"] / 255.0)


def test_bad_frames_name_the_file(tmp_path: Path) -> None:
    colour = tmp_path / "colour.png"
    Image.fromarray(np.zeros((HEIGHT, WIDTH, 3), dtype=np.uint8)).save(colour)
    with pytest.raises(AgriNeRFDataError, match=r"colour\.png: expected a single-channel image, got mode RGB"):
        load_aligned_frame(colour, HEIGHT, WIDTH)
    square = tmp_path / "square.png"
    Image.fromarray(np.zeros((WIDTH, WIDTH), dtype=np.uint8)).save(square)
    with pytest.raises(AgriNeRFDataError, match=r"square\.png: frame is 64x64 but its RGB image is 32x24"):
        load_aligned_frame(square, HEIGHT // 2, WIDTH // 2)
    broken = tmp_path / "broken.png"
    broken.write_bytes(b"not a png")
    with pytest.raises(AgriNeRFDataError, match=r"broken\.png: cannot read image"):
        load_aligned_frame(broken, HEIGHT, WIDTH)


def test_sixteen_bit_frames_scale_to_unit_range(tmp_path: Path) -> None:
    path = tmp_path / "thermal16.png"
    values = np.linspace(0, 65535, HEIGHT * WIDTH).reshape(HEIGHT, WIDTH).astype(np.uint16)
    Image.fromarray(values).save(path)
    frame = load_aligned_frame(path, HEIGHT, WIDTH)
    assert frame.min() == 0.0 and frame.max() == 1.0
    assert torch.allclose(frame[..., 0], torch.from_numpy(values.astype(np.float32) / 65535.0))


@pytest.mark.slow
def test_parallel_datamanager(tmp_path: Path) -> None:
    """Nerfstudio's ParallelDataManager (a spawned sampling process) also carries the extra keys."""
    datamanager = _datamanager(write_tridata(tmp_path), rays=128, parallel=True)
    try:
        assert isinstance(datamanager, ParallelDataManager)
        assert type(datamanager.train_dataset) is AgriNeRFDataset
        _, batch = datamanager.next_train(0)
        assert set(batch) == {"image", "indices", *EXTRA}
        assert_batch_matches_dataset(batch, datamanager.train_dataset, ("image", *EXTRA))
    finally:
        for process in datamanager.data_procs:
            process.terminate()
            process.join(timeout=10)
        datamanager.data_procs = []  # already stopped: nothing left for ParallelDataManager.__del__ at exit
