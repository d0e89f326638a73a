"""Readers of the capture's frames: the frame lists (``timestamps.txt``), RGB frames and raw thermal frames."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional, Tuple

import cv2
import numpy as np
from jaxtyping import Float, UInt8, UInt16

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.flir import read_flir
from agrinerf_ns.process.readers.time_list import read_time_list


@dataclass(frozen=True)
class FrameList:
    """Frames of one sensor: file paths and times in seconds, sorted by time."""

    paths: List[Path]
    times: Float[np.ndarray, " n"]

    def __len__(self) -> int:
        return len(self.paths)


def read_timestamps(folder: Path) -> FrameList:
    """Read ``folder/timestamps.txt`` ("<file name> <time in seconds>" per line)."""
    ts_file = folder / "timestamps.txt"
    if not ts_file.is_file():
        raise RawInputError(f"{ts_file}: missing timestamps file")
    paths: List[Path] = []
    times: List[float] = []
    for row in read_time_list(ts_file, ("file name", "time")):
        frame = folder / row.name
        if not frame.is_file():
            raise RawInputError(f"{ts_file}:{row.lineno}: frame file {frame} does not exist")
        paths.append(frame)
        times.append(row.times[0])
    if not paths:
        raise RawInputError(f"{ts_file}: no frames listed")
    t_arr = np.asarray(times, dtype=np.float64)
    if np.any(np.diff(t_arr) <= 0):
        bad = int(np.argmax(np.diff(t_arr) <= 0)) + 1
        raise RawInputError(f"{ts_file}: times must increase strictly (frame {paths[bad].name} at {t_arr[bad]})")
    return FrameList(paths=paths, times=t_arr)


def read_rgb(path: Path) -> UInt8[np.ndarray, "h w 3"]:
    """Read an 8-bit RGB frame (returned in RGB channel order)."""
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        raise RawInputError(f"{path}: RGB frame must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] != 3:
        raise RawInputError(f"{path}: RGB frame must have 3 channels, got shape {img.shape}")
    return np.ascontiguousarray(img[:, :, ::-1])


def read_thermal(path: Path, expected_hw: Optional[Tuple[int, int]] = None) -> UInt16[np.ndarray, "h w"]:
    """Read a raw single-channel thermal frame (16-bit counts; 8-bit is widened). PNG or TIFF, by content; a
    ``.jpg`` is a FLIR radiometric JPEG (its embedded raw counts, :mod:`agrinerf_ns.process.flir`)."""
    if Path(path).suffix.lower() in (".jpg", ".jpeg"):
        img = read_flir(path).counts
    else:
        img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        if img.shape[2] == 1 or np.all(img == img[:, :, :1]):
            img = img[:, :, 0]
        else:
            raise RawInputError(f"{path}: thermal frame must be single-channel, got shape {img.shape}")
    if img.dtype == np.uint8:
        img = img.astype(np.uint16)
    if img.dtype != np.uint16:
        raise RawInputError(f"{path}: thermal frame must be 16-bit unsigned counts, got {img.dtype}")
    if expected_hw is not None and tuple(img.shape) != tuple(expected_hw):
        raise RawInputError(
            f"{path}: thermal frame is {img.shape[1]}x{img.shape[0]} (w x h) but calibration says "
            f"{expected_hw[1]}x{expected_hw[0]}"
        )
    return img


def _imread(path: Path, flags: int) -> np.ndarray:
    if not Path(path).is_file():
        raise RawInputError(f"{path}: file does not exist")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, flags) if data.size else None
    if img is None:
        raise RawInputError(f"{path}: cannot decode image (corrupt or not an image file)")
    return img
