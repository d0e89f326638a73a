"""EvDeblurNeRF's blur model: DP-NeRF's learnt rigid blur kernel (EvDeblurNeRF's ``networks/dpnerf/blurmodel.py``,
``utils/rigid_warping.py``).

A training pixel is compared with a weighted mean of ``1 + M`` renders: its frame ray and M copies moved by learnt
rigid motions (SE(3) exponentials of a learnt screw vector), with learnt weights. The motions and weights come from a
per-image latent code (32 values, zero at the start) through three one-layer MLPs (32 wide): rotation and translation
(3 values per motion each, times the window 0.1) and the 1 + M weights (sigmoid, normalised to sum 1). EvDeblurNeRF
uses M = 9 (``kernel_ptnum 10``) from step 1200 (``kernel_start_iter``); before that the frame ray alone is compared.

Differences from the published kernel, kept small: the motion's pivot is the camera's centre (DP-NeRF moves the ray's
origin and end point about the world origin; the family of motions is the same, each one conjugated by the camera's
position), the rotation and translation layers start with zero biases (DP-NeRF leaves PyTorch's default biases, so its
kernel starts as fixed random motions of about 1 degree; here it starts as the identity: every ray is the frame's
ray) and the renders are blended in linear radiance, as the known-trajectory kernel does. DP-NeRF's adaptive weight
proposal (a second weight set from the rays' per-sample features, with its coarse-to-fine loss) is not reproduced:
it needs the field's sample features, which this model's renderer does not return.
"""

from __future__ import annotations

import math
from typing import Tuple

import torch
from jaxtyping import Float, Int
from torch import Tensor, nn

RV_WINDOW = 0.1
"""Scale of the rotation and translation outputs (``kernel_rbk_se_rv_window``)."""
OUTPUT_GAIN = 1e-5
"""The rotation and translation layers' weights start uniform in about +-1e-5 (DP-NeRF's xavier gain)."""


class RigidBlurKernel(nn.Module):
    """Per-image learnt rigid motions and blending weights of the blur kernel.

    Args:
        num_images: training images (one latent code each).
        num_motions: M, the moved copies of each frame ray (the kernel renders 1 + M rays per pixel).
        embed_dim: size of the per-image latent code.
        width: hidden width of the three branches.
    """

    def __init__(self, num_images: int, num_motions: int = 9, embed_dim: int = 32, width: int = 32) -> None:
        super().__init__()
        self.num_motions = num_motions
        self.embedding = nn.Parameter(torch.zeros(num_images, embed_dim))
        self.rotation = self._branch(embed_dim, width, 3 * num_motions, small=True)
        self.translation = self._branch(embed_dim, width, 3 * num_motions, small=True)
        self.weights = self._branch(embed_dim, width, num_motions + 1, small=False)

    @staticmethod
    def _branch(embed_dim: int, width: int, out: int, small: bool) -> nn.Sequential:
        branch = nn.Sequential(nn.Linear(embed_dim, width), nn.ReLU(), nn.Linear(width, out))
        if small:
            last = branch[2]
            assert isinstance(last, nn.Linear)
            nn.init.xavier_uniform_(last.weight, gain=OUTPUT_GAIN / math.sqrt((width + out) / 6))
            nn.init.zeros_(last.bias)
        return branch

    def forward(
        self, images: Int[Tensor, " n"]
    ) -> Tuple[Float[Tensor, "n m 3"], Float[Tensor, "n m 3"], Float[Tensor, "n m1"]]:
        """Rotation vectors (axis times angle, radians), translations (world units) and the 1 + M normalised weights
        (the frame ray's first) of each ray's image."""
        code = self.embedding[images.long()]
        n, m = code.shape[0], self.num_motions
        rotation = (self.rotation(code) * RV_WINDOW).reshape(n, 3, m).transpose(1, 2)
        translation = (self.translation(code) * RV_WINDOW).reshape(n, 3, m).transpose(1, 2)
        weights = torch.sigmoid(self.weights(code))
        return rotation, translation, weights / (weights.sum(dim=-1, keepdim=True) + 1e-10)


def _skew(w: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    zero = torch.zeros_like(w[..., 0])
    x, y, z = w.unbind(-1)
    return torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*w.shape[:-1], 3, 3)


def se3_exp(
    rotation: Float[Tensor, "*b 3"], translation: Float[Tensor, "*b 3"]
) -> Tuple[Float[Tensor, "*b 3 3"], Float[Tensor, "*b 3"]]:
    """The rigid motion exp([w, v]) of a screw vector (rotation vector w, translation part v): the rotation
    I + A [w] + B [w]^2 (Rodrigues) and the translation (I + B [w] + C [w]^2) v, with A = sin(t)/t,
    B = (1 - cos t)/t^2, C = (t - sin t)/t^3, t = |w| (series near t = 0, so the identity and its gradient are
    exact)."""
    w = rotation.double()
    theta2 = (w * w).sum(-1, keepdim=True)[..., None]  # [*b, 1, 1]
    theta = theta2.clamp(min=1e-30).sqrt()
    small = theta2 < 1e-8
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(theta) / theta)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(theta)) / theta2.clamp(min=1e-30))
    c = torch.where(small, 1.0 / 6.0 - theta2 / 120.0, (theta - torch.sin(theta)) / (theta2 * theta).clamp(min=1e-30))
    k = _skew(w)
    k2 = k @ k
    eye = torch.eye(3, dtype=w.dtype, device=w.device).expand_as(k)
    rot = eye + a * k + b * k2
    v = translation.double()[..., None]
    trans = ((eye + b * k + c * k2) @ v)[..., 0]
    return rot.to(rotation.dtype), trans.to(rotation.dtype)


def warp_rays(
    origins: Float[Tensor, "n 3"],
    directions: Float[Tensor, "n 3"],
    rotation: Float[Tensor, "n m 3"],
    translation: Float[Tensor, "n m 3"],
) -> Tuple[Float[Tensor, "n m 3"], Float[Tensor, "n m 3"]]:
    """Each ray moved by each of its M rigid motions about its origin (the camera's centre): origin o + t, unit
    direction R d."""
    rot, trans = se3_exp(rotation, translation)
    new_origins = origins[:, None, :] + trans
    new_directions = torch.nn.functional.normalize((rot @ directions[:, None, :, None])[..., 0], dim=-1)
    return new_origins, new_directions


def blend(linear: Float[Tensor, "n m1 3"], weights: Float[Tensor, "n m1"]) -> Float[Tensor, "n 3"]:
    """The kernel's weighted mean of the 1 + M renders (linear radiance)."""
    return (linear * weights[..., None]).sum(dim=1)
