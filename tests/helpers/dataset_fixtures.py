"""Tiny tri-modal AgriNeRF dataset folders for dataparser and dataset tests.

Writes what ``agrinerf-process`` writes (docs/formats.md): ``transforms.json`` of the RGB camera with per-frame
``thermal_file_path`` / ``thermal_mask_path`` / ``event_file_path`` / ``event_mask_path`` and the ``agrinerf`` block.
Pixel values are random (seeded); poses look at the origin from a jittered ring, in Nerfstudio's OpenGL axes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable, Dict, Iterable, Optional, Sequence

import numpy as np
import torch
from PIL import Image

from helpers.tiny_scene import look_at as _look_at
from helpers.tiny_scene import make_dataset_folders, write_transforms

WIDTH, HEIGHT = 64, 48


def _pixels(rng: np.random.Generator, fill: Optional[int], shape: Sequence[int]) -> np.ndarray:
    """Random uint8 pixels, or a constant ``fill`` value."""
    if fill is not None:
        return np.full(shape, fill, dtype=np.uint8)
    return rng.integers(0, 256, size=shape, dtype=np.uint8)


def write_tridata(
    root: Path,
    num_frames: int = 8,
    modalities: Sequence[str] = ("rgb", "thermal", "events"),
    masks: bool = True,
    width: int = WIDTH,
    height: int = HEIGHT,
    seed: int = 0,
    fill: Optional[Dict[str, int]] = None,
    downscaled_images: Sequence[int] = (),
) -> Path:
    """Writes a tiny dataset folder under ``root`` and returns ``root``.

    Args:
        modalities: which of "thermal" and "events" to write beside the RGB frames.
        masks: also write thermal/event valid masks (random, about 80 % valid).
        fill: constant uint8 value per stream instead of random pixels, keys "rgb", "thermal", "event", "mask".
        downscaled_images: factors N for which an ``images_N/`` copy of the RGB frames is written (as
            ``ns-process-data`` does); the thermal and event frames stay at full resolution.
    """
    rng = np.random.default_rng(seed)
    fill = fill or {}
    make_dataset_folders(root, modalities, ["images"] + [f"images_{n}" for n in downscaled_images])

    frames = []
    for i in range(num_frames):
        angle = 2 * np.pi * i / num_frames + rng.uniform(-0.1, 0.1)
        position = np.array([3.0 * np.cos(angle), 3.0 * np.sin(angle), 0.5 + rng.uniform(-0.2, 0.2)])
        name = f"frame_{i:05d}.png"
        rgb = _pixels(rng, fill.get("rgb"), (height, width, 3))
        Image.fromarray(rgb).save(root / "images" / name)
        for n in downscaled_images:
            Image.fromarray(rgb).resize((width // n, height // n), Image.Resampling.BILINEAR).save(
                root / f"images_{n}" / name
            )
        frame: Dict[str, Any] = {"file_path": f"images/{name}", "transform_matrix": _look_at(position).tolist()}
        for modality, key, folder in (("thermal", "thermal", "thermal"), ("events", "event", "events")):
            if modality not in modalities:
                continue
            Image.fromarray(_pixels(rng, fill.get(key), (height, width))).save(root / folder / name)
            frame[f"{key}_file_path"] = f"{folder}/{name}"
            if masks:
                if "mask" in fill:
                    mask = np.full((height, width), fill["mask"], dtype=np.uint8)
                else:
                    mask = np.where(rng.uniform(size=(height, width)) < 0.8, 255, 0).astype(np.uint8)
                Image.fromarray(mask).save(root / f"{key}_masks" / name)
                frame[f"{key}_mask_path"] = f"{key}_masks/{name}"
        frames.append(frame)

    return write_transforms(root, frames, width, height, 0.9 * width, modalities, source="test fixture")


def edit_transforms(root: Path, edit: Callable[[Dict[str, Any]], None]) -> None:
    """Applies ``edit`` to the parsed ``transforms.json`` under ``root`` and writes it back."""
    path = root / "transforms.json"
    meta = json.loads(path.read_text())
    edit(meta)
    path.write_text(json.dumps(meta, indent=2))


def assert_batch_matches_dataset(batch: Dict[str, torch.Tensor], dataset: Any, keys: Iterable[str]) -> None:
    """Every sampled value equals the dataset's full-image value at the pixel named by ``batch["indices"]``."""
    c, y, x = batch["indices"].T
    full = {i: dataset[i] for i in torch.unique(c).tolist()}
    for key in keys:
        assert batch[key].dtype == torch.float32, key
        expected = torch.stack(
            [full[ci][key][yi, xi] for ci, yi, xi in zip(c.tolist(), y.tolist(), x.tolist(), strict=True)]
        )
        assert torch.equal(batch[key], expected), key
