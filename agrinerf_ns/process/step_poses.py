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
        c2w, ok = read_odometry(raw, cap, config)
        return c2w, {"source": "given", "requested": "given", "file": "odometry.txt", "has_pose": ok.tolist()}
    idx = np.flatnonzero(keep)
    runs: Dict[str, pose_utils.SfmResult] = {}
    wanted = {"sfm-rgb": ["rgb"], "sfm-thermal": ["thermal"], "auto": ["rgb", "thermal"], "sfm-on-odometry": ["rgb"]}[
        config.poses
    ]
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
    c2w = np.tile(np.eye(4), (n, 1, 1))
    has = np.zeros(n, dtype=bool)
    c2w[idx] = res.c2w
    has[idx] = res.registered
    if config.poses == "sfm-on-odometry":  # too few registered is no error: the odometry's poses stand in
        return on_odometry(raw, cap, config, c2w, has, runs, len(idx))
    if res.num_registered < config.min_registered_frac * len(idx):
        raise RawInputError(
            f"{raw}: SfM registered only {res.num_registered} of {len(idx)} frames "
            f"({', '.join(f'{k}: {v.num_registered}' for k, v in runs.items())})"
        )
    return c2w, {
        "source": res.source,
        "requested": config.poses,
        "registered": {f"sfm-{k}": v.num_registered for k, v in runs.items()},
        "frames_tried": int(len(idx)),
        "has_pose": has.tolist(),
    }


def on_odometry(
    raw: Path,
    cap: Capture,
    config: ProcessConfig,
    c2w: np.ndarray,
    has: np.ndarray,
    runs: Dict[str, pose_utils.SfmResult],
    tried: int,
):
    """The SfM poses ``c2w`` (frames ``has``) moved into the odometry's frame and scale by the similarity fitted to
    the frames both posed (:func:`~agrinerf_ns.process.poses.camera_similarity`); with the poses metadata. Where
    SfM registered fewer than ``min_registered_frac`` of the frames (dark RGB frames) or its orientations drifted
    from the odometry's, the odometry's poses, and why."""
    odometry, ok = read_odometry(raw, cap, config)
    registered = {f"sfm-{k}": v.num_registered for k, v in runs.items()}

    def kept(why: str, detail: str, fit: Dict) -> tuple:
        CONSOLE.log(f"[yellow]{why} ({detail}): the odometry's poses are kept")
        meta = {"source": "given", "requested": config.poses, "registered": registered, "frames_tried": tried,
                "odometry": {**fit, "kept": "odometry", "why": why}, "has_pose": ok.tolist()}  # fmt: skip
        return odometry, meta

    if has.sum() < config.min_registered_frac * tried:
        why = f"SfM registered {int(has.sum())} of {tried} frames"
        return kept(why, f"fewer than {config.min_registered_frac:.0%}", {"file": "odometry.txt"})
    both = has & ok
    if both.sum() < 3:
        raise RawInputError(
            f"{raw / 'odometry.txt'}: {int(both.sum())} frames have both an odometry pose and an SfM pose; "
            "--poses sfm-on-odometry needs 3"
        )
    scale, rot, t, rms = pose_utils.camera_similarity(c2w[both], odometry[both])
    placed = pose_utils.apply_similarity(c2w, scale, rot, t)
    disagreement = float(np.mean(pose_utils.rotation_angles_deg(placed[both][:, :3, :3], odometry[both][:, :3, :3])))
    fit = {"file": "odometry.txt", "frames": int(both.sum()), "scale": scale, "centre_rms": rms,
           "rotation_disagreement_deg": disagreement, "max_rotation_disagreement_deg": config.sfm_max_disagreement_deg}  # fmt: skip
    if disagreement > config.sfm_max_disagreement_deg:  # SfM drifted: the odometry is the better of the two
        detail = (
            f"{disagreement:.2f} degrees from the odometry's on average, more than {config.sfm_max_disagreement_deg}"
        )
        return kept("SfM's orientations drift", detail, fit)
    CONSOLE.log(f"SfM placed on the odometry: scale {scale:.4f}, centres {rms:.4f} and orientations "
                f"{disagreement:.2f} degrees off the odometry's")  # fmt: skip
    return placed, {
        "source": "sfm-on-odometry",
        "requested": config.poses,
        "registered": registered,
        "frames_tried": tried,
        "odometry": {**fit, "kept": "sfm"},
        "has_pose": has.tolist(),
    }


def read_odometry(raw: Path, cap: Capture, config: ProcessConfig):
    """The odometry's camera-to-world pose at each RGB frame's time, and which frames it covers."""
    tol = config.max_time_offset_s if config.max_time_offset_s is not None else 0.5 * frame_interval(cap.rgb.times)
    return pose_utils.poses_from_odometry(raw / "odometry.txt", cap.rgb.times, max(tol, 1e-6))


def write_odometry_trajectory(raw: Path, tmp: Path) -> Dict:
    """The whole odometry as the dataset's ``trajectory.txt`` (OpenGL axes), for poses between frames
    (:mod:`agrinerf_ns.trajectory`); returns its metadata."""
    odo_t, odo_c2w = read_tum(raw / "odometry.txt")
    write_tum(tmp / TRAJECTORY, odo_t, pose_utils.opencv_to_opengl(odo_c2w))
    return {"file": TRAJECTORY, "source": "odometry.txt", "samples": int(len(odo_t))}
