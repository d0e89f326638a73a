"""Checks of a dataset's ``transforms.json`` before Nerfstudio's parser reads it and before any training step.

Nerfstudio's parser trusts the file: a truncated file raises a bare ``JSONDecodeError`` that does not name it, and a
NaN in one frame's pose trains to the end. These checks read the file once and raise :class:`AgriNeRFDataError`
naming the file (and the frame) for what would otherwise fail later or silently: invalid JSON, no frames, a pose that
is not a finite rigid camera-to-world matrix, intrinsics that are not finite and positive, a missing or unreadable
RGB image, or one whose size differs from the ``w`` x ``h`` the file gives it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Dict, List, Tuple

import numpy as np
from PIL import Image

RIGID_TOL = 1e-3
"""Largest entry of ``R^T R - I`` (and of the bottom row's difference from [0, 0, 0, 1]) accepted as rigid; a pose
stored with 6 or more significant digits is far inside it, a scaled or sheared matrix far outside."""

POSITIVE_INTRINSICS = ("fl_x", "fl_y", "w", "h")
FINITE_INTRINSICS = ("cx", "cy")


class AgriNeRFDataError(ValueError):
    """A tri-modal dataset does not follow the contract of docs/formats.md."""


def read_transforms(path: Path) -> Dict[str, Any]:
    """The parsed ``transforms.json``; an unreadable or invalid file raises naming it (and the line and column)."""
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as error:
        raise AgriNeRFDataError(f"{path}: cannot read the dataset file: {error}") from error
    try:
        meta = json.loads(text)
    except json.JSONDecodeError as error:
        raise AgriNeRFDataError(
            f"{path}: not valid JSON ({error.msg} at line {error.lineno}, column {error.colno}); "
            "the file may be truncated: write it again (agrinerf-process writes it atomically)."
        ) from error
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise AgriNeRFDataError(f"{path}: expected a JSON object with a non-empty 'frames' list.")
    return meta


def check_transforms(meta: Dict[str, Any], path: Path) -> None:
    """Checks every frame of a parsed ``transforms.json`` (``path``, for the messages): file path, pose, intrinsics
    and RGB image (existence and size, from the image header)."""
    data_dir = path.parent
    frames: List[Any] = meta["frames"]
    for index, frame in enumerate(frames):
        if not isinstance(frame, dict) or not isinstance(frame.get("file_path"), str):
            raise AgriNeRFDataError(f"{path}: frame {index} has no 'file_path'.")
        name = frame["file_path"]
        _check_pose(frame.get("transform_matrix"), f"{path}: frame {name}")
        _check_intrinsics(frame, meta, f"{path}: frame {name}")
        _check_image(data_dir / name, frame, meta, path)


def _check_pose(matrix: Any, where: str) -> None:
    """A finite rigid camera-to-world matrix: 4x4 (or 3x4), orthonormal rotation with determinant +1."""
    try:
        pose = np.asarray(matrix, dtype=np.float64)
    except (TypeError, ValueError) as error:
        raise AgriNeRFDataError(f"{where}: 'transform_matrix' is not a numeric matrix ({error}).") from error
    if pose.shape not in ((4, 4), (3, 4)):
        raise AgriNeRFDataError(f"{where}: 'transform_matrix' has shape {pose.shape}; expected 4x4.")
    if not np.all(np.isfinite(pose)):
        raise AgriNeRFDataError(f"{where}: 'transform_matrix' has non-finite entries (NaN or Inf): {pose.tolist()}")
    rotation = pose[:3, :3]
    orthonormal_error = float(np.abs(rotation.T @ rotation - np.eye(3)).max())
    bottom_error = float(np.abs(pose[3] - [0.0, 0.0, 0.0, 1.0]).max()) if pose.shape[0] == 4 else 0.0
    determinant = float(np.linalg.det(rotation))
    if orthonormal_error > RIGID_TOL or determinant <= 0 or bottom_error > RIGID_TOL:
        raise AgriNeRFDataError(
            f"{where}: 'transform_matrix' is not a rigid camera-to-world pose (rotation off orthonormal by "
            f"{orthonormal_error:.3g}, determinant {determinant:.3g}, bottom row off [0, 0, 0, 1] by "
            f"{bottom_error:.3g})."
        )


def _check_intrinsics(frame: Dict[str, Any], meta: Dict[str, Any], where: str) -> None:
    """``fl_x``, ``fl_y``, ``w``, ``h`` finite and > 0, ``cx``, ``cy`` finite, from the frame or the top level (a
    missing one is left to Nerfstudio's parser, which says which)."""
    for key in POSITIVE_INTRINSICS + FINITE_INTRINSICS:
        value = frame.get(key, meta.get(key))
        if value is None:
            continue
        try:
            number = float(value)
        except (TypeError, ValueError):
            number = math.nan
        if not math.isfinite(number) or (key in POSITIVE_INTRINSICS and number <= 0):
            source = "the frame" if key in frame else "the file's top level"
            need = "finite and > 0" if key in POSITIVE_INTRINSICS else "finite"
            raise AgriNeRFDataError(f"{where}: intrinsic '{key}' = {value!r} (in {source}) must be {need}.")


def image_size(path: Path, named_by: str) -> Tuple[int, int]:
    """(width, height) of an image from its header; a missing or unreadable file raises naming it and ``named_by``
    (what names it, e.g. "'thermal_file_path' in DATA/transforms.json")."""
    if not path.is_file():
        raise AgriNeRFDataError(f"{path}: file named by {named_by} does not exist.")
    try:
        with Image.open(path) as image:
            return image.size
    except Exception as error:  # PIL raises several types for unreadable files
        raise AgriNeRFDataError(f"{path}: cannot read the image named by {named_by}: {error}") from error


def _check_image(image_path: Path, frame: Dict[str, Any], meta: Dict[str, Any], transforms_path: Path) -> None:
    """The RGB image exists, is readable and (header only) has the frame's ``w`` x ``h`` when those are given."""
    size = image_size(image_path, f"'file_path' in {transforms_path}")
    width, height = frame.get("w", meta.get("w")), frame.get("h", meta.get("h"))
    if width is not None and height is not None and size != (int(width), int(height)):
        raise AgriNeRFDataError(
            f"{image_path}: image is {size[0]}x{size[1]} but {transforms_path} gives its frame w x h = "
            f"{int(width)}x{int(height)}."
        )
