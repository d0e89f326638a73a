"""The VM volume: Nerfstudio's `TensorVMEncoding` for a cube (only computed differently), one resolution per axis,
exact resampling, checkpoints that restore their shapes, and the hand-written TV gradient."""

from __future__ import annotations

import warnings

import pytest
import torch
from nerfstudio.field_components.encodings import TensorVMEncoding

from agrinerf_ns.model.plane_tv import _PlaneTV, plane_tv
from agrinerf_ns.model.vm_encoding import VMVolume, scatter_matrix, vm_corners, vm_product


def _pair(resolution: int, components: int, lookup: str = "rows"):
    torch.manual_seed(0)
    reference = TensorVMEncoding(resolution=resolution, num_components=components)
    torch.manual_seed(0)
    mine = VMVolume(resolution=resolution, num_components=components, lookup=lookup)
    return reference, mine


def _points(n: int = 500) -> torch.Tensor:
    gen = torch.Generator().manual_seed(1)
    pts = torch.rand(n, 3, generator=gen) * 2 - 1
    corners = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [1.0, -1.0, 0.25], [0.0, 0.0, 0.0]])
    return torch.cat([corners, pts])


def _as_tables(reference: TensorVMEncoding) -> tuple:
    comps = reference.num_components
    return (
        reference.plane_coef.permute(0, 2, 3, 1).reshape(-1, comps),
        reference.line_coef.permute(0, 2, 3, 1).reshape(-1, comps),
    )


