"""A tiny Nerfstudio dataset for tests of the Nerfstudio commands: a checker-textured sphere seen from a ring of views.

Rendered by analytic ray casting so that the views are multi-view consistent (a NeRF can fit them).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np
from PIL import Image


def look_at(position: np.ndarray) -> np.ndarray:
    """Camera-to-world (OpenGL axes: x right, y up, looking down -z) looking at the origin."""
    forward = -position / np.linalg.norm(position)
    right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    up = np.cross(right, forward)
    c2w = np.eye(4)
    c2w[:3, 0], c2w[:3, 1], c2w[:3, 2], c2w[:3, 3] = right, up, -forward, position
    return c2w


@dataclass
class SphereView:
    """What the rays of one view of the unit sphere hit (arrays of shape (height, width, ...))."""

    c2w: np.ndarray
    """Camera-to-world, 4x4, OpenGL axes."""
    dirs: np.ndarray
    """Unit ray directions in the world, (h, w, 3)."""
    hit: np.ndarray
    """Whether the ray hits the sphere, (h, w) bool."""
    points: np.ndarray
    """First intersection with the sphere's surface (meaningless where not ``hit``), (h, w, 3)."""


def cast_sphere_view(index: int, views: int, width: int, height: int, focal: float) -> SphereView:
    """Cast the rays of view ``index`` of ``views`` on a ring (radius 3, height 0.8) looking at the unit sphere."""
    angle = 2 * np.pi * index / views
    c2w = look_at(np.array([3.0 * np.cos(angle), 3.0 * np.sin(angle), 0.8]))
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    dirs = np.stack([(u - width / 2) / focal, -(v - height / 2) / focal, -np.ones_like(u)], -1) @ c2w[:3, :3].T
    dirs /= np.linalg.norm(dirs, axis=-1, keepdims=True)
    origin = c2w[:3, 3]
    b = dirs @ origin
    disc = b**2 - (origin @ origin - 1.0)
    points = origin + (-b - np.sqrt(np.clip(disc, 0, None)))[..., None] * dirs
    return SphereView(c2w, dirs, disc > 0, points)


def sphere_rgb(view: SphereView) -> np.ndarray:
    """The RGB colour in [0, 1] of each ray: checker-textured sphere under a blue sky gradient, (h, w, 3)."""
    points, dirs = view.points, view.dirs
    checker = (np.floor(points[..., 0] * 4) + np.floor(points[..., 1] * 4) + np.floor(points[..., 2] * 4)) % 2
    sphere = np.stack([0.2 + 0.7 * checker, 0.3 + 0.2 * (1 - checker), 0.2 + 0.1 * points[..., 2]], -1)
    sky = np.stack([0.5 + 0.3 * dirs[..., 2], 0.6 + 0.2 * dirs[..., 2], np.full(dirs.shape[:2], 0.9)], -1)
    return np.where(view.hit[..., None], sphere, sky)


def write_tiny_scene(root: Path, views: int = 8, width: int = 64, height: int = 48) -> Path:
    """Write images/ and transforms.json under ``root``; returns ``root``."""
    (root / "images").mkdir(parents=True, exist_ok=True)
    focal = 0.9 * width
    frames = []
    for i in range(views):
        view = cast_sphere_view(i, views, width, height, focal)
        name = f"images/frame_{i:05d}.png"
        Image.fromarray((np.clip(sphere_rgb(view), 0, 1) * 255).astype(np.uint8)).save(root / name)
        frames.append({"file_path": name, "transform_matrix": view.c2w.tolist()})
    return write_transforms(root, frames, width, height, focal)


def write_transforms(
    root: Path,
    frames: List[Dict[str, Any]],
    width: int,
    height: int,
    focal: float,
    modalities: Optional[Sequence[str]] = None,
    source: str = "test scene",
) -> Path:
    """Write a pinhole ``transforms.json`` (with an ``agrinerf`` block when ``modalities`` is given); returns ``root``."""
    meta: Dict[str, Any] = {
        "camera_model": "OPENCV",
        "fl_x": focal,
        "fl_y": focal,
        "cx": width / 2,
        "cy": height / 2,
        "w": width,
        "h": height,
        "frames": frames,
    }
    if modalities is not None:
        meta["agrinerf"] = {
            "modalities": ["rgb"] + [m for m in ("thermal", "events") if m in modalities],
            "events": {"window": 0.05, "representation": "signed polarity sum, 0.5 = no change"},
            "thermal_rescale": {"method": source},
            "poses": {"source": source, "dropped_frames": []},
        }
    (root / "transforms.json").write_text(json.dumps(meta, indent=2))
    return root


def make_dataset_folders(root: Path, modalities: Sequence[str], image_folders: Sequence[str] = ("images",)) -> None:
    """The folders of a tri-modal dataset under `root`: the image folders, then thermal/ and thermal_masks/, events/
    and event_masks/ for the modalities given."""
    folders = list(image_folders)
    if "thermal" in modalities:
        folders += ["thermal", "thermal_masks"]
    if "events" in modalities:
        folders += ["events", "event_masks"]
    for folder in folders:
        (root / folder).mkdir(parents=True, exist_ok=True)
