"""The full-resolution box: the per-axis contraction and its inverse, voxel sizes, the fit on a synthetic row's true
surfaces, and the coarse sampler that follows the box."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import torch
from nerfstudio.cameras.rays import RayBundle
from scipy.spatial.transform import Rotation

from agrinerf_ns.model.box_sampler import BoxPiecewiseSampler, box_exit
from agrinerf_ns.model.grid_mapping import (
    BoxContraction,
    axis_resolution,
    box_voxel,
    contract_axes,
    fit_box,
    smallest_box,
    uncontract_axes,
)


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


@pytest.mark.parametrize("share", [0.8, 0.9, 0.97])
def test_smallest_box_holds_its_share_and_drops_the_costly_tail_first(share: float) -> None:
    gen = torch.Generator().manual_seed(0)
    row = torch.rand(9000, 3, generator=gen, dtype=torch.float64) * torch.tensor([8.0, 1.0, 3.0])  # a long, flat row
    far = torch.rand(600, 3, generator=gen, dtype=torch.float64) * torch.tensor([8.0, 1.0, 3.0]) + torch.tensor(
        [0.0, 6.0, 0.0]
    )  # the next row, 6 units behind: 6% of the points
    strays = torch.randn(100, 3, generator=gen, dtype=torch.float64) * 40.0
    points = torch.cat([row, far, strays])
    weights = torch.ones(points.shape[0], dtype=torch.float64)
    box = smallest_box(points, weights, share)
    inside = ((points >= box[0]) & (points <= box[1])).all(dim=-1)
    assert float(weights[inside].sum() / weights.sum()) >= share
    assert float(inside[-100:].float().mean()) < 0.2  # strays cost the most volume per point: they go first
    if share <= 0.9:  # the next row costs 7x the volume for 6% of the weight: outside
        assert float(inside[9000:9600].float().mean()) < 0.05
        assert float(inside[:9000].float().mean()) >= (share - 0.01) / 0.94
        assert bool((box[1] - box[0] <= torch.tensor([8.0, 1.0, 3.0]) + 1e-6).all())
    else:  # 97% cannot be held without it
        assert float(inside[9000:9600].float().mean()) > 0.5


def test_smallest_box_follows_the_weights() -> None:
    gen = torch.Generator().manual_seed(1)
    near = torch.rand(1000, 3, generator=gen, dtype=torch.float64)
    heavy = torch.rand(100, 3, generator=gen, dtype=torch.float64) + 5.0  # few points, half the weight
    points = torch.cat([near, heavy])
    weights = torch.cat([torch.ones(1000), torch.full((100,), 10.0)]).double()
    box = smallest_box(points, weights, 0.9)
    assert bool((box[0] <= 0.2).all() and (box[1] >= 5.8).all())  # both clusters held (their near edges peeled)
    light = smallest_box(points, torch.ones(1100, dtype=torch.float64), 0.9)
    assert bool((light[1] <= 1.0).all())  # with equal weights the small cluster is the 9% left out


def test_a_box_fine_enough_stops_shrinking_and_holds_more_than_its_share() -> None:
    gen = torch.Generator().manual_seed(2)
    scene = torch.rand(5000, 3, generator=gen, dtype=torch.float64)
    strays = torch.rand(100, 3, generator=gen, dtype=torch.float64) * 50.0 + 10.0
    points = torch.cat([scene, strays])
    weights = torch.ones(points.shape[0], dtype=torch.float64)
    share = 0.8
    shrunk = smallest_box(points, weights, share)
    stopped = smallest_box(points, weights, share, done=lambda box: bool((box[1] - box[0]).prod() <= 1.0))
    held = [float(((points >= b[0]) & (points <= b[1])).all(dim=-1).double().mean()) for b in (shrunk, stopped)]
    assert share <= held[0] < 0.85 and held[1] == pytest.approx(5000 / 5100, abs=2e-3)  # about only the strays go
    assert float((stopped[1] - stopped[0]).prod()) <= 1.0
    voxel = box_voxel(stopped, 0.8, 100)
    assert voxel == pytest.approx(float((stopped[1] - stopped[0]).max()) / (0.8 * 99), rel=0.05)


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


def _ring_cameras(n: int = 8, radius: float = 3.0, size: int = 24, focal: float = 20.0):
    from nerfstudio.cameras.cameras import Cameras

    poses = []
    for k in range(n):
        angle = 2 * np.pi * k / n
        eye = np.array([radius * np.cos(angle), radius * np.sin(angle), 0.8])
        back = eye / np.linalg.norm(eye)  # OpenGL camera: it looks along -z, z points back at the eye
        right = np.cross([0.0, 0.0, 1.0], back)
        right /= np.linalg.norm(right)
        up = np.cross(back, right)
        poses.append(np.stack([right, up, back, eye], axis=1))
    c2w = torch.tensor(np.stack(poses), dtype=torch.float32)
    return Cameras(camera_to_worlds=c2w, fx=focal, fy=focal, cx=size / 2, cy=size / 2, width=size, height=size)


def test_the_model_fits_its_box_to_the_dense_region_it_renders() -> None:
    from helpers.small_model import SMALL_MODEL
    from nerfstudio.data.scene_box import SceneBox

    from agrinerf_ns.model.model import AgriNeRFModelConfig

    torch.manual_seed(0)
    # empty space truly empty (softplus(-12) per unit: nothing over a 1000-unit ray), grids fine enough for the box
    small = {**SMALL_MODEL, "box_fit_rays": 4096, "density_shift": -12.0, "init_resolution": 24}
    cfg = AgriNeRFModelConfig(modalities=("rgb",), **small)
    model = cfg.setup(scene_box=SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=8, metadata={})
    dense = torch.tensor([[-0.5, -0.3, -0.2], [0.3, 0.5, 0.4]])  # world box of the only dense matter
    _fill_density(model, dense)
    box = model.grid.fit_box(model.surface_points, _ring_cameras(), step=0)
    assert box is not None
    torch.testing.assert_close(model.field.full_resolution_box(), box)
    margin = 0.1 * float((dense[1] - dense[0]).max())
    overlap = (torch.minimum(box[1], dense[1]) - torch.maximum(box[0], dense[0])).clamp(min=0).prod()
    # holds the dense region, but for the little seen of it (its underside) that costs more volume than it weighs
    assert float(overlap / (dense[1] - dense[0]).prod()) > 0.75
    assert bool((box[0] >= dense[0] - margin - 0.1).all() and (box[1] <= dense[1] + margin + 0.1).all())  # and no more
    assert math.prod(model.field.density_encoding.resolution) == pytest.approx(24**3, rel=0.15)
    # the resampled density is still dense where the matter is and empty around it
    coords, valid = model.field.to_grid(torch.stack([dense.mean(0), dense[1] + 0.3]))
    density = model.field.density_at(coords, valid)[:, 0]
    assert float(density[0]) > 1.0 and float(density[1]) < 0.1


def test_later_fits_only_shrink_the_box() -> None:
    from helpers.small_model import SMALL_MODEL
    from nerfstudio.data.scene_box import SceneBox

    from agrinerf_ns.model.model import AgriNeRFModelConfig

    torch.manual_seed(0)
    small = {**SMALL_MODEL, "box_fit_rays": 2048, "density_shift": -12.0, "init_resolution": 24}
    cfg = AgriNeRFModelConfig(modalities=("rgb",), box_fit_iters=(10, 20), **small)
    model = cfg.setup(scene_box=SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=8, metadata={})
    _fill_density(model, torch.tensor([[-0.3, -0.3, -0.3], [0.3, 0.3, 0.3]]))
    first = model.grid.fit_box(model.surface_points, _ring_cameras(), step=10)
    assert first is not None
    wider = torch.tensor([[-0.7, -0.6, -0.5], [0.6, 0.7, 0.5]])  # floaters grown around the matter
    _fill_density(model, wider)
    later = model.grid.fit_box(model.surface_points, _ring_cameras(), step=20)
    assert later is not None
    assert bool((later[0] >= first[0] - 1e-6).all() and (later[1] <= first[1] + 1e-6).all())  # shrink only
    _fill_density(model, torch.tensor([[-0.2, -0.1, -0.2], [0.1, 0.2, 0.2]]))
    smaller = model.grid.fit_box(model.surface_points, _ring_cameras(), step=30)
    assert smaller is not None and float((smaller[1] - smaller[0]).prod()) < 0.5 * float((later[1] - later[0]).prod())


def _fill_density(model, *boxes: torch.Tensor) -> None:
    """Density 30 (per scene unit) inside each world box of `boxes` (one VM component each), none elsewhere (zeroed
    planes and lines)."""
    with torch.no_grad():
        volume = model.field.density_encoding
        volume.plane_table.zero_()
        volume.line_table.zero_()
        axes = [torch.linspace(-1, 1, r) for r in volume.resolution]
        for k, dense in enumerate(boxes):
            lo, hi = model.field.mapping(dense[0]), model.field.mapping(dense[1])
            inside = [(a >= lo[i]) & (a <= hi[i]) for i, a in enumerate(axes)]
            volume.planes()[0][:, :, k] = 30.0 * (inside[1][:, None] & inside[0][None, :]).float()  # xy: (y, x)
            volume.lines()[0][:, k] = inside[2].float()  # line z


def test_a_fruit_head_keeps_the_masked_fruit_in_the_box(tmp_path) -> None:
    from helpers.small_model import SMALL_MODEL
    from nerfstudio.data.scene_box import SceneBox
    from PIL import Image

    from agrinerf_ns.model.model import AgriNeRFModelConfig

    canopy = torch.tensor([[-0.5, -0.4, -0.4], [0.4, 0.4, 0.4]])
    fruit = torch.tensor([[0.55, 0.55, 0.5], [0.7, 0.7, 0.65]])  # a little matter apart: too little for the scene fit

    def model_of_the_scene():  # a fresh model each time: a fit resamples the volumes into its box
        torch.manual_seed(0)
        small = {**SMALL_MODEL, "box_fit_rays": 4096, "density_shift": -12.0, "init_resolution": 24}
        cfg = AgriNeRFModelConfig(modalities=("rgb",), box_fruit_share=0.9, **small)
        model = cfg.setup(scene_box=SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=8, metadata={})
        _fill_density(model, canopy, fruit)
        return model

    def held(box: torch.Tensor, region: torch.Tensor) -> float:
        """Share of `region`'s volume inside `box`."""
        overlap = (torch.minimum(box[1], region[1]) - torch.maximum(box[0], region[0])).clamp(min=0).prod()
        return float(overlap / (region[1] - region[0]).prod())

    model = model_of_the_scene()
    cameras = _ring_cameras(size=64, focal=100.0)  # the fruit some pixels across
    masks = []  # each camera's pixels whose surface lies in the fruit, as a segmenter would mark them
    for k in range(cameras.shape[0]):
        points, hit, _ = model.surface_points(cameras.generate_rays(camera_indices=k).flatten())
        near = ((points >= fruit[0] - 0.05) & (points <= fruit[1] + 0.05)).all(-1) & (hit > 0.5)
        masks.append(tmp_path / f"{k}.png")
        Image.fromarray((255 * near.view(64, 64).numpy()).astype(np.uint8)).save(masks[-1])
    assert sum(int((np.asarray(Image.open(m)) > 0).sum()) >= 8 for m in masks) >= 3, "the fruit shows in several views"
    scene_only = model.grid.fit_box(model.surface_points, cameras, step=0)
    assert scene_only is not None and held(scene_only, canopy) > 0.7 and held(scene_only, fruit) == 0.0
    model = model_of_the_scene()
    with_fruit = model.grid.fit_box(model.surface_points, cameras, step=0, fruit_masks=masks)
    # the box holds the fruit's seen surfaces (its far corner faces no camera)
    assert with_fruit is not None and held(with_fruit, canopy) > 0.7 and held(with_fruit, fruit) > 0.5
    # masks without fruit leave the scene's fit as it is
    empty = tmp_path / "empty.png"
    Image.fromarray(np.zeros((64, 64), np.uint8)).save(empty)
    model = model_of_the_scene()
    torch.testing.assert_close(model.grid.fit_box(model.surface_points, cameras, 0, [empty] * 8), scene_only)


