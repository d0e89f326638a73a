"""The pixel sampler's fruit share: uniform when off, the share on fruit pixels when on."""

import pytest
import torch
from nerfstudio.data.pixel_samplers import PixelSamplerConfig

from agrinerf_ns.dataparsers.agrinerf_dataset import agrinerf_datamanager_config
from agrinerf_ns.dataparsers.fruit_sampler import FruitPixelSamplerConfig


def _batch(images: int = 6, height: int = 30, width: int = 40) -> dict:
    fruit = torch.zeros(images, height, width, 1)
    fruit[:, 5:8, 10:13] = 1.0  # 9 fruit pixels per frame: 0.75% of them
    return {"image": torch.rand(images, height, width, 3), "fruit": fruit, "image_idx": torch.arange(images) + 10}


def test_off_it_draws_what_nerfstudios_sampler_draws() -> None:
    batch = _batch()
    torch.manual_seed(3)
    ours = FruitPixelSamplerConfig(num_rays_per_batch=256).setup().collate_image_dataset_batch(batch, 256)
    torch.manual_seed(3)
    stock = PixelSamplerConfig(num_rays_per_batch=256).setup().collate_image_dataset_batch(batch, 256)
    assert torch.equal(ours["indices"], stock["indices"]) and torch.equal(ours["image"], stock["image"])
    assert type(agrinerf_datamanager_config().pixel_sampler) is FruitPixelSamplerConfig  # the methods' default


def test_a_share_of_each_batch_lands_on_fruit_pixels() -> None:
    batch = _batch()
    torch.manual_seed(0)
    sampler = FruitPixelSamplerConfig(num_rays_per_batch=1000, fruit_share=0.25).setup()
    out = sampler.collate_image_dataset_batch(batch, 1000)
    on_fruit = out["fruit"][:, 0] > 0.5
    # the share, plus what the uniform rest finds (0.75% of 750)
    assert 250 <= int(on_fruit.sum()) <= 265
    assert out["image"].shape == (1000, 3) and bool((out["indices"][:, 0] >= 10).all())  # camera indices corrected
    # every fruit pixel is drawn: all frames and all nine pixels of each
    fruit_draws = out["indices"][on_fruit]
    assert len(set(fruit_draws[:, 0].tolist())) == 6 and len(set(map(tuple, fruit_draws[:, 1:].tolist()))) == 9
    # without fruit masks, or with Nerfstudio's mask, the draws are uniform
    plain = {k: v for k, v in batch.items() if k != "fruit"}
    torch.manual_seed(0)
    uniform = sampler.collate_image_dataset_batch(plain, 1000)
    torch.manual_seed(0)
    stock = PixelSamplerConfig(num_rays_per_batch=1000).setup().collate_image_dataset_batch(plain, 1000)
    assert torch.equal(uniform["indices"], stock["indices"])
    with pytest.raises(ValueError, match="fruit-share"):
        FruitPixelSamplerConfig(fruit_share=1.5).setup()
