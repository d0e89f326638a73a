"""The three-camera rig (RGB cam0, thermal cam1, event cam2): intrinsics, extrinsics, a smooth path, odometry.

Poses are camera-to-world 4x4 matrices with OpenCV camera axes (x right, y down, z forward). The rig looks across
the row (+y in the world) while it moves along it (+x), so the scene is roughly forward-facing.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.synth.config import SynthConfig
from agrinerf_ns.synth.raycast import PinholeRadtan

T0 = 0.1
"""Time of the first RGB frame in seconds (events start half a frame earlier)."""
THERMAL_DELAY = 0.004
"""Thermal frames are triggered with the RGB ones and exposed this much later (seconds)."""


def rot_x(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def make_T(R: np.ndarray, t: np.ndarray) -> Float[np.ndarray, "4 4"]:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, t
    return T


def inv_T(T: Float[np.ndarray, "4 4"]) -> Float[np.ndarray, "4 4"]:
    return make_T(T[:3, :3].T, -T[:3, :3].T @ T[:3, 3])


def quat_from_R(R: Float[np.ndarray, "3 3"]) -> Float[np.ndarray, "4"]:
    """Unit quaternion (qx, qy, qz, qw) with qw >= 0."""
    m = R
    tr = np.trace(m)
    if tr > 0:
        s = np.sqrt(tr + 1.0) * 2
        q = np.array([(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2]) * 2
        q = np.array([0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s])
    elif m[1, 1] > m[2, 2]:
        s = np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2]) * 2
        q = np.array([(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s])
    else:
        s = np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1]) * 2
        q = np.array([(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s])
    q /= np.linalg.norm(q)
    return -q if q[3] < 0 else q


def R_from_quat(q: Float[np.ndarray, "4"]) -> Float[np.ndarray, "3 3"]:
    """Rotation matrix of a unit quaternion (qx, qy, qz, qw)."""
    x, y, z, w = q / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def _pinhole(
    w: int, h: int, hfov_deg: float, aspect_f: float, c_off: Tuple[float, float], dist: tuple
) -> PinholeRadtan:
    fx = w / 2 / np.tan(np.radians(hfov_deg) / 2)
    return PinholeRadtan(
        w,
        h,
        round(fx, 4),
        round(fx * aspect_f, 4),
        round((w - 1) / 2 + c_off[0] * w, 4),
        round((h - 1) / 2 + c_off[1] * h, 4),
        dist,
    )


@dataclass
class Rig:
    """Cameras, fixed extrinsics and the continuous path of cam0."""

    cams: Dict[str, PinholeRadtan]
    """'rgb', 'thermal', 'event'."""
    T_c_c0: Dict[str, Float[np.ndarray, "4 4"]]
    """Maps points from the RGB camera frame into each camera's frame."""
    start_x: float
    height: float
    distance: float
    pitch: float
    speed: float
    wobble: Float[np.ndarray, "5 2"]
    """Phase and amplitude scale of the y, z, yaw, pitch, roll wobbles."""

    def pose(self, t: float, cam: str = "rgb") -> Float[np.ndarray, "4 4"]:
        """Camera-to-world pose of ``cam`` at time ``t`` (seconds)."""
        ph, sc = self.wobble[:, 0], self.wobble[:, 1]
        tt = t - T0
        pos = np.array(
            [
                self.start_x + self.speed * tt,
                -self.distance + 0.04 * sc[0] * np.sin(2 * np.pi * 0.23 * tt + ph[0]),
                self.height + 0.03 * sc[1] * np.sin(2 * np.pi * 0.41 * tt + ph[1]),
            ]
        )
        base = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])  # columns: cam x, y, z in the world
        yaw = np.radians(1.5) * sc[2] * np.sin(2 * np.pi * 0.17 * tt + ph[2])
        pitch = self.pitch + np.radians(1.0) * sc[3] * np.sin(2 * np.pi * 0.29 * tt + ph[3])
        roll = np.radians(0.7) * sc[4] * np.sin(2 * np.pi * 0.37 * tt + ph[4])
        R = base @ rot_y(yaw) @ rot_x(pitch) @ rot_z(roll)
        T = make_T(R, pos)
        return T if cam == "rgb" else T @ inv_T(self.T_c_c0[cam])


