"""Fruit masks per training frame, read for the dataset (the values: ``agrinerf_ns/fruit_mask_format.py``; the key:
``agrinerf_ns/dataset_format.py``).

The dataset returns ``fruit`` (1 fruit, 0 not) and ``fruit_known`` (1 where the mask says either) per pixel; the
fruit head's loss reads only the known pixels. Every frame's mask is found and its size checked before training.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
import torch
from jaxtyping import Float
from PIL import Image
from torch import Tensor

from agrinerf_ns.dataparsers.dataset_checks import AgriNeRFDataError
from agrinerf_ns.dataset_format import FRUIT_MASK
from agrinerf_ns.fruit_mask_format import fruit_and_known


def read_fruit_mask(path: Path) -> np.ndarray:
    """The mask's 8-bit values [H, W]; an :class:`AgriNeRFDataError` naming the file when it is not a single-channel
    8-bit image."""
    try:
        image = Image.open(path)
        image.load()
    except Exception as error:  # PIL raises several types for unreadable files
        raise AgriNeRFDataError(f"{path}: cannot read fruit mask: {error}") from error
    if image.mode not in ("L", "1", "P"):
        raise AgriNeRFDataError(f"{path}: a fruit mask must be a single-channel 8-bit image, got mode {image.mode}")
    return np.asarray(image.convert("L") if image.mode == "1" else image, dtype=np.uint8)


def fruit_mask_paths(frames: List[Dict[str, Any]], data_dir: Path, transforms_path: Path) -> Optional[List[Path]]:
    """The fruit mask of every frame in `frames`, or None when no frame of the dataset names one; an
    :class:`AgriNeRFDataError` naming the frame when one lacks its mask (the dataparser checks each file as it checks
    the thermal and event frames: there, and at its RGB frame's size)."""
    if not any(FRUIT_MASK.key in frame for frame in frames):
        return None
    for frame in frames:
        if FRUIT_MASK.key not in frame:
            raise AgriNeRFDataError(
                f"{transforms_path}: frame {frame.get('file_path')} has no {FRUIT_MASK.key} while other frames have one; "
                "give every training frame a mask (128 marks pixels nobody labelled)"
            )
    return [data_dir / frame[FRUIT_MASK.key] for frame in frames]


def load_fruit_mask(
    path: Path, height: int, width: int
) -> Tuple[Float[Tensor, "height width 1"], Float[Tensor, "height width 1"]]:
    """(fruit, known) of a mask file as float32 (H, W, 1) at (height, width); a resize takes the nearest pixel (the
    values are labels)."""
    values = read_fruit_mask(path)
    if values.shape != (height, width):
        values = np.asarray(Image.fromarray(values).resize((width, height), resample=Image.Resampling.NEAREST))
    fruit, known = fruit_and_known(values)
    return torch.from_numpy(fruit.astype(np.float32))[..., None], torch.from_numpy(known.astype(np.float32))[..., None]
