"""A rig that drives along x while turning about y (four poses), and rays of its frames: what the tests of the
model's timed renders (blur, events, the thermal camera's rays) draw on."""

import math

import numpy as np
import torch
from nerfstudio.cameras.rays import RayBundle

from agrinerf_ns.trajectory import CameraTrajectory


def yawing_trajectory(dt: float = 0.1, yaw_rate: float = 0.3, speed: float = 1.0) -> CameraTrajectory:
    """Four poses `dt` seconds apart, 3 units from the origin along z, moving along x at `speed` units per second
    while turning about y at `yaw_rate` radians per second."""
    times = np.arange(4) * dt
    c2w = np.zeros((4, 3, 4))
    for i, t in enumerate(times):
        yaw = yaw_rate * t
        c2w[i, :3, :3] = [[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]]
        c2w[i, :3, 3] = [speed * t, 0.0, 3.0]
    return CameraTrajectory(times, c2w)


def trajectory_rays(trajectory: CameraTrajectory, n: int, cameras: int = 4) -> RayBundle:
    """`n` unit rays around the optical axis (OpenGL: -z) of the trajectory's first `cameras` poses, ray i from
    pose i % cameras (its camera index)."""
    gen = torch.Generator().manual_seed(1)
    index = torch.arange(n) % cameras
    poses = torch.from_numpy(trajectory.poses_at(trajectory.times[index.numpy()])).float()
    local = torch.nn.functional.normalize(
        torch.randn(n, 3, generator=gen) * 0.2 + torch.tensor([0.0, 0.0, -1.0]), dim=-1
    )
    return RayBundle(
        origins=poses[:, :3, 3].clone(),
        directions=(poses[:, :3, :3] @ local[..., None])[..., 0],
        pixel_area=torch.full((n, 1), 1e-4),
        camera_indices=index[:, None],
    )
