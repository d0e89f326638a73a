"""The event stream at the event camera's own pixels, for the event loss: ON/OFF counts of any pixel over any time
window, random sub-windows of the training frames' windows, and the rays of event pixels at any time.

Why not the event frames warped into the RGB pixels: the warp resamples a coarser camera with a nearest lookup and
puts each count on an RGB ray that passes up to half an event pixel away from where the event camera looked; in
textured canopy the log change there is a different one (docs/model.md, Event loss). Here each event pixel is
rendered along its own ray, from the event camera's centre, at the two ends of its window.

Counting without per-pixel lists: every event becomes one sortable key ``pixel * span + (t - t_min)`` (one sorted
int64 array per polarity), so the events of pixel ``p`` in ``[t0, t1)`` are the keys in
``[p * span + t0 - t_min, p * span + t1 - t_min)``: two binary searches, for any number of pixels at once.
"""

from __future__ import annotations

import copy
import dataclasses
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Dict, Optional, Tuple

import numpy as np
import torch
from jaxtyping import Float, Int, Integer
from torch import Tensor

if TYPE_CHECKING:
    from agrinerf_ns.trajectory import CameraTrajectory

GL_FLIP = np.diag([1.0, -1.0, -1.0])
"""OpenCV camera axes (x right, y down, z forward) to OpenGL's (x right, y up, z backward) and back."""


class EventStreamError(ValueError):
    """An event stream file that cannot be read or does not fit its camera."""


class EventStream:
    """ON and OFF events of a ``width`` x ``height`` event camera; times in integer microseconds of the frame clock.

    Args:
        x, y: pixel coordinates of each event.
        t_us: time of each event (microseconds, the clock of the RGB frames).
        p: polarity, 1 = ON, 0 = OFF.
        width, height: the event camera's resolution.
    """

    def __init__(
        self,
        x: Integer[np.ndarray, " n"],
        y: Integer[np.ndarray, " n"],
        t_us: Integer[np.ndarray, " n"],
        p: Integer[np.ndarray, " n"],
        width: int,
        height: int,
    ) -> None:
        self.width, self.height = int(width), int(height)
        t = np.asarray(t_us, dtype=np.int64)
        self.num_events = int(t.shape[0])
        self.t_min = int(t.min()) if t.size else 0
        self.span = (int(t.max()) - self.t_min + 2) if t.size else 2
        pixel = np.asarray(y, dtype=np.int64) * self.width + np.asarray(x, dtype=np.int64)
        keys = pixel * self.span + (t - self.t_min)
        on = np.asarray(p).astype(bool)
        self._keys: Dict[str, Tensor] = {
            "on": torch.from_numpy(np.sort(keys[on])),  # host: the stream is counted in host memory
            "off": torch.from_numpy(np.sort(keys[~on])),  # host: as above
        }

    @classmethod
    def from_h5(cls, path: Path, width: int, height: int) -> "EventStream":
        """The stream of a dataset's ``events/stream.h5`` (:func:`read_stream_h5`)."""
        return cls(*read_stream_h5(path, width, height), width, height)

    def counts(
        self, pixel: Int[Tensor, " n"], t0_us: Int[Tensor, " n"], t1_us: Int[Tensor, " n"]
    ) -> Tuple[Float[Tensor, "n 1"], Float[Tensor, "n 1"]]:
        """ON and OFF counts of each `pixel` (``y * width + x``) over ``[t0, t1)``."""
        lo = self._clamped(t0_us)
        hi = torch.maximum(self._clamped(t1_us), lo)
        base = pixel.long() * self.span
        out = []
        for polarity in ("on", "off"):
            keys = self._keys[polarity]
            n = torch.searchsorted(keys, base + hi) - torch.searchsorted(keys, base + lo)
            out.append(n.float()[:, None])
        return out[0], out[1]

    def to(self, device: torch.device) -> "EventStream":
        """This stream with its sorted keys on `device`: `counts` then runs there (`torch.searchsorted`), for pixels
        and times drawn there, with nothing copied per call."""
        moved = copy.copy(self)
        moved._keys = {polarity: keys.to(device) for polarity, keys in self._keys.items()}
        return moved

    def _clamped(self, t_us: Tensor) -> Tensor:
        return (t_us.long() - self.t_min).clamp(0, self.span - 1)