def test_a_dataset_with_sfm_points_starts_with_their_box(tmp_path) -> None:
    from helpers.model_scene import write_model_scene

    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
    from agrinerf_ns.model.model import AgriNeRFModelConfig

    data = write_model_scene(tmp_path / "scene", views=4, modalities=("rgb",))
    gen = np.random.default_rng(0)
    points = gen.uniform([-0.3, -0.2, -0.1], [0.2, 0.3, 0.25], size=(400, 3))
    lines = ["ply", "format ascii 1.0", f"element vertex {len(points)}", "property float x", "property float y",
             "property float z", "property uchar red", "property uchar green", "property uchar blue", "end_header"]  # fmt: skip
    lines += [f"{x:.6f} {y:.6f} {z:.6f} 128 128 128" for x, y, z in points]
    (data / "sparse_pc.ply").write_text("\n".join(lines) + "\n")
    meta = json.loads((data / "transforms.json").read_text())
    meta["ply_file_path"] = "sparse_pc.ply"
    (data / "transforms.json").write_text(json.dumps(meta))
    outputs = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")
    xyz = outputs.metadata["points3D_xyz"]
    assert xyz.shape == (400, 3)
    model = AgriNeRFModelConfig(modalities=("rgb",), init_resolution=16).setup(
        scene_box=outputs.scene_box, num_train_data=4, metadata=outputs.metadata
    )
    box = model.field.full_resolution_box()
    assert bool((box[0] <= xyz.min(0).values + 0.02).all() and (box[1] >= xyz.max(0).values - 0.02).all())
    assert float((box[1] - box[0]).prod()) < 0.5 * float((outputs.scene_box.aabb[1] - outputs.scene_box.aabb[0]).prod())
    missing = json.loads((data / "transforms.json").read_text())
    missing["ply_file_path"] = "nowhere.ply"
    (data / "transforms.json").write_text(json.dumps(missing))
    with pytest.raises(Exception, match="nowhere.ply"):
        AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train")


