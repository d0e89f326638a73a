"""The full-resolution box: the per-axis contraction and its inverse, voxel sizes, the fit on a synthetic row's true
surfaces, and the coarse sampler that follows the box."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from nerfstudio.cameras.rays import RayBundle
from scipy.spatial.transform import Rotation

from agrinerf_ns.model.box_sampler import BoxPiecewiseSampler, box_exit
from agrinerf_ns.model.grid_mapping import BoxContraction, axis_resolution, contract_axes, fit_box, uncontract_axes


def test_contraction_is_linear_in_the_box_continuous_and_inverted() -> None:
    u = torch.tensor([[0.0, 0.5, -1.0], [1.0, 2.0, -4.0], [1e8, -1e8, 0.25]])
    c = contract_axes(u, 0.8)
    torch.testing.assert_close(c[0], torch.tensor([0.0, 0.4, -0.8]))
    torch.testing.assert_close(c[1], torch.tensor([0.8, 0.9, -0.95]))
    assert bool((c.abs() <= 1).all()) and c[2, 0] == pytest.approx(1.0, abs=1e-6)
    inside = torch.linspace(-0.999, 0.999, 101)[:, None].expand(-1, 3)
    torch.testing.assert_close(contract_axes(uncontract_axes(inside, 0.8), 0.8), inside, rtol=1e-5, atol=1e-6)
    mapping = BoxContraction(torch.tensor([[0.0, 2.0, -1.0], [4.0, 3.0, 1.0]]), inner=0.8)
    pts = torch.tensor([[2.0, 2.5, 0.0], [4.0, 2.0, 1.0], [10.0, 2.5, 0.0]])
    torch.testing.assert_close(mapping(pts)[:2], torch.tensor([[0.0, 0.0, 0.0], [0.8, -0.8, 0.8]]))
    assert mapping.full_resolution(pts).tolist() == [True, True, False]
    torch.testing.assert_close(mapping.inverse(mapping(pts)), pts, rtol=1e-4, atol=1e-4)


def test_voxels_are_cubes_in_the_box_and_grow_outside() -> None:
    box = torch.tensor([[0.0, 0.0, 0.0], [8.0, 2.0, 4.0]])
    res = axis_resolution(box, 0.8, 64)
    assert res[0] > res[2] > res[1] and abs(np.prod(res) / 64**3 - 1) < 0.05
    mapping = BoxContraction(box, 0.8)
    size = mapping.voxel_size(torch.tensor([[4.0, 1.0, 2.0], [40.0, 1.0, 2.0]]), res)
    inner = size[0]
    assert float(inner.max() / inner.min()) < 1.1  # square cells inside the box
    torch.testing.assert_close(inner[0], torch.tensor(8.0 / (0.8 * (res[0] - 1))), rtol=1e-5, atol=0.0)
    assert size[1, 0] > 10 * inner[0]  # far out along x the cells are much longer


def _true_surface_points(raw, frames: int = 8):
    """World points (metres) of the synthetic capture's true depth maps, with the camera centres they were seen from."""
    import yaml

    calib = yaml.safe_load((raw / "calib.yaml").read_text())["cam0"]
    fx, fy, cx, cy = calib["intrinsics"]
    poses = np.loadtxt(raw / "truth" / "poses.txt")
    points, origins = [], []
    for i in range(frames):
        depth = np.load(raw / "truth" / "depth" / f"{i:06d}.npy")
        v, u = np.mgrid[0 : depth.shape[0], 0 : depth.shape[1]] + 0.5
        cam = np.stack([(u - cx) / fx * depth, (v - cy) / fy * depth, depth], -1).reshape(-1, 3)
        cam = cam[np.isfinite(cam).all(axis=1)]  # the sky has no depth
        rotation = Rotation.from_quat(poses[i, 4:8]).as_matrix()
        points.append(cam @ rotation.T + poses[i, 1:4])
        origins.append(np.broadcast_to(poses[i, 1:4], points[-1].shape))
    return torch.tensor(np.concatenate(points), dtype=torch.float32), torch.tensor(
        np.concatenate(origins), dtype=torch.float32
    )


@pytest.mark.slow
def test_fitted_box_holds_the_front_row_and_leaves_out_the_far_background(tmp_path) -> None:
    from agrinerf_ns.synth import SynthConfig, generate_capture

    raw = tmp_path / "raw"
    generate_capture(SynthConfig(scene="orchard", lighting="bright", seed=3, views=8, width=64, height=48), raw)
    points, origins = _true_surface_points(raw)
    box = fit_box(points, origins=origins)
    assert box is not None
    inside = ((points >= box[0]) & (points <= box[1])).all(dim=-1)
    front = points[:, 1] < 1.0  # the front row (y = 0) and the ground before it
    assert float(inside[front].float().mean()) > 0.95
    assert float(inside.float().mean()) > 0.8  # most of what the cameras see, sky aside
    hedge = points[:, 1] > 7.5  # the hedge far behind the rows is background
    assert float(inside[hedge].float().mean()) < 0.05
    seen = torch.stack([points.min(dim=0).values, points.max(dim=0).values])
    assert float((box[1] - box[0]).prod() / (seen[1] - seen[0]).prod()) < 0.35  # most empty space is outside


def test_fit_refuses_too_few_points_and_ignores_non_finite_ones() -> None:
    assert fit_box(torch.full((5, 3), float("nan"))) is None
    pts = torch.cat([torch.rand(200, 3), torch.tensor([[float("inf"), 0.0, 0.0]])])
    box = fit_box(pts)
    assert box is not None and bool(torch.isfinite(box).all()) and bool((box[0] < 0.1).all() and (box[1] > 0.9).all())


def test_box_sampler_puts_half_the_samples_before_the_box_exit() -> None:
    box = torch.tensor([[-1.0, 4.0, -1.0], [1.0, 6.0, 1.0]])
    origins = torch.zeros(3, 3)
    directions = torch.tensor([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.6, 0.8]])
    exits = box_exit(origins, directions, box)
    assert exits[0, 0] == pytest.approx(6.0) and exits[1, 0] == pytest.approx(0.0)  # a miss: nearest point is behind
    bundle = RayBundle(origins=origins, directions=directions, pixel_area=torch.ones(3, 1),
                       nears=torch.full((3, 1), 0.05), fars=torch.full((3, 1), 1000.0))  # fmt: skip
    sampler = BoxPiecewiseSampler(16, box=lambda: box)
    sampler.eval()
    samples = sampler(bundle)
    ends = samples.frustums.ends[0, :, 0]
    assert float(ends[7]) == pytest.approx(6.0, rel=1e-4) and float(ends[-1]) == pytest.approx(1000.0, rel=1e-4)
    assert bool((samples.frustums.starts[..., 1:, 0] >= samples.frustums.starts[..., :-1, 0]).all())
    assert bool(torch.isfinite(samples.frustums.ends).all())
    spacing = samples.spacing_to_euclidean_fn(torch.tensor([[0.0, 0.5, 1.0]]).expand(3, -1))
    torch.testing.assert_close(spacing[0], torch.tensor([0.05, 6.0, 1000.0]), rtol=1e-4, atol=1e-4)