@pytest.mark.parametrize("lookup", ["rows", "grid_sample"])
@pytest.mark.parametrize("resolution,components", [(2, 1), (7, 3), (16, 5)])
def test_cube_features_initial_values_and_gradients_equal_nerfstudios(
    lookup: str, resolution: int, components: int
) -> None:
    reference, mine = _pair(resolution, components, lookup)
    plane, line = _as_tables(reference)
    assert torch.equal(mine.plane_table.detach(), plane.detach()) and torch.equal(
        mine.line_table.detach(), line.detach()
    )
    pts = _points()
    expected, got = reference(pts), mine(pts)
    assert got.shape == expected.shape == (pts.shape[0], 3 * components)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    weights = torch.randn_like(expected)
    (expected * weights).sum().backward()
    (got * weights).sum().backward()
    ref_plane, ref_line = _as_tables(
        type(
            "G",
            (),
            {
                "plane_coef": reference.plane_coef.grad,
                "line_coef": reference.line_coef.grad,
                "num_components": components,
            },
        )()
    )
    torch.testing.assert_close(mine.plane_table.grad, ref_plane, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(mine.line_table.grad, ref_line, rtol=1e-4, atol=1e-5)


def test_axis_resolutions_agree_between_lookups_in_values_and_gradients() -> None:
    torch.manual_seed(2)
    rows = VMVolume((5, 11, 3), 4, lookup="rows")
    grid = VMVolume((5, 11, 3), 4, lookup="grid_sample")
    grid.load_state_dict(rows.state_dict())
    assert rows.resolution == (5, 11, 3) and rows.plane_table.shape == (5 * 11 + 5 * 3 + 11 * 3, 4)
    pts = _points(300)
    torch.testing.assert_close(rows(pts), grid(pts), rtol=1e-5, atol=1e-6)
    weights = torch.randn(pts.shape[0], 12)
    (rows(pts) * weights).sum().backward()
    (grid(pts) * weights).sum().backward()
    torch.testing.assert_close(rows.plane_table.grad, grid.plane_table.grad, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(rows.line_table.grad, grid.line_table.grad, rtol=1e-4, atol=1e-5)


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


def test_upsampling_matches_nerfstudio() -> None:
    reference, mine = _pair(8, 3)
    reference.upsample_grid(13)
    mine.upsample_grid(13)
    assert mine.resolution == (13, 13, 13)
    pts = _points(100)
    torch.testing.assert_close(mine(pts), reference(pts), rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="resolution"):
        mine.features(vm_corners(pts, 8))


def test_resampling_along_axes_is_exact_at_the_new_grid_points() -> None:
    torch.manual_seed(3)
    volume = VMVolume((6, 7, 5), 2)
    before = VMVolume((6, 7, 5), 2)
    before.load_state_dict(volume.state_dict())
    # the new grid covers [-0.5, 0.25] of the old x axis, all of y and z: its grid points are old coordinates
    res = (9, 7, 5)
    sources = [torch.linspace(-0.5, 0.25, 9), torch.linspace(-1, 1, 7), torch.linspace(-1, 1, 5)]
    volume.resample(res, sources)
    assert volume.resolution == res
    grid = torch.stack(torch.meshgrid(*[torch.linspace(-1, 1, r) for r in res], indexing="ij"), -1).reshape(-1, 3)
    old = torch.stack(torch.meshgrid(*sources, indexing="ij"), -1).reshape(-1, 3)
    torch.testing.assert_close(volume(grid), before(old), rtol=1e-5, atol=1e-6)


def test_a_checkpoint_restores_its_shapes_and_the_legacy_cube_layout_loads() -> None:
    torch.manual_seed(4)
    trained = VMVolume((4, 9, 6), 3)
    fresh = VMVolume(5, 3)
    fresh.load_state_dict(trained.state_dict())
    pts = _points(50)
    assert fresh.resolution == (4, 9, 6)
    torch.testing.assert_close(fresh(pts), trained(pts))
    reference, _ = _pair(6, 3)
    legacy = VMVolume(8, 3)
    legacy.load_state_dict(reference.state_dict())  # Nerfstudio's plane_coef / line_coef names and shapes
    torch.testing.assert_close(legacy(pts), reference(pts), rtol=1e-5, atol=1e-6)


def test_tv_value_and_hand_written_gradient_equal_autograds() -> None:
    torch.manual_seed(5)
    volume = VMVolume((4, 7, 5), 3)
    table = volume.plane_table.detach().double()
    volume.plane_table = torch.nn.Parameter(table.clone())
    got = plane_tv(volume)
    got.backward()
    auto = table.clone().requires_grad_(True)
    planes = volume.planes(auto)
    n_h = sum((p.shape[0] - 1) * p.shape[1] * p.shape[2] for p in planes)
    n_w = sum(p.shape[0] * (p.shape[1] - 1) * p.shape[2] for p in planes)
    expected = (
        sum((p[1:] - p[:-1]).pow(2).sum() for p in planes) / n_h
        + sum((p[:, 1:] - p[:, :-1]).pow(2).sum() for p in planes) / n_w
    )
    expected.backward()
    torch.testing.assert_close(got.double(), expected)
    torch.testing.assert_close(volume.plane_table.grad, auto.grad, rtol=1e-9, atol=1e-12)
    assert torch.autograd.gradcheck(lambda t: _PlaneTV.apply(t, volume.layout), (auto.detach().requires_grad_(True),))


def test_tv_of_a_cube_by_hand() -> None:
    volume = VMVolume(3, 1)
    with torch.no_grad():
        volume.plane_table.zero_()
        volume.planes()[0][:, :, 0] = torch.tensor([[0.0, 1.0, 3.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    # height diffs (3 planes * 2 * 3 = 18): 0, 1, 9 -> 10/18; width diffs (18): 1, 4 -> 5/18
    assert plane_tv(volume).item() == pytest.approx(10 / 18 + 5 / 18, abs=1e-6)


def test_scatter_matrix_adds_every_weighted_corner_in_its_segment() -> None:
    gen = torch.Generator().manual_seed(2)
    segments, offsets = (0, 30, 50), [(0, 1, 5, 6), (0, 1, 4, 5)]
    base = torch.cat([torch.randint(0, 24, (30,), generator=gen), torch.randint(30, 45, (10,), generator=gen)])
    weight = torch.rand(40, 4, generator=gen)
    expected = torch.zeros(50, 40)
    for i in range(40):
        for k, off in enumerate(offsets[0 if base[i] < 30 else 1]):
            expected[base[i] + off, i] += weight[i, k]
    matrix = scatter_matrix(base, offsets, weight, segments)
    torch.testing.assert_close(matrix.to_dense(), expected)
    assert bool((matrix.crow_indices().diff() >= 0).all()) and int(matrix.crow_indices()[-1]) == 160


def test_vm_product_gradient_is_exact() -> None:
    gen = torch.Generator().manual_seed(3)
    res, comps = (5, 4, 3), 3
    coords = torch.rand(30, 3, dtype=torch.float64, generator=gen) * 2 - 1
    coords[:4] = torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0], [0.0, 0.0, 0.0], [1.0, -1.0, 0.3]])
    corners = vm_corners(coords, res)
    plane = torch.randn(5 * 4 + 5 * 3 + 4 * 3, comps, dtype=torch.float64, generator=gen, requires_grad=True)
    line = torch.randn(3 + 4 + 5, comps, dtype=torch.float64, generator=gen, requires_grad=True)
    assert torch.autograd.gradcheck(lambda p, q: vm_product(p, q, corners), (plane, line))


def test_the_row_lookup_is_differentiable_in_the_coordinates_as_grid_sample_is() -> None:
    # a moved ray (a learnt blur kernel, pose refinement) learns through its samples' positions; interior points, away
    # from cell borders, where both lookups are differentiable
    gen = torch.Generator().manual_seed(4)
    res, comps = (6, 5, 4), 3
    coords = (torch.rand(40, 3, dtype=torch.float64, generator=gen) * 1.8 - 0.9).requires_grad_(True)
    plane = torch.randn(6 * 5 + 6 * 4 + 5 * 4, comps, dtype=torch.float64, generator=gen, requires_grad=True)
    line = torch.randn(4 + 5 + 6, comps, dtype=torch.float64, generator=gen, requires_grad=True)
    assert torch.autograd.gradcheck(lambda c, p, q: vm_product(p, q, vm_corners(c, res)), (coords, plane, line))
    rows = VMVolume(res, comps, lookup="rows").double()
    grid = VMVolume(res, comps, lookup="grid_sample").double()
    grid.load_state_dict(rows.state_dict())
    weights = torch.randn(40, 3 * comps, dtype=torch.float64, generator=gen)
    (g_rows,) = torch.autograd.grad((rows(coords) * weights).sum(), coords)
    (g_grid,) = torch.autograd.grad((grid(coords) * weights).sum(), coords)
    torch.testing.assert_close(g_rows, g_grid, rtol=1e-9, atol=1e-10)
    # positions without a graph keep the cheaper lookup: no coordinate gradient is computed or linked
    assert vm_corners(coords.detach(), res).source is None
    with torch.no_grad():
        assert vm_corners(coords, res).source is None


def test_no_points_give_zero_gradients() -> None:
    _, mine = _pair(6, 2)
    out = mine(torch.zeros(0, 3))
    assert out.shape == (0, 6)
    out.sum().backward()
    assert bool((mine.plane_table.grad == 0).all()) and bool((mine.line_table.grad == 0).all())


def test_unknown_lookup_and_tiny_resolution_are_refused() -> None:
    # the runtime type checker of the test suite refuses it first; without it, the constructor's own check does
    with pytest.raises((ValueError, TypeError), match="lookup"):
        VMVolume(8, 2, lookup="bicubic")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="at least 2"):
        vm_corners(torch.zeros(1, 3), 1)
    with pytest.raises(ValueError, match="at least 2"):
        VMVolume((4, 1, 4), 2)


def _warn_here() -> None:
    warnings.warn("a notice from one place", UserWarning, stacklevel=1)


def test_a_training_lookup_leaves_other_warnings_said_once() -> None:
    """Python shows a warning once per code location; a lookup's backward (which builds the sparse transposes) must not
    reset that, or every library's warning is printed again at every training step (seen: 6 lines a step in ns-train
    logs)."""
    volume = VMVolume(resolution=(8, 6, 5), num_components=4)
    with warnings.catch_warnings(record=True) as seen:
        warnings.simplefilter("default")
        for _ in range(3):
            _warn_here()
            corners = vm_corners(torch.rand(64, 3) * 2 - 1, volume.resolution)
            volume.features(corners).sum().backward()
    assert [str(w.message) for w in seen] == ["a notice from one place"]