def read_stream_h5(path: Path, width: int, height: int) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """x, y, t (integer microseconds, frame clock), p of a dataset's ``events/stream.h5`` (events/x, y, t, p), checked
    against the event camera's resolution."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            group = f["events"]
            x, y, t, p = (np.asarray(group[k]) for k in "xytp")
    except (OSError, KeyError) as error:
        raise EventStreamError(f"{path}: not an event stream with events/x, y, t, p ({error})") from error
    if x.size and (int(x.max()) >= width or int(y.max()) >= height):
        raise EventStreamError(f"{path}: event coordinates outside the {width}x{height} event camera")
    return x, y, t, p


def sample_windows(
    windows: Float[Tensor, "f 2"], frames: Int[Tensor, " n"], min_fraction: float, generator: Optional[torch.Generator]
) -> Tuple[Int[Tensor, " n"], Int[Tensor, " n"]]:
    """Random sub-windows ``[t0, t1)`` (integer microseconds) of the `frames`' windows (seconds): a length uniform in
    ``[min_fraction, 1]`` of the window, placed uniformly inside it."""
    start, end = windows[frames, 0].double(), windows[frames, 1].double()
    device = windows.device  # the draws where the windows are (a generator must be of that device)
    fraction = min_fraction + (1.0 - min_fraction) * torch.rand(
        frames.shape, generator=generator, dtype=torch.float64, device=device
    )
    length = (end - start) * fraction
    t0 = start + (end - start - length) * torch.rand(
        frames.shape, generator=generator, dtype=torch.float64, device=device
    )
    return torch.round(t0 * 1e6).long(), torch.round((t0 + length) * 1e6).long()


def pixel_directions(
    intrinsics: Tuple[float, float, float, float], distortion: Tuple[float, ...], width: int, height: int
) -> Float[Tensor, "hw 3"]:
    """Unit ray direction of every pixel centre (row-major, ``y * width + x``) in the camera's OpenCV frame, through
    OpenCV's pinhole + radial-tangential model (the centre of pixel column ``i`` is at ``u = i``)."""
    import cv2

    fx, fy, cx, cy = intrinsics
    K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    v, u = np.mgrid[0:height, 0:width].astype(np.float64)
    points = np.stack([u.ravel(), v.ravel()], -1)[:, None, :]
    normalised = cv2.undistortPoints(points, K, np.asarray(distortion, dtype=np.float64))[:, 0, :]
    rays = np.concatenate([normalised, np.ones((normalised.shape[0], 1))], -1)
    return torch.from_numpy(rays / np.linalg.norm(rays, axis=-1, keepdims=True))  # host: once per dataset (cached)


def rig_offset(T_cam_rgb: Float[np.ndarray, "4 4"], scale: float) -> Tuple[Float[Tensor, "3 3"], Float[Tensor, "3"]]:
    """A rig camera (events, thermal) in the RGB camera's frame, OpenGL axes: the rotation taking its OpenCV ray
    directions into the RGB camera's OpenGL frame, and its centre (times `scale`, the dataparser's). `T_cam_rgb` maps
    points of the RGB camera's OpenCV frame into that camera's."""
    T = np.asarray(T_cam_rgb, dtype=np.float64)
    rotation = GL_FLIP @ T[:3, :3].T
    centre = GL_FLIP @ (-T[:3, :3].T @ T[:3, 3]) * scale
    return torch.from_numpy(rotation), torch.from_numpy(centre)  # host: dataparser metadata, once


@dataclass
class EventCamera:
    """The event camera at its own pixels, as the dataparser gives it (metadata ``event_stream``)."""

    path: Path
    """The dataset's ``events/stream.h5``."""
    width: int
    height: int
    intrinsics: Tuple[float, float, float, float]
    """fx, fy, cx, cy (OpenCV: the centre of pixel column ``i`` is at ``u = i``)."""
    distortion: Tuple[float, ...]
    """OpenCV radial-tangential coefficients."""
    rotation: Float[Tensor, "3 3"]
    """The event camera's OpenCV ray directions into the RGB camera's OpenGL frame (:func:`rig_offset`)."""
    centre: Float[Tensor, "3"]
    """The event camera's centre in the RGB camera's OpenGL frame, in the dataparser's scale."""

    @cached_property
    def directions(self) -> Float[Tensor, "hw 3"]:
        """Every pixel's ray in the event camera's OpenCV frame, computed on first use (only the event loss needs
        them)."""
        return pixel_directions(self.intrinsics, self.distortion, self.width, self.height)

    def stream(self) -> EventStream:
        """The events of :attr:`path`."""
        return EventStream.from_h5(self.path, self.width, self.height)

    def to(self, device: torch.device) -> "EventCamera":
        """This camera with its rotation, centre and pixel rays on `device` (`event_rays` for pixels drawn there)."""
        moved = dataclasses.replace(self, rotation=self.rotation.to(device), centre=self.centre.to(device))
        moved.__dict__["directions"] = self.directions.to(device)  # the cached property, computed here once
        return moved


def event_rays(
    trajectory: "CameraTrajectory", camera: EventCamera, pixel: Int[Tensor, " n"], times_s: Float[Tensor, "n k"]
) -> Tuple[Float[Tensor, "n k 3"], Float[Tensor, "n k 3"]]:
    """Origins and unit directions (float64, the trajectory's frame) of event `pixel`s seen at `times_s`: the
    trajectory's RGB pose there, moved to the event camera."""
    poses = trajectory.poses_at_tensor(times_s.double(), dtype=torch.float64)  # [n, k, 3, 4] RGB camera to world
    rotation = poses[..., :3]
    local_d = camera.directions[pixel].double() @ camera.rotation.double().T  # [n, 3], RGB camera (OpenGL)
    origins = poses[..., 3] + (rotation @ camera.centre.double()[:, None])[..., 0]
    directions = (rotation @ local_d[:, None, :, None])[..., 0]
    return origins, directions
