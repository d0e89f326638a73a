"""A continuous camera trajectory: the camera-to-world pose at any time from timed pose samples.

Rotations are interpolated by spherical linear interpolation (scipy's :class:`~scipy.spatial.transform.Slerp`),
translations linearly, between consecutive samples; before the first and after the last sample the end segment's
constant velocity is continued (``extrapolate="linear"``), the end pose is held (``"clamp"``), or a query raises
(``"error"``). This is what EvDeblurNeRF does for event times (poses at event times by interpolation of the frame
poses) and what a blur model needs for sub-poses across an exposure.

The samples are the dataset's frame poses, or a denser odometry where the capture has one. Any rigid change of
world frame applied to every sample (and a uniform scale of the translations, as Nerfstudio's dataparser applies),
and any fixed change of camera axes (OpenCV <-> OpenGL), commutes with this interpolation, so a trajectory can be
built in the capture's frame and moved into the dataparser's with :meth:`CameraTrajectory.transformed`.

The samples' file format is TUM's ("t tx ty tz qx qy qz qw" per line: :func:`read_tum`, :func:`write_tum`).

Times are float64 seconds in the capture's clock (real clocks are Unix times near 1.7e9 s, which float32 cannot
resolve below minutes: subtract a reference before any float32 use).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, Literal, Optional, Tuple, Union

import numpy as np
from jaxtyping import Float
from scipy.spatial.transform import Rotation, Slerp

if TYPE_CHECKING:  # torch is imported only when a tensor is asked for (agrinerf-synth does not load it)
    import torch
    from torch import Tensor

Extrapolate = Literal["linear", "clamp", "error"]


class TrajectoryError(ValueError):
    """Invalid trajectory samples, a query outside the samples' time span with ``extrapolate="error"``, or a TUM file
    that is missing or malformed (the message names the file and line)."""


class CameraTrajectory:
    """Camera-to-world poses at any time from samples (times strictly increasing, rigid 3x4 or 4x4 poses)."""

    def __init__(
        self,
        times: Float[np.ndarray, " n"],
        c2w: Union[Float[np.ndarray, "n 3 4"], Float[np.ndarray, "n 4 4"]],
        extrapolate: Extrapolate = "linear",
    ) -> None:
        times = np.asarray(times, dtype=np.float64).reshape(-1)
        c2w = np.asarray(c2w, dtype=np.float64)
        if c2w.ndim != 3 or c2w.shape[1:] not in ((3, 4), (4, 4)) or c2w.shape[0] != times.size:
            raise TrajectoryError(f"poses must be [n, 3, 4] or [n, 4, 4] for {times.size} times, got {c2w.shape}")
        if times.size == 0:
            raise TrajectoryError("a trajectory needs at least one pose sample")
        if not (np.all(np.isfinite(times)) and np.all(np.isfinite(c2w))):
            raise TrajectoryError("pose samples and their times must be finite")
        if np.any(np.diff(times) <= 0):
            bad = int(np.argmax(np.diff(times) <= 0)) + 1
            raise TrajectoryError(f"sample times must increase strictly (sample {bad} at {times[bad]!r} s)")
        if extrapolate not in ("linear", "clamp", "error"):
            raise TrajectoryError(f"extrapolate must be linear, clamp or error, got {extrapolate!r}")
        self.times = times
        self.extrapolate: Extrapolate = extrapolate
        self.translations: Float[np.ndarray, "n 3"] = c2w[:, :3, 3].copy()
        self.rotations = Rotation.from_matrix(c2w[:, :3, :3])
        self._slerp = Slerp(times, self.rotations) if times.size > 1 else None

    def __repr__(self) -> str:
        return f"CameraTrajectory({len(self)} samples, {self.t_min:.6f}..{self.t_max:.6f} s, {self.extrapolate})"

    def __len__(self) -> int:
        return int(self.times.size)

    @property
    def t_min(self) -> float:
        return float(self.times[0])

    @property
    def t_max(self) -> float:
        return float(self.times[-1])

    def poses_at(self, t: Float[np.ndarray, "*b"]) -> Float[np.ndarray, "*b 3 4"]:
        """Camera-to-world poses (float64, the samples' axes and world frame) at times ``t`` (seconds)."""
        t = np.asarray(t, dtype=np.float64)
        flat = t.reshape(-1)
        if not np.all(np.isfinite(flat)):
            raise TrajectoryError("query times must be finite")
        out = np.zeros((flat.size, 3, 4))
        if flat.size == 0:
            return out.reshape(*t.shape, 3, 4)
        outside = (flat < self.t_min) | (flat > self.t_max)
        if self.extrapolate == "error" and np.any(outside):
            raise TrajectoryError(
                f"query times {flat.min():.6f}..{flat.max():.6f} s leave the trajectory's "
                f"{self.t_min:.6f}..{self.t_max:.6f} s"
            )
        if self._slerp is None:  # one sample: a constant pose
            out[:, :3, :3] = self.rotations.as_matrix()[0]
            out[:, :3, 3] = self.translations[0]
            return out.reshape(*t.shape, 3, 4)
        inside = np.clip(flat, self.t_min, self.t_max)
        out[:, :3, :3] = self._slerp(inside).as_matrix()
        out[:, :3, 3] = np.stack([np.interp(inside, self.times, self.translations[:, k]) for k in range(3)], -1)
        if self.extrapolate == "linear" and np.any(outside):
            for sel, i0, i1, t_ref in ((flat < self.t_min, 0, 1, self.t_min), (flat > self.t_max, -2, -1, self.t_max)):
                if not np.any(sel):
                    continue
                dt = self.times[i1] - self.times[i0]
                # constant angular and linear velocity of the end segment, continued from the end sample
                omega = (self.rotations[i0].inv() * self.rotations[i1]).as_rotvec() / dt
                velocity = (self.translations[i1] - self.translations[i0]) / dt
                i_end = 0 if i0 == 0 else -1
                tau = flat[sel] - t_ref
                rot = self.rotations[i_end] * Rotation.from_rotvec(tau[:, None] * omega[None])
                out[sel, :3, :3] = rot.as_matrix()
                out[sel, :3, 3] = self.translations[i_end] + tau[:, None] * velocity[None]
        return out.reshape(*t.shape, 3, 4)

    def poses_at_tensor(self, t: Float[Tensor, "*b"], dtype: Optional[torch.dtype] = None) -> Float[Tensor, "*b 3 4"]:
        """:meth:`poses_at` in torch on ``t``'s device (pass float64 times): the same interpolation and extrapolation
        (rotations: ``R_i exp(alpha log(R_i^T R_i+1))``, as scipy's Slerp; translations: linear), so a training step
        on a GPU computes its rays' poses there without a round trip through the CPU. Poses in ``dtype`` (default
        float32), computed in float64; equal to :meth:`poses_at` within float64 rounding. No gradient flows to the
        times. With ``extrapolate="error"`` the check of the query times reads them back (a device sync)."""
        import torch

        tables = self._tables(t.device)
        flat = t.detach().reshape(-1).to(torch.float64)
        if self.extrapolate == "error" and flat.numel() and bool(((flat < self.t_min) | (flat > self.t_max)).any()):
            raise TrajectoryError(
                f"query times {float(flat.min()):.6f}..{float(flat.max()):.6f} s leave the trajectory's "
                f"{self.t_min:.6f}..{self.t_max:.6f} s"
            )
        rot, trans = tables["rotations"], tables["translations"]
        if len(self) == 1:  # one sample: a constant pose
            pose = torch.cat([rot[0], trans[0][:, None]], dim=-1).expand(flat.shape[0], 3, 4)
            return pose.reshape(*t.shape, 3, 4).to(dtype or torch.float32)
        times = tables["times"]
        inside = flat.clamp(self.t_min, self.t_max)
        # scipy's segment choice: the sample at or before the time, the first segment at the first sample
        index = (torch.searchsorted(times, inside) - 1).clamp(0, len(self) - 2)
        alpha = (inside - times[index]) / (times[index + 1] - times[index])
        rotation = rot[index] @ rotvec_matrix(tables["segment_rotvecs"][index] * alpha[:, None])
        translation = trans[index] + alpha[:, None] * (trans[index + 1] - trans[index])
        if self.extrapolate == "linear":  # the end segments' constant velocities, continued from the end samples
            for sel, end, ref in ((flat < self.t_min, 0, self.t_min), (flat > self.t_max, 1, self.t_max)):
                tau = (flat - ref)[:, None]
                i_end = 0 if end == 0 else len(self) - 1
                ext_rot = rot[i_end] @ rotvec_matrix(tau * tables["end_omegas"][end])
                ext_trans = trans[i_end] + tau * tables["end_velocities"][end]
                rotation = torch.where(sel[:, None, None], ext_rot, rotation)
                translation = torch.where(sel[:, None], ext_trans, translation)
        pose = torch.cat([rotation, translation[:, :, None]], dim=-1)
        return pose.reshape(*t.shape, 3, 4).to(dtype or torch.float32)

    def _tables(self, device: torch.device) -> Dict[str, Tensor]:
        """The samples as float64 tensors on `device` (made once per device): times, rotation matrices,
        translations, each segment's rotation vector and the end segments' angular and linear velocities."""
        import torch

        key = str(device)
        cache: Dict[str, Dict[str, Tensor]] = self.__dict__.setdefault("_device_tables", {})
        if key not in cache:
            tables = {"times": self.times, "rotations": self.rotations.as_matrix(), "translations": self.translations}
            if len(self) > 1:
                dt = np.diff(self.times)
                tables["segment_rotvecs"] = (self.rotations[:-1].inv() * self.rotations[1:]).as_rotvec()
                ends = (tables["segment_rotvecs"][[0, -1]], np.diff(self.translations, axis=0)[[0, -1]])
                tables["end_omegas"] = ends[0] / dt[[0, -1], None]
                tables["end_velocities"] = ends[1] / dt[[0, -1], None]
            cache[key] = {k: torch.as_tensor(np.ascontiguousarray(v), dtype=torch.float64, device=device)
                          for k, v in tables.items()}  # fmt: skip
        return cache[key]

    def __getstate__(self) -> Dict[str, Any]:
        """Pickled without the per-device tensor tables (they are rebuilt on first use)."""
        state = dict(self.__dict__)
        state.pop("_device_tables", None)
        return state

    def transformed(self, transform: Float[np.ndarray, "3 4"], scale: float = 1.0) -> "CameraTrajectory":
        """The trajectory in another world frame: ``p' = scale * (R p + t)`` for ``transform = [R | t]``.

        This is how Nerfstudio's dataparser maps poses (``dataparser_transform``, then ``dataparser_scale`` on the
        translations).
        """
        A = np.asarray(transform, dtype=np.float64)[:3, :4]
        c2w = np.zeros((len(self), 4, 4))
        c2w[:, :3, :3] = A[:3, :3] @ self.rotations.as_matrix()
        c2w[:, :3, 3] = scale * (self.translations @ A[:3, :3].T + A[:3, 3])
        c2w[:, 3, 3] = 1.0
        return CameraTrajectory(self.times, c2w, self.extrapolate)


def rotvec_matrix(rotvec: Float[Tensor, "*b 3"]) -> Float[Tensor, "*b 3 3"]:
    """Rotation matrices of rotation vectors (Rodrigues' formula, on the vectors' device and dtype; a Taylor series
    below 1e-4 rad, where the closed form loses precision)."""
    import torch

    theta2 = (rotvec * rotvec).sum(dim=-1, keepdim=True)[..., None]  # [*b, 1, 1]
    theta = theta2.sqrt()
    small = theta < 1e-4
    safe = torch.where(small, torch.ones_like(theta), theta)
    a = torch.where(small, 1.0 - theta2 / 6.0, torch.sin(safe) / safe)
    b = torch.where(small, 0.5 - theta2 / 24.0, (1.0 - torch.cos(safe)) / (safe * safe))
    x, y, z = rotvec.unbind(dim=-1)
    zero = torch.zeros_like(x)
    k = torch.stack([zero, -z, y, z, zero, -x, -y, x, zero], dim=-1).reshape(*rotvec.shape[:-1], 3, 3)
    eye = torch.eye(3, dtype=rotvec.dtype, device=rotvec.device)
    return eye + a * k + b * (k @ k)


def exposure_subtimes(exposure: Float[np.ndarray, "n 2"], k: int) -> Float[np.ndarray, "n k"]:
    """``k`` times per exposure interval ``[start, end]``: the midpoints of ``k`` equal parts (a box filter; the
    middle one is the interval's centre when ``k`` is odd; all equal ``start`` for a zero-length exposure)."""
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    exposure = np.asarray(exposure, dtype=np.float64)
    frac = (np.arange(k) + 0.5) / k
    return exposure[:, :1] + frac[None] * (exposure[:, 1:2] - exposure[:, :1])


TUM_FIELDS = ("t", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
"""The names of a TUM line's eight values, in order (for error messages)."""


def read_tum(path: Path) -> Tuple[Float[np.ndarray, " n"], Float[np.ndarray, "n 4 4"]]:
    """Read a TUM trajectory "t tx ty tz qx qy qz qw" -> (times, 4x4 camera-to-world matrices): a capture's
    ``odometry.txt`` and ``truth/poses.txt``, a dataset's ``trajectory.txt``.

    Raises :class:`TrajectoryError` naming the file and the 1-based line of a malformed row: not 8 numbers, a NaN or
    infinite value (``float()`` accepts "nan" and "inf", which would otherwise become a NaN pose), or a zero
    quaternion.
    """
    if not path.is_file():
        raise TrajectoryError(f"{path}: pose file missing")
    rows = []
    linenos = []  # the file line of each row (comments and blank lines are skipped), for the messages below
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise TrajectoryError(f"{path}:{lineno}: non-numeric value in {line!r}") from err
        if len(vals) != 8:
            raise TrajectoryError(f"{path}:{lineno}: expected 8 values 't tx ty tz qx qy qz qw', got {len(vals)}")
        bad = [name for name, v in zip(TUM_FIELDS, vals, strict=True) if not np.isfinite(v)]
        if bad:
            raise TrajectoryError(f"{path}:{lineno}: value not finite ({', '.join(bad)}) in {line!r}")
        rows.append(vals)
        linenos.append(lineno)
    if not rows:
        raise TrajectoryError(f"{path}: no poses")
    arr = np.asarray(rows, dtype=np.float64)
    q = arr[:, 4:8]
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < 1e-8):
        raise TrajectoryError(f"{path}:{linenos[int(np.argmin(norm))]}: zero quaternion")
    q = q / norm[:, None]
    c2w = np.tile(np.eye(4), (arr.shape[0], 1, 1))
    c2w[:, :3, :3] = quat_xyzw_to_rotmat(q)
    c2w[:, :3, 3] = arr[:, 1:4]
    return arr[:, 0], c2w


def quat_xyzw_to_rotmat(q: Float[np.ndarray, "n 4"]) -> Float[np.ndarray, "n 3 3"]:
    """Unit quaternions (x, y, z, w) to rotation matrices."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )


def write_tum(path: Path, times: Float[np.ndarray, " n"], c2w: Float[np.ndarray, "n 4 4"]) -> None:
    """Write a TUM file "t tx ty tz qx qy qz qw" of camera-to-world poses (their world and camera axes) atomically."""
    q = Rotation.from_matrix(np.asarray(c2w)[:, :3, :3]).as_quat()  # x, y, z, w
    rows = np.concatenate([np.asarray(times, dtype=np.float64)[:, None], np.asarray(c2w)[:, :3, 3], q], 1)
    tmp = path.with_suffix(path.suffix + ".part")
    tmp.write_text("# t tx ty tz qx qy qz qw: camera-to-world, OpenGL camera axes (as transform_matrix)\n"
                   + "".join(" ".join(f"{v:.9f}" for v in row) + "\n" for row in rows))  # fmt: skip
    tmp.rename(path)
