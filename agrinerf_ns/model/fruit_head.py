"""The fruit head: where the field holds fruit, learnt from 2D fruit masks of the captured frames.

One logit per sample from the density volume's features (the shared geometry) and the sample's encoded grid
position, through a small MLP; rendered as the
``fruit`` output, the expected fruit probability along each ray (background: no fruit). Trained with binary cross
entropy against the frames' masks, unknown pixels left out (``dataparsers/fruit_masks.py``). By default neither the
head's features nor the render weights pass its gradient into the density, so the masks cannot bend the geometry
(FruitNeRF's choice); ``shape_geometry`` lets them. Built only for a dataset whose frames have fruit masks (the
model's plan), so that ``agrinerf-count --path fruit`` can count fruit in the field itself.
"""

from __future__ import annotations

from typing import Dict, List, Optional, Tuple

import torch
from jaxtyping import Float
from nerfstudio.field_components.encodings import NeRFEncoding
from nerfstudio.field_components.mlp import MLP
from torch import Tensor, nn
from torch.nn import Parameter
from torch.nn import functional as F

from agrinerf_ns.model import thermal_view
from agrinerf_ns.model.model_part import ModelPart, TermInputs

PROBABILITY_EPS = 1e-6
"""Rendered probabilities are clamped to [eps, 1 - eps] in the loss (BCE of an exact 0 or 1 is infinite)."""
FRUIT_DEPTH_EPS = 1e-4
"""Below this rendered fruit probability a ray has no fruit depth (NaN)."""


class FruitHead(nn.Module, ModelPart):
    """Fruit logit of a sample from its density features and its encoded grid position; the part of the term
    `fruit_loss`.

    The position is there because at the grid sizes a CPU trains (16^3 to 300^3, a few components) the density
    features are smooth and alike across a surface, so alone they can hardly tell a fruit from the leaf beside it.

    Args:
        in_dim: density features per sample (the density volume's `get_out_dim()`).
        width: hidden width of the MLP.
        shape_geometry: let the fruit loss's gradient reach the density (features and render weights).
        frequencies: octaves of the grid position's sinusoidal encoding.
    """

    def __init__(self, in_dim: int, width: int, shape_geometry: bool = False, frequencies: int = 6) -> None:
        super().__init__()
        self.shape_geometry = shape_geometry
        self.norm = nn.LayerNorm(in_dim)  # the VM features' scale drifts with training and with the grids' size
        self.position = NeRFEncoding(in_dim=3, num_frequencies=frequencies, min_freq_exp=0.0,
                                     max_freq_exp=frequencies - 1.0, include_input=True)  # fmt: skip
        self.mlp = MLP(in_dim=in_dim + self.position.get_out_dim(), num_layers=3, layer_width=width, out_dim=1,
                       activation=nn.ReLU(), out_activation=None, implementation="torch")  # fmt: skip

    def probability(self, features: Float[Tensor, "n c"], coords: Float[Tensor, "n 3"]) -> Float[Tensor, "n 1"]:
        """Fruit probability of samples with density `features` at grid coordinates `coords` (in [-1, 1])."""
        if not self.shape_geometry:
            features = features.detach()
        inputs = torch.cat([self.norm(features), self.position(coords.detach())], dim=-1)
        return torch.sigmoid(self.mlp(inputs))

    def render(
        self,
        features: Float[Tensor, "n c"],
        coords: Float[Tensor, "n 3"],
        weights: Float[Tensor, "rays samples 1"],
        distances: Optional[Float[Tensor, "rays samples 1"]] = None,
    ) -> Tuple[Float[Tensor, "rays 1"], Optional[Float[Tensor, "rays 1"]]]:
        """Expected fruit probability along each ray (`features`, `coords`: the rays' samples flattened, ray-major)
        and, given the samples' `distances` along the ray, the fruit depth: the mean distance weighted by each
        sample's render weight times its fruit probability, where along the ray the head puts the fruit (the
        rendered depth, the median of the weights, passes through a fruit the field holds only half opaque)."""
        if not self.shape_geometry:
            weights = weights.detach()
        probability = self.probability(features, coords).view(*weights.shape[:2], 1)
        fruit_weights = weights * probability
        fruit = fruit_weights.sum(dim=-2)
        return fruit, None if distances is None else fruit_depth(fruit_weights, distances)

    def loss(self, term: str, inputs: TermInputs) -> Optional[Tensor]:
        """The fruit loss: a mask of the RGB camera's view on the RGB rays; one of the thermal camera's view on the
        first rays rendered along the thermal camera's rays (`thermal_view`), and not on the RGB rays."""
        outputs, batch = inputs.outputs, inputs.batch
        if "fruit" not in batch:
            return None
        fruit, known = inputs.target("fruit"), inputs.target("fruit_known")
        assert fruit is not None and known is not None
        tv = thermal_view.PREFIX + "fruit"
        if tv not in outputs or "fruit_thermal" not in batch:
            return fruit_loss(outputs["fruit"], fruit, known)
        thermal = batch["fruit_thermal"].to(inputs.device)
        m = outputs[tv].shape[0]
        rendered = torch.cat([outputs["fruit"], outputs[tv]])
        known = torch.cat([known * (1.0 - thermal), known[:m] * thermal[:m]])
        return fruit_loss(rendered, torch.cat([fruit, fruit[:m]]), known)

    def param_groups(self) -> Dict[str, List[Parameter]]:
        return {"fields": list(self.parameters())}


def fruit_depth(
    fruit_weights: Float[Tensor, "rays samples 1"], distances: Float[Tensor, "rays samples 1"]
) -> Float[Tensor, "rays 1"]:
    """Mean sample distance weighted by render weight times fruit probability; NaN where a ray's rendered fruit
    probability is below :data:`FRUIT_DEPTH_EPS`."""
    fruit = fruit_weights.sum(dim=-2)
    depth = (fruit_weights * distances).sum(dim=-2) / fruit.clamp(min=FRUIT_DEPTH_EPS)
    return torch.where(fruit > FRUIT_DEPTH_EPS, depth, torch.full_like(depth, float("nan")))


def fruit_loss(
    rendered: Float[Tensor, "rays 1"], fruit: Float[Tensor, "rays 1"], known: Float[Tensor, "rays 1"]
) -> Float[Tensor, ""]:
    """Binary cross entropy of the rendered fruit probability against the masks, over the known pixels (0 when none
    is known)."""
    p = rendered.float().clamp(PROBABILITY_EPS, 1.0 - PROBABILITY_EPS)
    per_ray = F.binary_cross_entropy(p, fruit.float(), reduction="none")
    weight = known.float()
    return (per_ray * weight).sum() / weight.sum().clamp(min=1.0)


def fruit_iou(
    rendered: Float[Tensor, "*bs 1"],
    fruit: Float[Tensor, "*bs 1"],
    known: Float[Tensor, "*bs 1"],
    threshold: float = 0.5,
) -> float:
    """Intersection over union of the rendered fruit mask (probability >= `threshold`) and the true one, over the
    known pixels; 1 when neither has fruit (they agree)."""
    inside = known > 0.5
    predicted, truth = (rendered >= threshold) & inside, (fruit > 0.5) & inside
    union = int((predicted | truth).sum())
    return float((predicted & truth).sum()) / union if union else 1.0