def build_rig(config: SynthConfig) -> Rig:
    """The rig of ``config``: cameras scaled to the configured resolutions, fixed extrinsics, seeded wobble."""
    rng = np.random.default_rng([config.seed, 23])
    tw, th = config.thermal_wh
    ew, eh = config.event_wh
    cams = {
        "rgb": _pinhole(
            config.width, config.height, config.rgb_hfov_deg, 1.001, (0.011, -0.008), (-0.06, 0.012, 4e-4, -3e-4)
        ),
        "thermal": _pinhole(tw, th, config.thermal_hfov_deg, 0.998, (-0.009, 0.012), (-0.11, 0.03, 6e-4, 2e-4)),
        "event": _pinhole(ew, eh, config.event_hfov_deg, 1.0, (0.006, 0.01), (-0.08, 0.015, -5e-4, 4e-4)),
    }
    # points in cam0 -> camN: camN sits at offset o in cam0's frame, slightly rotated
    R1 = rot_x(np.radians(0.6)) @ rot_y(np.radians(-0.8)) @ rot_z(np.radians(0.3))
    R2 = rot_x(np.radians(-0.5)) @ rot_y(np.radians(0.7)) @ rot_z(np.radians(-0.4))
    o1, o2 = np.array([0.07, 0.012, -0.005]), np.array([-0.065, -0.02, 0.004])
    T_c_c0 = {"rgb": np.eye(4), "thermal": make_T(R1, -R1 @ o1), "event": make_T(R2, -R2 @ o2)}
    if config.scene == "orchard":
        distance, height, pitch = 2.8, 1.45, np.radians(3.0)
    else:
        distance, height, pitch = 1.55, 0.95, np.radians(-12.0)
    wobble = np.stack([rng.uniform(0, 2 * np.pi, 5), rng.uniform(0.5, 1.0, 5)], -1)
    return Rig(cams, T_c_c0, 0.0, height, distance, pitch, config.speed, wobble)


def frame_times(config: SynthConfig) -> Float[np.ndarray, " n"]:
    """RGB frame timestamps in seconds."""
    return T0 + np.arange(config.views) / config.fps


def heldout_poses(rig: Rig, config: SynthConfig) -> List[Tuple[float, np.ndarray]]:
    """(time, RGB camera-to-world pose) of held-out views: between frames, shifted off the path."""
    n = config.num_heldout
    out = []
    for k in range(n):
        t = T0 + (k + 0.5) * (config.views - 1) / max(n, 1) / config.fps
        shift = np.array([0.0, 0.12 * (-1) ** k, 0.25 * (-1) ** (k // 2)])  # camera frame: down, forward
        T = rig.pose(t)
        T = T.copy()
        T[:3, 3] += T[:3, :3] @ shift
        out.append((float(t), T))
    return out


def odometry(poses: List[np.ndarray], seed: int) -> List[np.ndarray]:
    """Odometry-like poses: the true ones with a slow random-walk drift (about 1 % of distance) and jitter."""
    rng = np.random.default_rng([seed, 31])
    out = []
    drift_t = np.zeros(3)
    drift_r = np.zeros(3)
    bias = rng.normal(0, 0.006, 3)
    prev = poses[0][:3, 3]
    for T in poses:
        step = np.linalg.norm(T[:3, 3] - prev)
        prev = T[:3, 3]
        drift_t += bias * step / 0.6 + rng.normal(0, 0.0015, 3)
        drift_r += rng.normal(0, np.radians(0.04), 3)
        Rn = rot_x(drift_r[0] + rng.normal(0, np.radians(0.05))) @ rot_y(drift_r[1]) @ rot_z(drift_r[2])
        t_noisy = T[:3, 3] + drift_t + rng.normal(0, 0.002, 3)
        out.append(make_T(Rn @ T[:3, :3], t_noisy))
    return out
