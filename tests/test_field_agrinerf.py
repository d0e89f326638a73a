"""AgriNeRF field: shapes, gradients per head, in-place upsampling, occupancy pruning (CPU, random points)."""

from __future__ import annotations

import pytest
import torch
from nerfstudio.cameras.rays import Frustums, RaySamples
from nerfstudio.field_components.field_heads import FieldHeadNames

from agrinerf_ns.model.field import AgriNeRFField
from agrinerf_ns.model.field_heads import AgriNeRFFieldHeadNames

AABB = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]])


def _samples(rays: int = 5, per_ray: int = 7, seed: int = 0, scale: float = 0.9) -> RaySamples:
    gen = torch.Generator().manual_seed(seed)
    origins = (torch.rand(rays, per_ray, 3, generator=gen) * 2 - 1) * scale
    directions = torch.nn.functional.normalize(torch.randn(rays, per_ray, 3, generator=gen), dim=-1)
    zeros = torch.zeros(rays, per_ray, 1)
    frustums = Frustums(
        origins=origins, directions=directions, starts=zeros, ends=zeros + 0.01, pixel_area=torch.ones_like(zeros)
    )
    return RaySamples(frustums=frustums, deltas=zeros + 0.01)


def _field(with_rgb: bool = True, with_thermal: bool = True, contraction: bool = False, **kw) -> AgriNeRFField:
    torch.manual_seed(0)
    return AgriNeRFField(
        AABB,
        contraction=contraction,
        resolution=8,
        num_density_components=4,
        with_rgb=with_rgb,
        with_thermal=with_thermal,
        num_rgb_components=6,
        rgb_appearance_dim=5,
        num_thermal_components=3,
        thermal_appearance_dim=4,
        mlp_width=16,
        density_shift=0.5,
        occupancy_resolution=4,
        **kw,
    )


@pytest.mark.parametrize("with_thermal", [False, True])
@pytest.mark.parametrize("contraction", [False, True])
def test_forward_shapes_and_contract(with_thermal: bool, contraction: bool) -> None:
    field = _field(with_thermal=with_thermal, contraction=contraction)
    samples = _samples()
    density, embedding = field.get_density(samples)
    assert density.shape == (5, 7, 1) and embedding.shape == (5, 7, 3)
    assert (density >= 0).all() and torch.isfinite(density).all()
    outputs = field(samples)
    assert outputs[FieldHeadNames.RGB].shape == (5, 7, 3)
    assert outputs[FieldHeadNames.DENSITY].shape == (5, 7, 1)
    assert ((outputs[FieldHeadNames.RGB] >= 0) & (outputs[FieldHeadNames.RGB] <= 1)).all()
    if with_thermal:
        assert outputs[AgriNeRFFieldHeadNames.THERMAL].shape == (5, 7, 1)
    else:
        assert AgriNeRFFieldHeadNames.THERMAL not in outputs
        assert field.thermal_head is None
    # Field.density_fn of the base class unpacks (density, embedding): the contract holds
    assert field.density_fn(samples.frustums.get_positions()).shape == (5, 7, 1)


def _grad_names(field: AgriNeRFField, loss: torch.Tensor) -> set:
    field.zero_grad(set_to_none=True)
    loss.backward()
    return {n for n, p in field.named_parameters() if p.grad is not None and p.grad.abs().sum() > 0}


def test_gradients_reach_exactly_the_right_parameters() -> None:
    field = _field()
    samples = _samples()
    all_names = {n for n, _ in field.named_parameters()}
    rgb_head = {n for n in all_names if n.startswith("rgb_head.")}
    thermal_head = {n for n in all_names if n.startswith("thermal_head.")}
    density = {n for n in all_names if n.startswith("density_encoding.")}
    assert rgb_head and thermal_head and density and rgb_head | thermal_head | density == all_names

    out = field(samples)
    got = _grad_names(field, out[FieldHeadNames.RGB].sum() + out[FieldHeadNames.DENSITY].sum())
    assert got == rgb_head | density

    out = field(samples)
    got = _grad_names(field, out[AgriNeRFFieldHeadNames.THERMAL].sum())
    assert got == thermal_head  # the thermal loss alone never moves geometry or RGB through the head

    out = field(samples)
    total = sum(v.sum() for v in out.values())
    assert _grad_names(field, total) == all_names


def test_rgb_only_and_thermal_only_fields() -> None:
    rgb_only = _field(with_thermal=False)
    assert not any(n.startswith("thermal_head") for n, _ in rgb_only.named_parameters())
    thermal_only = _field(with_rgb=False)
    assert not any(n.startswith("rgb_head") for n, _ in thermal_only.named_parameters())
    assert set(thermal_only(_samples())) == {AgriNeRFFieldHeadNames.THERMAL, FieldHeadNames.DENSITY}
    with pytest.raises(ValueError, match="at least one"):
        _field(with_rgb=False, with_thermal=False)


def test_a_head_subset_evaluates_those_heads_only_with_the_same_values() -> None:
    field = _field(temperature_stats=(20.0, 4.0))
    coords = torch.rand(50, 3) * 2 - 1
    directions = torch.nn.functional.normalize(torch.randn(50, 3), dim=-1)
    every = field.appearance_at(coords, directions)
    names = {"rgb": FieldHeadNames.RGB, "thermal": AgriNeRFFieldHeadNames.THERMAL,
             "temperature": AgriNeRFFieldHeadNames.TEMPERATURE}  # fmt: skip
    assert set(every) == set(names.values())
    for heads in (("rgb", "thermal"), ("temperature",), ("thermal", "temperature"), ("rgb",)):
        some = field.appearance_at(coords, directions, heads=heads)
        assert set(some) == {names[h] for h in heads}
        for key, values in some.items():
            torch.testing.assert_close(values, every[key])


def test_points_outside_the_box_have_zero_density() -> None:
    field = _field()
    density, _ = field.get_density(_samples(scale=5.0))
    coords, inside = field.to_grid(_samples(scale=5.0).frustums.get_positions())
    assert (~inside).any() and (density[~inside] == 0).all()
    assert (coords.abs() <= 1).all()


def test_occupancy_prunes_empty_space_and_keeps_dense_cells() -> None:
    field = _field()
    with torch.no_grad():
        enc = field.density_encoding
        enc.plane_table.fill_(0.0)
        enc.line_table.fill_(0.0)
        # a dense slab near x = +1: plane (x, y) and line (z) active only at large x
        enc.planes()[0][:, -2:, 0] = 3.0  # plane 0 is indexed (y, x); last columns = x near +1
        enc.lines()[0][:, 0] = 3.0
    field.density_shift = -10.0
    kept = field.update_occupancy(density_threshold=0.01)
    assert 0.0 < kept < 1.0
    samples = _samples(rays=50, per_ray=10, seed=3)
    coords, _ = field.to_grid(samples.frustums.get_positions())
    occupied = field.occupied(coords.reshape(-1, 3))
    density, _ = field.get_density(samples)
    assert (density.reshape(-1)[~occupied] == 0).all()
    assert (coords.reshape(-1, 3)[occupied][:, 0] > -0.5).all()  # only cells towards the slab survive


def test_occupancy_update_never_prunes_everything() -> None:
    field = _field()
    field.density_shift = -30.0  # nothing is dense yet
    assert field.update_occupancy(density_threshold=0.1) == 1.0
    assert field.occupancy.all() and field.occupancy_all
