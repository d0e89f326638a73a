"""Device bugs caught on a CPU: fake CUDA tensors (``FakeTensorMode``) through the parts that take device-carrying
inputs (the static check of tensor factories: ``test_device_scan.py``; whole steps: ``test_fake_device_step.py``)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torch._subclasses.fake_tensor import FakeTensorMode

ROOT = Path(__file__).resolve().parent.parent


@pytest.fixture
def fake_cuda():
    """A mode in which tensors made with ``device="cuda"`` keep that device without a GPU; mixing them with CPU
    tensors raises a device mismatch, as on a GPU."""
    with FakeTensorMode(allow_non_fake_inputs=True) as mode:
        yield mode


def test_fake_cuda_catches_a_device_mismatch(fake_cuda) -> None:
    """The harness itself: a CPU tensor meeting a fake CUDA one fails, as it would on a GPU."""
    with pytest.raises(Exception, match="(?i)device"):
        _ = torch.ones(3, device="cuda") / torch.tensor([1.0, 2.0, 3.0])


def test_box_voxel_arithmetic_takes_the_device_of_its_box(monkeypatch) -> None:
    """The tensor `box_voxel` builds lives on its box's device: checked by recording the factory's device."""
    from agrinerf_ns.model import grid_mapping

    made = []
    real = torch.tensor

    def recording(*args, **kwargs):
        made.append(kwargs.get("device"))
        return real(*args, **{**kwargs, "device": "cpu"})

    box = torch.tensor([[-1.0, -0.5, -0.2], [1.0, 0.5, 0.2]])
    expected = grid_mapping.box_voxel(box, 0.8, 20)
    monkeypatch.setattr(grid_mapping.torch, "tensor", recording)
    assert grid_mapping.box_voxel(box, 0.8, 20) == expected
    assert made and all(d is not None and torch.device(d) == box.device for d in made)


def test_box_voxel_under_fake_cuda_raises_no_device_mismatch(fake_cuda, monkeypatch) -> None:
    """`box_voxel` on a fake CUDA box runs to its final read-back (``float()``, which a fake tensor cannot answer:
    ``aten._local_scalar_dense``) without a device mismatch; the same call with its resolution tensor planted on the
    CPU (the bug this guards against) stops earlier, at the device mismatch."""
    from torch._subclasses.fake_tensor import DataDependentOutputException, FakeTensorDeviceMismatchError

    from agrinerf_ns.model import grid_mapping

    monkeypatch.setattr(grid_mapping, "axis_resolution", lambda *a, **k: (40, 20, 8))
    box = torch.tensor([[-1.0, -0.5, -0.2], [1.0, 0.5, 0.2]], device="cuda")
    with pytest.raises(DataDependentOutputException, match="_local_scalar_dense"):
        grid_mapping.box_voxel(box, 0.8, 20)
    real = torch.tensor
    monkeypatch.setattr(torch, "tensor", lambda *a, **k: real(*a, **{**k, "device": "cpu"}))
    with pytest.raises(FakeTensorDeviceMismatchError, match="cuda:0 and cpu"):
        grid_mapping.box_voxel(box, 0.8, 20)


def test_box_mapping_under_fake_cuda(fake_cuda) -> None:
    """The contraction of CUDA points into the grid and back."""
    from agrinerf_ns.model.grid_mapping import contract_axes, uncontract_axes

    points = torch.rand(64, 3, device="cuda") * 2.0 - 1.0
    coords = contract_axes(points, 0.8)
    back = uncontract_axes(coords, 0.8)
    assert coords.device.type == "cuda" and back.device.type == "cuda"


def test_event_pair_targets_with_learnt_cuda_thresholds(fake_cuda) -> None:
    """EvDeblurNeRF's pair targets: the pairs' polarity comes from the CPU stream, learnt thresholds live on CUDA."""
    from agrinerf_ns.model.event_pairs import pair_targets

    polarity = torch.tensor([1, -1, 1, -1], dtype=torch.int64)  # the CPU pairs (EventPairs.sample)
    log_threshold = torch.full((2,), math.log(0.25), device="cuda")
    c = log_threshold.exp()
    target = pair_targets(polarity, c[0], c[1])
    assert target.device.type == "cuda" and tuple(target.shape) == (4, 1)
    assert pair_targets(polarity, 0.25, 0.25).device.type == "cpu"  # fixed thresholds: the polarity's device


def test_trajectory_poses_on_fake_cuda(fake_cuda) -> None:
    """The trajectory's torch interpolation (blur, events, thermal camera) stays on the query times' device."""
    from scipy.spatial.transform import Rotation

    from agrinerf_ns.trajectory import CameraTrajectory, rotvec_matrix

    rot = Rotation.from_rotvec([[0.0, 0.0, 0.0], [0.1, 0.2, 0.0], [0.1, 0.3, 0.2]]).as_matrix()
    c2w = np.concatenate([rot, np.arange(9.0).reshape(3, 3, 1)], axis=-1)
    traj = CameraTrajectory(np.array([0.0, 1.0, 2.0]), c2w)
    times = torch.zeros(5, 2, dtype=torch.float64, device="cuda")
    poses = traj.poses_at_tensor(times, dtype=torch.float64)
    assert poses.device.type == "cuda" and tuple(poses.shape) == (5, 2, 3, 4)
    assert rotvec_matrix(torch.zeros(4, 3, device="cuda")).device.type == "cuda"


def test_reposed_rays_on_fake_cuda(fake_cuda) -> None:
    """Blur and event renders: rays at other times, with the rays, the times and the rig offset on CUDA."""
    from nerfstudio.cameras.rays import RayBundle

    from agrinerf_ns.model.timed_rays import exposure_times, reposed_rays
    from agrinerf_ns.trajectory import CameraTrajectory

    c2w = np.tile(np.eye(4)[:3], (3, 1, 1))
    c2w[:, 0, 3] = [0.0, 1.0, 2.0]
    traj = CameraTrajectory(np.array([0.0, 1.0, 2.0]), c2w)
    n = 6
    bundle = RayBundle(
        origins=torch.zeros(n, 3, device="cuda"),
        directions=torch.ones(n, 3, device="cuda") / math.sqrt(3.0),
        pixel_area=torch.ones(n, 1, device="cuda"),
        camera_indices=torch.zeros(n, 1, dtype=torch.long, device="cuda"),
    )
    exposure = torch.zeros(n, 2, dtype=torch.float64, device="cuda")
    times = exposure_times(exposure, 3)
    centre = torch.tensor([0.01, 0.0, 0.0], device="cuda")
    moved = reposed_rays(
        bundle, traj, torch.zeros(n, dtype=torch.float64), times, camera_centre=centre, plane_depth=2.0
    )
    assert moved.origins.device.type == "cuda" and tuple(moved.origins.shape) == (3 * n, 3)


def test_rigid_blur_kernel_on_fake_cuda(fake_cuda) -> None:
    """The learnt blur kernel's motions for CUDA camera rows, the kernel's parameters on CUDA."""
    from agrinerf_ns.model.rigid_blur import RigidBlurKernel

    with torch.device("cuda"):
        kernel = RigidBlurKernel(num_images=4)
    outputs = kernel(torch.tensor([0, 3, 1], device="cuda"))
    assert all(t.device.type == "cuda" for t in outputs)


def test_poses_in_torch_equal_scipys() -> None:
    """The torch interpolation equals scipy's (the CPU path before it) within float64 rounding: inside, at the
    samples, and extrapolated on both sides, for every extrapolation mode."""
    from scipy.spatial.transform import Rotation

    from agrinerf_ns.trajectory import CameraTrajectory

    gen = np.random.default_rng(0)
    times = np.sort(gen.uniform(0.0, 2.0, 12)) + 1.7e9
    c2w = np.concatenate(
        [Rotation.from_rotvec(gen.normal(0, 0.8, (12, 3))).as_matrix(), gen.normal(0, 2, (12, 3, 1))], -1
    )
    queries = np.concatenate([gen.uniform(times[0] - 0.3, times[-1] + 0.3, 200), times, [times[0] + 1e-9]])
    for mode in ("linear", "clamp"):
        traj = CameraTrajectory(times, c2w, extrapolate=mode)
        expected = traj.poses_at(queries)
        got = traj.poses_at_tensor(torch.from_numpy(queries), dtype=torch.float64).numpy()
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    one = CameraTrajectory(times[:1], c2w[:1])
    np.testing.assert_allclose(
        one.poses_at_tensor(torch.from_numpy(queries[:5]), dtype=torch.float64).numpy(), one.poses_at(queries[:5])
    )
    strict = CameraTrajectory(times, c2w, extrapolate="error")
    with pytest.raises(ValueError, match="leave the trajectory"):
        strict.poses_at_tensor(torch.tensor([times[-1] + 1.0], dtype=torch.float64))


def test_rotvec_matrix_at_the_extremes() -> None:
    """Rodrigues' formula against scipy at zero, tiny, ordinary and near-pi angles."""
    from scipy.spatial.transform import Rotation

    from agrinerf_ns.trajectory import rotvec_matrix

    axis = np.array([0.3, -0.5, 0.81]) / np.linalg.norm([0.3, -0.5, 0.81])
    vectors = np.stack([axis * a for a in (0.0, 1e-12, 1e-6, 9.9e-5, 1e-4, 0.5, 3.0, math.pi - 1e-9)])
    got = rotvec_matrix(torch.from_numpy(vectors)).numpy()
    np.testing.assert_allclose(got, Rotation.from_rotvec(vectors).as_matrix(), rtol=0, atol=1e-14)


