"""agrinerf_ns.trajectory: poses between frames against the synthetic rig's continuous path (the truth)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from scipy.spatial.transform import Rotation

from agrinerf_ns.synth import SynthConfig
from agrinerf_ns.synth.camera_rig import build_rig, frame_times
from agrinerf_ns.trajectory import CameraTrajectory, TrajectoryError, exposure_subtimes


def _errors(a: np.ndarray, b: np.ndarray) -> tuple:
    """(max translation error in m, max rotation error in degrees) between pose stacks [..., 3, 4]."""
    dt = np.linalg.norm(a[..., :3, 3] - b[..., :3, 3], axis=-1).max()
    rel = Rotation.from_matrix(np.swapaxes(a[..., :3, :3], -1, -2).reshape(-1, 3, 3) @ b[..., :3, :3].reshape(-1, 3, 3))
    return float(dt), float(np.degrees(rel.magnitude()).max())


def _assert_close(a: np.ndarray, b: np.ndarray, max_dt: float, max_dr_deg: float) -> None:
    dt, dr = _errors(a, b)
    assert dt < max_dt and dr < max_dr_deg, (dt, dr)


@pytest.mark.parametrize("scene", ["orchard", "garden"])
def test_interpolation_between_frames_matches_the_rig_path(scene: str) -> None:
    config = SynthConfig(scene=scene, seed=3)
    rig = build_rig(config)
    times = frame_times(config)
    frames = np.stack([rig.pose(float(t)) for t in times])
    traj = CameraTrajectory(times, frames)

    at_frames = traj.poses_at(times)
    _assert_close(at_frames, frames[:, :3], 1e-12, 1e-6)  # exact at the samples

    # event times and exposure sub-times: anywhere between frames, where the rig's path is the truth
    rng = np.random.default_rng(0)
    query = np.sort(rng.uniform(times[0], times[-1], 200))
    truth = np.stack([rig.pose(float(t))[:3] for t in query])
    dt, dr = _errors(traj.poses_at(query), truth)
    assert dt < 1e-3 and dr < 0.01, (dt, dr)  # the wobble is smooth: slerp + lerp over 0.1 s is sub-millimetre

    # the nearest frame's pose (no interpolation) is centimetres off: the comparison above can fail
    nearest = frames[np.abs(query[:, None] - times[None]).argmin(1), :3]
    dt_nearest, _ = _errors(nearest, truth)
    assert dt_nearest > 50 * dt and dt_nearest > 0.02


def test_exposure_sub_poses_span_the_rig_motion_over_the_exposure() -> None:
    config = SynthConfig.tiny(lighting="dark")
    rig = build_rig(config)
    times = frame_times(config)
    traj = CameraTrajectory(times, np.stack([rig.pose(float(t)) for t in times]))
    e = config.rgb_exposure_s(0.1)
    exposure = np.stack([times - e / 2, times + e / 2], -1)
    sub = exposure_subtimes(exposure, 5)
    assert sub.shape == (config.views, 5)
    np.testing.assert_allclose(sub[:, 2], times, atol=1e-12)  # odd K: the middle sub-time is the frame's time
    np.testing.assert_allclose(np.diff(sub, axis=1), e / 5, atol=1e-12)
    poses = traj.poses_at(sub)  # includes times before the first and after the last frame (extrapolated)
    assert poses.shape == (config.views, 5, 3, 4)
    truth = np.stack([[rig.pose(float(t))[:3] for t in row] for row in sub])
    dt, dr = _errors(poses, truth)
    assert dt < 1e-3 and dr < 0.02, (dt, dr)
    travel = np.linalg.norm(poses[:, -1, :3, 3] - poses[:, 0, :3, 3], axis=-1)
    np.testing.assert_allclose(travel, config.speed * e * 4 / 5, rtol=0.05)  # 0.75 m/s along the row


def test_extrapolation_modes_and_constant_velocity() -> None:
    omega, velocity = np.array([0.1, -0.3, 0.2]), np.array([0.75, 0.02, -0.01])

    def pose(t: np.ndarray) -> np.ndarray:
        out = np.zeros((len(t), 3, 4))
        out[:, :3, :3] = Rotation.from_rotvec(t[:, None] * omega[None]).as_matrix()
        out[:, :3, 3] = t[:, None] * velocity[None]
        return out

    times = np.array([0.0, 0.1, 0.2, 0.3])
    traj = CameraTrajectory(times, pose(times))
    query = np.array([-0.05, 0.05, 0.17, 0.35])
    _assert_close(traj.poses_at(query), pose(query), 1e-12, 1e-9)  # constant velocity is reproduced exactly

    clamp = CameraTrajectory(times, pose(times), extrapolate="clamp").poses_at(np.array([-1.0, 2.0]))
    _assert_close(clamp, pose(np.array([0.0, 0.3])), 1e-12, 1e-9)
    strict = CameraTrajectory(times, pose(times), extrapolate="error")
    with pytest.raises(TrajectoryError, match="leave"):
        strict.poses_at(np.array([0.31]))
    single = CameraTrajectory(times[:1], pose(times[:1])).poses_at(np.array([[5.0, 6.0]]))
    assert single.shape == (1, 2, 3, 4) and _errors(single[0], pose(np.zeros(2))) < (1e-12, 1e-9)


def test_a_change_of_world_frame_commutes_with_interpolation() -> None:
    rng = np.random.default_rng(1)
    times = np.cumsum(rng.uniform(0.05, 0.15, 6))
    c2w = np.zeros((6, 4, 4))
    c2w[:, :3, :3] = Rotation.random(6, random_state=2).as_matrix()
    c2w[:, :3, 3] = rng.normal(size=(6, 3))
    c2w[:, 3, 3] = 1
    A = np.zeros((3, 4))
    A[:, :3], A[:, 3] = Rotation.random(random_state=3).as_matrix(), [0.3, -1.0, 2.0]
    scale = 0.37
    query = rng.uniform(times[0] - 0.05, times[-1] + 0.05, 20)
    moved = CameraTrajectory(times, c2w).transformed(A, scale).poses_at(query)
    direct = CameraTrajectory(times, c2w).poses_at(query)
    expected = np.concatenate([A[:, :3] @ direct[..., :3], scale * (direct[..., 3:] + 0)], -1)
    expected[..., 3] = scale * (direct[..., :3, 3] @ A[:, :3].T + A[:, 3])
    _assert_close(moved, expected, 1e-12, 1e-9)


def test_bad_samples_and_tensor_queries() -> None:
    eye = np.tile(np.eye(4), (3, 1, 1))
    with pytest.raises(TrajectoryError, match="increase strictly"):
        CameraTrajectory(np.array([0.0, 0.1, 0.1]), eye)
    with pytest.raises(TrajectoryError, match="finite"):
        CameraTrajectory(np.array([0.0, 0.1, np.nan]), eye)
    with pytest.raises(ValueError, match="k must be"):
        exposure_subtimes(np.zeros((2, 2)), 0)
    traj = CameraTrajectory(np.array([1.7e9, 1.7e9 + 0.1]), eye[:2])  # a Unix clock: float64 times
    out = traj.poses_at_tensor(torch.tensor([1.7e9 + 0.05], dtype=torch.float64))
    assert out.shape == (1, 3, 4) and out.dtype == torch.float32
    torch.testing.assert_close(out[0], torch.eye(4)[:3])
    zero = exposure_subtimes(np.array([[2.0, 2.0]]), 3)  # a zero-length exposure: every sub-time is the frame time
    np.testing.assert_array_equal(zero, [[2.0, 2.0, 2.0]])