def test_the_voxel_target_applies_where_the_scale_is_metric() -> None:
    from helpers.small_model import SMALL_MODEL
    from nerfstudio.data.scene_box import SceneBox

    from agrinerf_ns.model.model import AgriNeRFModelConfig

    aabb = SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3]))
    cfg = AgriNeRFModelConfig(modalities=("rgb",), **{**SMALL_MODEL, "final_resolution": 100})
    assert cfg.setup(scene_box=aabb, num_train_data=8, metadata={}).grid.fine_enough() is None  # no scale: share only
    metric = cfg.setup(scene_box=aabb, num_train_data=8, metadata={"metres_per_unit": 0.5})
    check = metric.grid.fine_enough()
    assert check is not None
    # a 1-unit cube at 100^3 over 0.8 of the grid: cells of 1 / (0.8 * 99) units, 6.3 mm
    assert check(torch.tensor([[0.0] * 3, [1.0] * 3]))
    assert not check(torch.tensor([[0.0] * 3, [4.0] * 3]))  # 25 mm
    off = AgriNeRFModelConfig(modalities=("rgb",), box_voxel_target_m=0.0, **SMALL_MODEL)
    assert off.setup(scene_box=aabb, num_train_data=8, metadata={"metres_per_unit": 0.5}).grid.fine_enough() is None