def test_gpu_check_commands_all_parse_and_a_wrong_one_is_named(tmp_path: Path) -> None:
    """`scripts/gpu_check.sh --dry-run` parses every command it would run with that command's own parser; a wrong
    option makes it fail and names the command."""
    import subprocess

    done = subprocess.run(["bash", str(ROOT / "scripts" / "gpu_check.sh"), "--dry-run", "--out", str(tmp_path)],
                          check=False, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    ok = [line for line in done.stdout.splitlines() if line.startswith("ok ")]
    checks = {line.split(":")[0].split(maxsplit=1)[1] for line in ok}
    assert {"scene", "dataset", "train agrinerf", "eval agrinerf", "render", "count", "step time"} <= checks
    assert len(ok) == 2 + 2 * 6 + 3  # scene, dataset, train + eval per preset, render, count, step time

    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import gpu_check
    finally:
        sys.path.pop(0)
    plan = gpu_check.steps(gpu_check.Args(out=tmp_path, presets=("agrinerf-lite",)))
    broken = [s._replace(argv=[*s.argv, "--no-such-option", "1"]) if s.check == "count" else s for s in plan]
    lines = gpu_check.dry_run(broken)
    assert [line.split(":")[0] for line in lines if line.startswith("FAILED")] == ["FAILED  count"]
