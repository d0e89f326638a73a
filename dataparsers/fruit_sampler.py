"""A pixel sampler that can give the frames' fruit pixels a share of every training batch.

Fruit cover a few percent of an orchard frame, so a batch of uniformly drawn rays holds few of them, and the field
places the fruit's surfaces (and the fruit head learns them) from that trickle. With ``fruit_share`` > 0 that share
of each batch is drawn among the pixels the frames' fruit masks mark as fruit (every such pixel equally likely), the
rest uniformly as Nerfstudio's sampler draws them. Every loss then weighs fruit pixels that much more than their share
of the frames. Off (0) by default, and without effect on a dataset without fruit masks or with Nerfstudio's ``mask``
(whose sampling it leaves as it is).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple, Type, Union

import torch
from jaxtyping import Int
from nerfstudio.data.pixel_samplers import PixelSampler, PixelSamplerConfig
from torch import Tensor


@dataclass
class FruitPixelSamplerConfig(PixelSamplerConfig):
    """Nerfstudio's pixel sampler with a share of each batch on the frames' fruit pixels."""

    _target: Type = field(default_factory=lambda: FruitPixelSampler)
    fruit_share: float = 0.0
    """Share of each training batch drawn among the fruit-mask pixels (0: uniform, as Nerfstudio's sampler)."""


class FruitPixelSampler(PixelSampler):
    """:class:`PixelSampler` whose draws put ``fruit_share`` of a batch on fruit pixels (module docstring)."""

    config: FruitPixelSamplerConfig

    def __init__(self, config: FruitPixelSamplerConfig, **kwargs) -> None:
        super().__init__(config, **kwargs)
        if not 0.0 <= config.fruit_share <= 1.0:
            raise ValueError(f"pixel-sampler.fruit-share must lie in [0, 1], got {config.fruit_share}")
        self._fruit: Optional[Tensor] = None
        self._cached: Optional[Tuple[Tuple[int, Tuple[int, ...]], Tensor]] = None

    def collate_image_dataset_batch(self, batch: Dict, num_rays_per_batch: int, keep_full_image: bool = False):
        self._fruit = batch.get("fruit") if self.config.fruit_share > 0 and "mask" not in batch else None
        try:
            return super().collate_image_dataset_batch(batch, num_rays_per_batch, keep_full_image)
        finally:
            self._fruit = None

    def sample_method(
        self,
        batch_size: int,
        num_images: int,
        image_height: int,
        image_width: int,
        mask: Optional[Tensor] = None,
        device: Union[torch.device, str] = "cpu",
    ) -> Int[Tensor, "batch_size 3"]:
        indices = super().sample_method(batch_size, num_images, image_height, image_width, mask=mask, device=device)
        if self._fruit is None:
            return indices
        fruit = self.fruit_pixels(self._fruit)
        count = int(round(self.config.fruit_share * batch_size))
        if fruit.shape[0] == 0 or count == 0:
            return indices
        pick = torch.randint(0, fruit.shape[0], (count,), device=fruit.device)
        indices[:count] = fruit[pick].to(indices)  # the uniform draws are independent: any of them may give way
        return indices

    def fruit_pixels(self, fruit: Tensor) -> Int[Tensor, "n 3"]:
        """(image, row, column) of every fruit pixel of the batch's `fruit` images [N, H, W, 1], cached while the
        batch holds the same tensor (Nerfstudio keeps its cached images from step to step)."""
        key = (fruit.data_ptr(), tuple(fruit.shape))
        if self._cached is None or self._cached[0] != key:
            self._cached = (key, torch.nonzero(fruit[..., 0] > 0.5, as_tuple=False))
        return self._cached[1]
