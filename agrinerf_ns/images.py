"""8-bit image conversion and PNG writing, shared by the synthesiser, the processing and the detection renders."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from jaxtyping import Float, UInt8


def to_uint8(image: Float[np.ndarray, "*shape"]) -> UInt8[np.ndarray, "*shape"]:
    """[0, 1] floats -> 8-bit as round(255 v), clipped; NaN -> 0, +Inf -> 255, -Inf -> 0."""
    image = np.nan_to_num(np.asarray(image), nan=0.0, posinf=1.0, neginf=0.0)
    return np.clip(np.round(image * 255.0), 0, 255).astype(np.uint8)


def write_png(path: Path, image: np.ndarray) -> None:
    """Write an 8-bit gray or RGB (RGB channel order) or 16-bit gray PNG, creating the folder; OpenCV writes no time
    or text chunks, so the same pixels give the same file."""
    if image.dtype not in (np.uint8, np.uint16) or image.ndim not in (2, 3):
        raise TypeError(f"cannot write a {image.dtype} image of shape {image.shape} to {path} as PNG")
    if image.ndim == 3 and (image.shape[2] != 3 or image.dtype != np.uint8):
        raise TypeError(f"cannot write a {image.dtype} image of shape {image.shape} to {path}: expected 8-bit RGB")
    path.parent.mkdir(parents=True, exist_ok=True)
    pixels = cv2.cvtColor(image, cv2.COLOR_RGB2BGR) if image.ndim == 3 else np.ascontiguousarray(image)
    if not cv2.imwrite(str(path), pixels):
        raise OSError(f"{path}: could not write image")
