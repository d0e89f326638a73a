"""A tiny AgriNeRF model whose field is fitted, point by point, to a known scene: a wall of leaves (18 C), warm fruit
in front of it (23 C) and warm ground (21 C) in the box [-1, 1]^3 (bounded, no contraction), for the tests of the
3D counter. The fit is real training of the real field (its density volume, thermal appearance and temperature
head), supervised by the scene's density and temperature at random points rather than by rendered rays."""

from __future__ import annotations

from typing import Any, Tuple

import numpy as np
import torch

FRUIT_CENTRES = np.array([[-0.55, -0.22, 0.25], [-0.1, -0.22, -0.3], [0.3, -0.22, 0.4], [0.65, -0.22, -0.05]])
FRUIT_RADIUS = 0.11
LEAF_C, FRUIT_C, GROUND_C = 18.0, 23.0, 21.0
DENSITY = 40.0


def scene_at(points: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
    """(density, temperature in C) of the scene at `points` [n, 3]; temperature is NaN in empty space."""
    x, y, z = points.unbind(-1)
    wall = y.abs() < 0.1
    ground = z < -0.75
    centres = torch.as_tensor(FRUIT_CENTRES, dtype=points.dtype)
    fruit = ((points[:, None, :] - centres[None]).norm(dim=-1) < FRUIT_RADIUS).any(dim=-1)
    temperature = torch.full_like(x, float("nan"))
    temperature[wall] = LEAF_C
    temperature[ground] = GROUND_C
    temperature[fruit] = FRUIT_C
    solid = wall | ground | fruit
    return torch.where(solid, DENSITY, 0.0), temperature


def fruit_model(steps: int = 400, seed: int = 0, fruit_head: bool = False) -> Any:
    """An `AgriNeRFModel` (RGB and thermal heads, a temperature head) whose field is fitted to `scene_at`; with
    `fruit_head`, also a fruit head fitted to which solid points are fruit (as masks would teach it)."""
    from nerfstudio.data.scene_box import SceneBox

    from agrinerf_ns.model.model import AgriNeRFModelConfig
    from helpers.small_model import SMALL_MODEL

    torch.manual_seed(seed)
    settings = dict(SMALL_MODEL) | dict(
        init_resolution=40, final_resolution=40, upsampling_iters=(), num_density_components=8,
        num_thermal_components=8, thermal_appearance_dim=8, thermal_mlp_width=16, scene_contraction=False,
        occupancy_resolution=0,
    )  # fmt: skip
    metadata = {
        "modalities": ("rgb", "thermal"),
        "temperature_stats": {"mean_c": 20.0, "std_c": 2.0, "min_c": 15.0, "max_c": 25.0},
    }
    if fruit_head:
        metadata["fruit_mask_filenames"] = []  # the plan builds a fruit head where the frames have masks
    config = AgriNeRFModelConfig(**settings)
    model = config.setup(scene_box=SceneBox(torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=1, metadata=metadata)
    field = model.field
    params = [p for p in field.parameters() if p.requires_grad]
    params += list(model.fruit_head.parameters()) if model.fruit_head is not None else []
    optimizer = torch.optim.Adam(params, lr=0.02)
    generator = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        points = torch.rand(8192, 3, generator=generator) * 2 - 1
        target_density, target_temperature = scene_at(points)
        coords, inside = field.to_grid(points)
        density = field.density_at(coords, inside)[:, 0]
        loss = ((torch.log1p(density) - torch.log1p(target_density)) ** 2).mean()
        solid = torch.isfinite(target_temperature)
        heads = field.appearance_at(coords[solid], torch.zeros_like(coords[solid]))
        from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames

        predicted = heads[AgriNeRFFieldHeadNames.TEMPERATURE][:, 0]
        loss = loss + ((predicted - field.temperature_head.normalise(target_temperature[solid])) ** 2).mean()
        if fruit_head:
            is_fruit = (target_temperature[solid] == FRUIT_C).float()[:, None]
            features = field.density_encoding.features(field.corners(coords[solid]))
            probability = model.fruit_head.probability(features, coords[solid]).clamp(1e-6, 1 - 1e-6)
            loss = loss + torch.nn.functional.binary_cross_entropy(probability, is_fruit)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.eval()
    return model


def assert_finds_the_known_fruit(fruit: Any) -> None:
    """The counted `fruit` are the scene's: one at each centre (within 3 cm), of its size (30%) and temperature
    (1 C)."""
    assert len(fruit) == len(FRUIT_CENTRES)
    centres = np.stack([f.centre for f in fruit])
    distance = np.linalg.norm(centres[:, None] - FRUIT_CENTRES[None], axis=-1)
    assert sorted(distance.argmin(1).tolist()) == list(range(len(FRUIT_CENTRES)))
    assert distance.min(1).max() < 0.03
    for one in fruit:
        assert abs(one.diameter - 2 * FRUIT_RADIUS) < 0.3 * 2 * FRUIT_RADIUS
        assert one.temperature is not None and abs(one.temperature - FRUIT_C) < 1.0
