"""Checks of a dataset's ``transforms.json`` before Nerfstudio's parser reads it and before any training step.

Nerfstudio's parser trusts the file: a truncated file raises a bare ``JSONDecodeError`` that does not name it, and a
NaN in one frame's pose trains to the end. These checks read the file once and raise :class:`AgriNeRFDataError`
naming the file (and the frame) for what would otherwise fail later or silently: invalid JSON, no frames, a pose that
is not a finite rigid camera-to-world matrix, intrinsics that are not finite and positive, a missing or unreadable
RGB image, or one whose size differs from the ``w`` x ``h`` the file gives it. Every image a frame names (RGB,
thermal frame and mask, event frame and mask, temperature image, fruit mask) is checked to exist, to be whole
(:func:`check_image_file`: a truncated or corrupt file is refused by its name) and to have its RGB frame's size.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

import numpy as np
from PIL import Image

from agrinerf_ns.dataset_format import FRAME_FILES, IMAGE, TRANSFORMS

RIGID_TOL = 1e-3
"""Largest entry of ``R^T R - I`` (and of the bottom row's difference from [0, 0, 0, 1]) accepted as rigid; a pose
stored with 6 or more significant digits is far inside it, a scaled or sheared matrix far outside."""

ALIGNED_IMAGE_KEYS = tuple(f.key for f in FRAME_FILES if f is not IMAGE and f.suffix == ".png")
"""Per-frame keys naming an image aligned to the frame's RGB image: it must exist, be whole and have its size."""

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
            f"{path}: not valid JSON: {_json_fault(error, text)}; write it again (agrinerf-process writes it "
            "atomically)."
        ) from error
    if not isinstance(meta, dict) or not isinstance(meta.get("frames"), list) or not meta["frames"]:
        raise AgriNeRFDataError(f"{path}: expected a JSON object with a non-empty 'frames' list.")
    return meta


def _json_fault(error: json.JSONDecodeError, text: str) -> str:
    """What is wrong with the text: the file ends early (truncated), or a syntax error at a line and column."""
    if not text[error.pos :].strip():
        return f"it ends early, at line {error.lineno}, column {error.colno} ({error.msg}): the file is truncated"
    return f"syntax error at line {error.lineno}, column {error.colno}: {error.msg}"


def check_transforms(meta: Dict[str, Any], path: Path) -> None:
    """Checks every frame of a parsed ``transforms.json`` (``path``, for the messages): file path, pose, intrinsics,
    the RGB image and every aligned image the frame names (:data:`ALIGNED_IMAGE_KEYS`): there, whole, at size."""
    data_dir = path.parent
    frames: List[Any] = meta["frames"]
    for index, frame in enumerate(frames):
        if not isinstance(frame, dict) or not isinstance(frame.get(IMAGE.key), str):
            raise AgriNeRFDataError(f"{path}: frame {index} has no 'file_path'.")
        name = frame[IMAGE.key]
        _check_pose(frame.get("transform_matrix"), f"{path}: frame {name}")
        _check_intrinsics(frame, meta, f"{path}: frame {name}")
        check_frame_image(data_dir / name, frame, meta, IMAGE.key, path)
        for key in ALIGNED_IMAGE_KEYS:
            if isinstance(frame.get(key), str):
                check_frame_image(data_dir / frame[key], frame, meta, key, path)


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


PNG_END = b"IEND\xaeB`\x82"
"""The last 8 bytes of every whole PNG file: the IEND chunk's type and CRC."""
JPEG_END = b"\xff\xd9"
"""The JPEG end-of-image marker."""


def check_image_file(path: Path, named_by: str) -> Tuple[int, int]:
    """(width, height) of a whole image file; a missing, unreadable, truncated or corrupt one raises naming it and
    ``named_by`` (what names it, e.g. "'thermal_file_path' in DATA/transforms.json").

    Cheap, without decoding pixels: a PNG's chunks are walked and their CRCs checked (``Image.verify``) and its last
    chunk must be IEND; a JPEG must end with its end-of-image marker. Other formats are decoded whole."""
    if not path.is_file():
        raise AgriNeRFDataError(f"{path}: file named by {named_by} does not exist.")
    try:
        image = Image.open(path)
    except Exception as error:  # PIL raises several types for unreadable files
        raise AgriNeRFDataError(f"{path}: cannot read the image named by {named_by}: {error}") from error
    with image:
        size = image.size
        try:
            fault = _whole_image_fault(image, path)
        except Exception as error:  # a cut or corrupt file: PIL raises SyntaxError, OSError, ...
            fault = f"truncated or corrupt ({error})"
    if fault is not None:
        raise AgriNeRFDataError(f"{path}: the image named by {named_by} is {fault}; write it again.")
    return size


def _whole_image_fault(image: Image.Image, path: Path) -> Optional[str]:
    """None when the open ``image`` (of file ``path``) is whole, else what is wrong with it."""
    if image.format == "PNG":
        image.verify()  # walks every chunk, checks its CRC; raises on a cut or corrupt file
        with open(path, "rb") as handle:
            handle.seek(max(path.stat().st_size - len(PNG_END), 0))
            return None if handle.read() == PNG_END else "truncated (it does not end with the PNG IEND chunk)"
    if image.format == "JPEG":
        with open(path, "rb") as handle:
            handle.seek(max(path.stat().st_size - 64, 0))
            tail = handle.read().rstrip(b"\x00")  # some writers pad after the marker
        return None if tail.endswith(JPEG_END) else "truncated (it does not end with the JPEG end-of-image marker)"
    image.load()  # other formats: decode it (raises on a cut file)
    return None


def check_frame_image(
    path: Path, frame: Dict[str, Any], meta: Dict[str, Any], frame_key: str, transforms_path: Path
) -> None:
    """An image a frame names under ``frame_key`` (the RGB image, or a thermal/event frame, mask, temperature image
    or fruit mask) exists, is whole and has the frame's ``w`` x ``h`` when those are given: the RGB frame's full
    resolution, which every aligned image is warped to."""
    size = check_image_file(path, f"'{frame_key}' in {transforms_path}")
    width, height = frame.get("w", meta.get("w")), frame.get("h", meta.get("h"))
    if width is None or height is None or size == (int(width), int(height)):
        return
    if frame_key == IMAGE.key:
        raise AgriNeRFDataError(
            f"{path}: image is {size[0]}x{size[1]} but {transforms_path} gives its frame w x h = "
            f"{int(width)}x{int(height)}."
        )
    raise AgriNeRFDataError(
        f"{path}: image is {size[0]}x{size[1]} but its RGB frame {frame[IMAGE.key]} is "
        f"{int(width)}x{int(height)}; '{frame_key}' images must be warped into the RGB camera at its resolution."
    )


def check_dataset(data: Path) -> Dict[str, Any]:
    """Read and check the dataset at ``data`` (its folder or its ``transforms.json``): :func:`read_transforms` and
    :func:`check_transforms`. Returns the parsed file."""
    path = data if data.suffix == ".json" else data / TRANSFORMS
    meta = read_transforms(path)
    check_transforms(meta, path)
    return meta
