"""Coarse samples that follow the fitted box: uniform until the ray leaves it, linear in disparity beyond.

Nerfstudio's `UniformLinDispPiecewiseSampler` spaces half the samples uniformly up to distance 1 and half linearly in
disparity beyond, which suits cameras around an object in the unit cube. An orchard row stands several units from the
cameras, so most of those uniform samples fell in the air in front of the rig. Here the uniform part ends where each ray
leaves the full-resolution box (`BoxContraction`), so the samples sit where the grids can resolve the scene.
"""

from __future__ import annotations

from typing import Callable, Optional

import torch
from jaxtyping import Float
from nerfstudio.cameras.rays import RayBundle, RaySamples
from nerfstudio.model_components.ray_samplers import Sampler
from torch import Tensor


def box_exit(
    origins: Float[Tensor, "n 3"], directions: Float[Tensor, "n 3"], box: Float[Tensor, "2 3"]
) -> Float[Tensor, "n 1"]:
    """Distance along each ray to where it leaves `box` (slab method); for a ray that misses the box, the distance
    to the point of the ray nearest the box centre (at least 0)."""
    safe = torch.where(directions.abs() < 1e-9, torch.full_like(directions, 1e-9), directions)
    t1 = (box[0] - origins) / safe
    t2 = (box[1] - origins) / safe
    t_in = torch.minimum(t1, t2).amax(dim=-1, keepdim=True)
    t_out = torch.maximum(t1, t2).amin(dim=-1, keepdim=True)
    closest = ((box.mean(dim=0) - origins) * directions).sum(dim=-1, keepdim=True).clamp(min=0.0)
    return torch.where(t_out >= t_in.clamp(min=0.0), t_out, closest)


class BoxPiecewiseSampler(Sampler):
    """`inner_share` of the samples uniform from the near plane to the box exit, the rest linear in disparity from
    there to the far plane; stratified jitter in training.

    Args:
        num_samples: samples per ray.
        box: returns the world (2, 3) lo / hi corners of the current full-resolution box.
        inner_share: fraction of the samples before the box exit.
        train_stratified: jitter the samples within their bins in training.
    """

    def __init__(
        self,
        num_samples: int,
        box: Callable[[], Float[Tensor, "2 3"]],
        inner_share: float = 0.5,
        train_stratified: bool = True,
    ) -> None:
        super().__init__(num_samples=num_samples)
        if not 0.0 < inner_share < 1.0:
            raise ValueError(f"inner_share must be in (0, 1), got {inner_share}")
        self.box = box
        self.inner_share = inner_share
        self.train_stratified = train_stratified

    def generate_ray_samples(
        self, ray_bundle: Optional[RayBundle] = None, num_samples: Optional[int] = None
    ) -> RaySamples:
        assert ray_bundle is not None and ray_bundle.nears is not None and ray_bundle.fars is not None
        num = num_samples or self.num_samples
        assert num is not None
        num_rays = ray_bundle.origins.shape[0]
        near, far = ray_bundle.nears, ray_bundle.fars  # [n, 1]
        exit_ = box_exit(ray_bundle.origins, ray_bundle.directions, self.box().to(near))
        exit_ = torch.minimum(torch.maximum(exit_, near * 1.001 + 1e-6), far * 0.999)
        share = self.inner_share

        def spacing_to_euclidean(s: Tensor) -> Tensor:
            """Normalised spacing in [0, 1] -> distance: linear to the box exit, linear in disparity beyond."""
            uniform = near + (s / share) * (exit_ - near)
            frac = ((s - share) / (1.0 - share)).clamp(0.0, 1.0)
            disparity = 1.0 / exit_ + frac * (1.0 / far - 1.0 / exit_)
            return torch.where(s <= share, uniform, 1.0 / disparity)

        bins = torch.linspace(0.0, 1.0, num + 1, device=near.device)[None].expand(num_rays, -1)
        if self.train_stratified and self.training:
            centres = (bins[..., 1:] + bins[..., :-1]) / 2.0
            upper = torch.cat([centres, bins[..., -1:]], -1)
            lower = torch.cat([bins[..., :1], centres], -1)
            bins = lower + (upper - lower) * torch.rand_like(bins)
        euclidean = spacing_to_euclidean(bins)
        return ray_bundle.get_ray_samples(
            bin_starts=euclidean[..., :-1, None],
            bin_ends=euclidean[..., 1:, None],
            spacing_starts=bins[..., :-1, None],
            spacing_ends=bins[..., 1:, None],
            spacing_to_euclidean_fn=spacing_to_euclidean,
        )
