"""Fruit masks for the tiny sphere scene: the sphere above ``CAP_Z`` is "fruit", its bottom and the sky background,
a thin band around the rim unknown (128), as a segmenter unsure of a fruit's edge would leave it. (A smaller cap is
finer than the tiny scene's 16^3-24^3 grids resolve in a test's 150 steps.)"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from PIL import Image

from helpers.tiny_scene import cast_sphere_view

CAP_Z = -0.2
BAND = 0.08


def cap_mask(index: int, views: int, width: int, height: int) -> np.ndarray:
    """The 8-bit fruit mask of view `index`: 255 on the cap, 0 elsewhere, 128 within `BAND` of the rim."""
    view = cast_sphere_view(index, views, width, height, 0.9 * width)
    z = np.where(view.hit, view.points[..., 2], -1.0)
    mask = np.where(z > CAP_Z, 255, 0).astype(np.uint8)
    mask[view.hit & (np.abs(z - CAP_Z) < BAND)] = 128
    return mask


def add_fruit_masks(root: Path, folder: str = "fruit_masks") -> Path:
    """Write a cap mask per frame of the scene at `root` and name it in transforms.json; returns `root`."""
    meta = json.loads((root / "transforms.json").read_text())
    (root / folder).mkdir(exist_ok=True)
    views = len(meta["frames"])
    for i, frame in enumerate(meta["frames"]):
        name = f"{folder}/{Path(frame['file_path']).stem}.png"
        Image.fromarray(cap_mask(i, views, int(meta["w"]), int(meta["h"]))).save(root / name)
        frame["fruit_mask_file_path"] = name
    (root / "transforms.json").write_text(json.dumps(meta, indent=2))
    return root
