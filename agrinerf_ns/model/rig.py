"""What the model's optional terms are given instead of the model: the rig's timing and cameras from the dataset
(`Rig`), the one render call they make (`RenderRays`), and the random stream their renders draw from
(`side_stream`)."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from typing import Any, Dict, Iterator, Mapping, Optional, Protocol, Tuple, runtime_checkable

import torch
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor

from agrinerf_ns.dataparsers.event_stream import EventCamera

SIDE_STREAM_SEED = 20_261_202
"""Seed of the blur and event renders' random stream at step 0 (`side_stream`), and of the optional parts' weights."""


@dataclass(frozen=True)
class Rig:
    """The training frames' timing and the rig's other cameras, from the dataparser's metadata (all optional: a
    dataset without them gets no blur model, event loss or thermal view; `plan.resolve_plan` decides)."""

    frame_times: Optional[Tensor] = None
    """When each training frame was taken, seconds (float64 [N])."""
    exposure: Optional[Tensor] = None
    """Each frame's exposure interval, seconds ([N, 2])."""
    trajectory: Any = None
    """The rig's `agrinerf_ns.trajectory.CameraTrajectory`: the RGB camera's pose at any time."""
    event_windows: Optional[Tensor] = None
    """Each frame's event window, seconds ([N, 2])."""
    event_camera: Dict[str, Any] = field(default_factory=dict)
    """The event camera's centre and alignment plane (`camera_centre`, `plane_depth`; `timed_rays.reposed_rays`)."""
    event_stream: Optional[EventCamera] = None
    """The event camera's own stream and intrinsics, where the dataset has events/stream.h5."""
    thermal_camera: Dict[str, Any] = field(default_factory=dict)
    """The thermal camera's centre and alignment plane (`thermal_view.py`)."""
    thermal_times: Optional[Tensor] = None
    """When each training frame's thermal frame was taken (float64 [N]); None: at the RGB frames' times."""

    @classmethod
    def from_metadata(cls, metadata: Mapping[str, Any]) -> Rig:
        return cls(
            frame_times=metadata.get("times"),
            exposure=metadata.get("exposure"),
            trajectory=metadata.get("trajectory"),
            event_windows=metadata.get("event_windows"),
            event_camera=dict(metadata.get("event_camera") or {}),
            event_stream=metadata.get("event_stream"),
            thermal_camera=dict(metadata.get("thermal_camera") or {}),
            thermal_times=metadata.get("thermal_times"),
        )


@runtime_checkable
class RenderRays(Protocol):
    """The model's render of a side bundle of rays (collided with the scene first), evaluating only `heads`.

    `term`: the loss term the renders serve; they then reach the density at that term's gradient scale and carry no
    routed copies. None: a render at full scale with the routed copies of its outputs (the thermal camera's rays,
    whose terms read them)."""

    def __call__(self, bundle: RayBundle, heads: Tuple[str, ...], term: Optional[str] = None) -> Dict[str, Tensor]: ...


@contextlib.contextmanager
def side_stream(device: torch.device, step: int) -> Iterator[None]:
    """The blur and event renders draw their pixels, windows and sample jitter from a random stream of their own
    (seeded by the step), so that turning them on leaves the draws of the RGB batches as they were: an ablation
    row and its baseline stay paired (common random numbers)."""
    devices = [device] if device.type == "cuda" else []
    with torch.random.fork_rng(devices=devices):
        torch.manual_seed(SIDE_STREAM_SEED + step)
        yield
