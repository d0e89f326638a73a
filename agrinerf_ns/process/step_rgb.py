"""The RGB step of ``agrinerf-process``: every RGB frame checked against the calibration, undistorted and written as
the dataset's ``images/``."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import cv2
from rich.progress import Progress

from agrinerf_ns.images import write_png
from agrinerf_ns.process import align, readers
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.raw_capture import Capture


def write_rgb_frames(cap: Capture, tmp: Path, frames: List[Dict], progress: Progress) -> None:
    """Write ``frames[i]["file_path"]`` under ``tmp`` for every RGB frame of the capture."""
    rgb_cam = cap.calib.rgb
    und = align.undistort_maps(rgb_cam)
    task = progress.add_task("RGB frames", total=len(frames))
    for i, path in enumerate(cap.rgb.paths):
        img = readers.read_rgb(path)
        if img.shape[:2] != (rgb_cam.height, rgb_cam.width):
            raise RawInputError(
                f"{path}: RGB frame is {img.shape[1]}x{img.shape[0]} but calibration cam0 says "
                f"{rgb_cam.width}x{rgb_cam.height}"
            )
        if und is not None:
            img = cv2.remap(img, und[0], und[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        write_png(tmp / frames[i]["file_path"], img)
        progress.advance(task)
