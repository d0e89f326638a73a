"""Fruit masks of the RGB frames from the user's own segmenter (``agrinerf-process --fruit-masks DIR``).

``DIR`` holds one mask per raw RGB frame, named like it (same stem, any image extension: SAM, a YOLO-seg model or
hand labels); a folder with a ``semantics/`` subfolder (FruitNeRF's dataset layout) is read from there. A mask is a
single-channel 8-bit image (a 3-channel one is read when its channels agree) at the raw frame's size: 0 background,
128 unknown, any other value fruit (``agrinerf_ns/fruit_mask_format.py``). Masks are undistorted with the RGB frames' maps
(nearest pixel: the values are labels) and written as ``fruit_masks/NNNNNN.png`` beside ``images/``. Every mask is
found and read before any output is written.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import cv2
import numpy as np
from jaxtyping import UInt8

from agrinerf_ns.dataset_format import FRUIT_MASK
from agrinerf_ns.fruit_mask_format import UNKNOWN
from agrinerf_ns.images import write_png
from agrinerf_ns.process import align
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.readers import CameraCalib

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")


def mask_folder(folder: Path) -> Path:
    """The folder that holds the masks: `folder`, or its ``semantics/`` (FruitNeRF's layout) when it has one."""
    folder = Path(folder)
    if not folder.is_dir():
        raise RawInputError(f"{folder}: --fruit-masks folder does not exist")
    return folder / "semantics" if (folder / "semantics").is_dir() else folder


def find_fruit_masks(folder: Path, rgb_paths: List[Path]) -> List[Path]:
    """The mask of each raw RGB frame (matched by file stem) in :func:`mask_folder` of `folder`; a
    :class:`RawInputError` naming the first frame without one (or with two)."""
    where = mask_folder(folder)
    by_stem: Dict[str, List[Path]] = {}
    for path in sorted(where.iterdir()):
        if path.suffix.lower() in IMAGE_SUFFIXES:
            by_stem.setdefault(path.stem, []).append(path)
    masks = []
    for frame in rgb_paths:
        found = by_stem.get(frame.stem, [])
        if len(found) != 1:
            problem = "no mask" if not found else f"{len(found)} masks ({', '.join(p.name for p in found)})"
            raise RawInputError(f"{where}: {problem} named like RGB frame {frame.name} (one {frame.stem}.png each)")
        masks.append(found[0])
    return masks


def read_mask(path: Path, width: int, height: int) -> UInt8[np.ndarray, "h w"]:
    """A mask's 8-bit labels; a :class:`RawInputError` naming the file when it is unreadable, not 8-bit, of several
    different channels or not of the frame's size."""
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise RawInputError(f"{path}: cannot read fruit mask")
    if image.dtype != np.uint8:
        raise RawInputError(f"{path}: fruit mask must be 8-bit, got {image.dtype}")
    if image.ndim == 3:
        if not all(np.array_equal(image[..., 0], image[..., c]) for c in range(1, min(image.shape[2], 3))):
            raise RawInputError(f"{path}: fruit mask has {image.shape[2]} different channels; give one channel")
        image = image[..., 0]
    if image.shape != (height, width):
        raise RawInputError(
            f"{path}: fruit mask is {image.shape[1]}x{image.shape[0]} but the RGB frames are {width}x{height}"
        )
    return image


def check_fruit_masks(masks: List[Path], width: int, height: int) -> None:
    """Read every mask once (before any output is written)."""
    for path in masks:
        read_mask(path, width, height)


def write_fruit_masks(
    masks: List[Path], calib_rgb: CameraCalib, tmp: Path, frames: List[Dict], names: List[str]
) -> dict:
    """Write each frame's mask, undistorted like its frame, and name it in the frame; returns the dataset's record."""
    und = align.undistort_maps(calib_rgb)
    (tmp / FRUIT_MASK.folder).mkdir(parents=True, exist_ok=True)
    for i, path in enumerate(masks):
        mask = read_mask(path, calib_rgb.width, calib_rgb.height)
        if und is not None:  # nearest: labels; pixels from outside the raw frame are unknown
            mask = cv2.remap(mask, und[0], und[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT,
                             borderValue=UNKNOWN)  # fmt: skip
        frames[i][FRUIT_MASK.key] = FRUIT_MASK.path(names[i])
        write_png(tmp / frames[i][FRUIT_MASK.key], mask)
    return {"source": "user", "folder": str(masks[0].parent.resolve()) if masks else "",
            "values": f"0 background, {UNKNOWN} unknown, any other value fruit"}  # fmt: skip
