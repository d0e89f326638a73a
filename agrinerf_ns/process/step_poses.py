"""The pose step of ``agrinerf-process``: a camera-to-world pose for each RGB frame, from the capture's odometry
(``--poses given``) or from pycolmap SfM on the dataset's RGB or aligned thermal frames, and the odometry as the
dataset's trajectory."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Dict, List

import cv2
import numpy as np
from rich.progress import Progress

from agrinerf_ns.dataset_format import IMAGE, THERMAL, THERMAL_MASK, TRAJECTORY
from agrinerf_ns.process import poses as pose_utils
from agrinerf_ns.process.config import ProcessConfig
from agrinerf_ns.process.console import CONSOLE
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.raw_capture import Capture, frame_interval
from agrinerf_ns.trajectory import read_tum, write_tum


def estimate_poses(
    raw: Path, tmp: Path, cap: Capture, config: ProcessConfig, frames: List[Dict], keep, progress: Progress
):
    """Camera-to-world (OpenCV axes) for every RGB frame, and the poses metadata (with a has_pose list)."""
    n = len(frames)
    if config.poses == "given":
        tol = config.max_time_offset_s if config.max_time_offset_s is not None else 0.5 * frame_interval(cap.rgb.times)
        c2w, ok = pose_utils.poses_from_odometry(raw / "odometry.txt", cap.rgb.times, max(tol, 1e-6))
        return c2w, {"source": "given", "requested": "given", "file": "odometry.txt", "has_pose": ok.tolist()}
    idx = np.flatnonzero(keep)
    runs: Dict[str, pose_utils.SfmResult] = {}
    wanted = {"sfm-rgb": ["rgb"], "sfm-thermal": ["thermal"], "auto": ["rgb", "thermal"]}[config.poses]
    if cap.thermal is None:
        wanted = [w for w in wanted if w != "thermal"]
    for source in wanted:
        if runs and max(r.num_registered for r in runs.values()) == len(idx):
            break  # auto: RGB registered every frame, thermal cannot do better
        task = progress.add_task(f"SfM ({source})", total=None)
        if source == "rgb":
            images = [cv2.cvtColor(cv2.imread(str(tmp / frames[i][IMAGE.key])), cv2.COLOR_BGR2RGB) for i in idx]
            masks = None
        else:
            images = [cv2.imread(str(tmp / frames[i][THERMAL.key]), cv2.IMREAD_GRAYSCALE) for i in idx]
            if config.sfm.thermal_clahe:
                clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(4, 4))
                images = [clahe.apply(im) for im in images]
            masks = [cv2.imread(str(tmp / frames[i][THERMAL_MASK.key]), cv2.IMREAD_GRAYSCALE) for i in idx]
        work = tmp / f".sfm_{source}"
        res = pose_utils.run_sfm(images, cap.calib.rgb.K, work, config.sfm, f"sfm-{source}", masks=masks)
        shutil.rmtree(work, ignore_errors=True)
        runs[source] = res
        progress.update(task, total=1, completed=1)
        CONSOLE.log(f"SfM on {source}: registered {res.num_registered} of {len(idx)} frames")
    best = max(runs, key=lambda s: (runs[s].num_registered, s == "rgb"))
    res = runs[best]
    if res.num_registered < config.min_registered_frac * len(idx):
        raise RawInputError(
            f"{raw}: SfM registered only {res.num_registered} of {len(idx)} frames "
            f"({', '.join(f'{k}: {v.num_registered}' for k, v in runs.items())})"
        )
    c2w = np.tile(np.eye(4), (n, 1, 1))
    has = np.zeros(n, dtype=bool)
    c2w[idx] = res.c2w
    has[idx] = res.registered
    return c2w, {
        "source": res.source,
        "requested": config.poses,
        "registered": {f"sfm-{k}": v.num_registered for k, v in runs.items()},
        "frames_tried": int(len(idx)),
        "has_pose": has.tolist(),
    }


def write_odometry_trajectory(raw: Path, tmp: Path) -> Dict:
    """The whole odometry as the dataset's ``trajectory.txt`` (OpenGL axes), for poses between frames
    (:mod:`agrinerf_ns.trajectory`); returns its metadata."""
    odo_t, odo_c2w = read_tum(raw / "odometry.txt")
    write_tum(tmp / TRAJECTORY, odo_t, pose_utils.opencv_to_opengl(odo_c2w))
    return {"file": TRAJECTORY, "source": "odometry.txt", "samples": int(len(odo_t))}