def test_a_voxel_target_the_grids_cannot_reach_keeps_the_surface_share() -> None:
    from helpers.small_model import SMALL_MODEL
    from nerfstudio.data.scene_box import SceneBox

    from agrinerf_ns.model.model import AgriNeRFModelConfig

    dense = torch.tensor([[-0.5, -0.3, -0.2], [0.3, 0.5, 0.4]])
    boxes = {}
    for name, metadata, final in (("no scale", {}, 24), ("unreachable", {"metres_per_unit": 1.0}, 24),
                                  ("reachable", {"metres_per_unit": 1.0}, 400)):  # fmt: skip
        torch.manual_seed(0)
        small = {**SMALL_MODEL, "box_fit_rays": 4096, "density_shift": -12.0, "init_resolution": 24,
                 "final_resolution": final}  # fmt: skip
        cfg = AgriNeRFModelConfig(modalities=("rgb",), box_voxel_target_m=0.005, **small)
        model = cfg.setup(scene_box=SceneBox(aabb=torch.tensor([[-1.0] * 3, [1.0] * 3])), num_train_data=8,
                          metadata=metadata)  # fmt: skip
        _fill_density(model, dense)
        boxes[name] = model.grid.fit_box(model.surface_points, _ring_cameras(), step=0)
        check = model.grid.fine_enough()
        assert (check is None) == (name == "no scale")
        if check is not None:
            assert check(boxes[name]) == (name == "reachable")
    torch.testing.assert_close(boxes["unreachable"], boxes["no scale"])  # 2 cm cells at 24^3: hold 95%
    volume = {name: float((box[1] - box[0]).prod()) for name, box in boxes.items()}
    assert volume["reachable"] >= volume["no scale"]  # 5 mm cells at 400^3 without shrinking as far


def test_a_large_point_cloud_is_thinned_and_fitted_alike() -> None:
    gen = torch.Generator().manual_seed(3)
    points = torch.rand(100_000, 3, generator=gen) * torch.tensor([6.0, 2.0, 1.0])
    box = fit_box(points)
    assert box is not None
    inside = ((points >= box[0]) & (points <= box[1])).all(dim=-1).float().mean()
    assert float(inside) >= 0.95 and bool((box[1] - box[0] < torch.tensor([6.0, 2.0, 1.0]) * 1.2).all())
