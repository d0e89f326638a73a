"""The row-gather VM lookup is Nerfstudio's `TensorVMEncoding`, only computed differently."""

from __future__ import annotations

import pytest
import torch
from nerfstudio.field_components.encodings import TensorVMEncoding

from agrinerf_ns.model.vm_encoding import BilinearVMEncoding, scatter_matrix, vm_corners, vm_product


def _pair(resolution: int, components: int, lookup: str = "rows"):
    torch.manual_seed(0)
    reference = TensorVMEncoding(resolution=resolution, num_components=components)
    mine = BilinearVMEncoding(resolution=resolution, num_components=components, lookup=lookup)
    mine.load_state_dict(reference.state_dict())  # the same parameter names and shapes: old checkpoints load
    return reference, mine


def _points(n: int = 500) -> torch.Tensor:
    gen = torch.Generator().manual_seed(1)
    pts = torch.rand(n, 3, generator=gen) * 2 - 1
    corners = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 0.25], [0.0, 0.0, 0.0]])
    return torch.cat([corners, pts])


@pytest.mark.parametrize("lookup", ["rows", "grid_sample"])
@pytest.mark.parametrize("resolution,components", [(2, 1), (7, 3), (16, 5)])
def test_features_and_gradients_equal_nerfstudios(lookup: str, resolution: int, components: int) -> None:
    reference, mine = _pair(resolution, components, lookup)
    pts = _points()
    expected, got = reference(pts), mine(pts)
    assert got.shape == expected.shape == (pts.shape[0], 3 * components)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    weights = torch.randn_like(expected)
    (expected * weights).sum().backward()
    (got * weights).sum().backward()
    torch.testing.assert_close(mine.plane_coef.grad, reference.plane_coef.grad, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(mine.line_coef.grad, reference.line_coef.grad, rtol=1e-4, atol=1e-5)


def test_batched_input_keeps_its_shape() -> None:
    reference, mine = _pair(9, 2)
    pts = _points(64)[:60].reshape(3, 20, 3)
    torch.testing.assert_close(mine(pts), reference(pts), rtol=1e-5, atol=1e-6)


def test_shared_corners_select_the_same_points() -> None:
    _, mine = _pair(9, 2)
    pts = _points(40)
    keep = torch.arange(pts.shape[0]) % 3 == 0
    corners = vm_corners(pts, mine.resolution)
    torch.testing.assert_close(mine.features(corners.select(keep)), mine(pts[keep]))


def test_out_of_range_and_nan_coordinates_are_clamped_to_the_border() -> None:
    _, mine = _pair(8, 2)
    far = torch.tensor([[5.0, -7.0, 0.5], [float("nan"), 0.0, float("inf")]])
    clamped = torch.tensor([[1.0, -1.0, 0.5], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(mine(far), mine(clamped))


def test_upsampling_matches_nerfstudio_and_stays_channels_last() -> None:
    reference, mine = _pair(8, 3)
    reference.upsample_grid(13)
    mine.upsample_grid(13)
    assert mine.resolution == 13 and mine.plane_coef.shape == (3, 3, 13, 13)
    assert mine.plane_coef.is_contiguous(memory_format=torch.channels_last)
    assert mine.line_coef.is_contiguous(memory_format=torch.channels_last)
    pts = _points(100)
    torch.testing.assert_close(mine(pts), reference(pts), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="resolution 8"):
        mine.features(vm_corners(pts, 8))


def test_scatter_matrix_adds_every_weighted_corner() -> None:
    gen = torch.Generator().manual_seed(2)
    rows, offsets = 30, (0, 1, 5, 6)
    base = torch.randint(0, rows - 6, (40,), generator=gen)  # repeated bases: their entries must all be there
    weight = torch.rand(40, 4, generator=gen)
    expected = torch.zeros(rows, 40)
    for i in range(40):
        for k, off in enumerate(offsets):
            expected[base[i] + off, i] += weight[i, k]
    matrix = scatter_matrix(base, offsets, weight, rows)
    torch.testing.assert_close(matrix.to_dense(), expected)
    assert bool((matrix.crow_indices().diff() >= 0).all()) and int(matrix.crow_indices()[-1]) == 160


def test_vm_product_gradient_is_exact() -> None:
    gen = torch.Generator().manual_seed(3)
    res, comps = 5, 3
    coords = torch.rand(30, 3, dtype=torch.float64, generator=gen) * 2 - 1
    coords[:4] = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, -1.0, 0.3]])
    corners = vm_corners(coords, res)
    plane = torch.randn(3 * res * res, comps, dtype=torch.float64, generator=gen, requires_grad=True)
    line = torch.randn(3 * res, comps, dtype=torch.float64, generator=gen, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p, q: vm_product(p, q, corners), (plane, line))


def test_no_points_give_zero_gradients() -> None:
    _, mine = _pair(6, 2)
    out = mine(torch.zeros(0, 3))
    assert out.shape == (0, 6)
    out.sum().backward()
    assert bool((mine.plane_coef.grad == 0).all()) and bool((mine.line_coef.grad == 0).all())


def test_unknown_lookup_and_tiny_resolution_are_refused() -> None:
    # the runtime type checker of the test suite refuses it first; without it, the constructor's own check does
    with pytest.raises((ValueError, TypeError), match="lookup"):
        BilinearVMEncoding(8, 2, lookup="bicubic")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="at least 2"):
        vm_corners(torch.zeros(1, 3), 1)
