"""Event Camera Dataset (ECD, Mueggler et al. 2017) text layout -> a raw capture folder with given poses.

    python -m agrinerf_ns.process.ecd --ecd shapes_6dof/ --out raw/
    agrinerf-process --raw raw/ --out dataset/ --poses given

Input (one DAVIS sensor: frames and events share the camera): ``events.txt`` ("t x y p", t in seconds, p 0/1),
``images.txt`` ("t images/frame_NNNNNNNN.png"), ``images/``, ``groundtruth.txt`` ("t tx ty tz qx qy qz qw",
camera-to-world, the camera's OpenCV axes) and ``calib.txt`` ("fx fy cx cy k1 k2 p1 p2 k3" on one line).
Output: ``rgb/`` (the frames as they are, 8-bit grayscale read as RGB), ``events/events.h5`` (streamed and
validated), ``odometry.txt`` (the ground truth interpolated at each frame time: linear position, slerp rotation;
frames outside the ground-truth time span get no pose and are dropped by ``agrinerf-process``), and
``calib.yaml`` (cam0 rgb and cam1 event: same intrinsics and radtan distortion, identity extrinsics). Every input
file is checked before anything is written; the output is written to a temporary sibling and renamed into place.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import List, Tuple

import numpy as np
import tyro
import yaml

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.process import readers
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.event_h5 import EventH5Writer
from agrinerf_ns.process.readers import read_time_list
from agrinerf_ns.trajectory import TrajectoryError, read_tum

ECD_FILES = ("events.txt", "images.txt", "images", "groundtruth.txt", "calib.txt")


def read_ecd_calib(path: Path) -> Tuple[np.ndarray, np.ndarray]:
    """``calib.txt`` -> (fx, fy, cx, cy), (k1, k2, p1, p2); k3 must be 0 (Kalibr's radtan has four terms)."""
    try:
        vals = [float(v) for v in path.read_text().split()]
    except ValueError as err:
        raise RawInputError(f"{path}: non-numeric value ({err})") from err
    if len(vals) not in (4, 8, 9):
        raise RawInputError(f"{path}: expected 'fx fy cx cy k1 k2 p1 p2 k3', got {len(vals)} numbers")
    vals += [0.0] * (9 - len(vals))
    if vals[0] <= 0 or vals[1] <= 0:
        raise RawInputError(f"{path}: focal lengths must be positive, got fx={vals[0]}, fy={vals[1]}")
    if vals[8] != 0:
        raise RawInputError(f"{path}: k3 = {vals[8]} is not supported (radtan with k1 k2 p1 p2 only)")
    return np.asarray(vals[:4]), np.asarray(vals[4:8])


def read_ecd_images(ecd: Path) -> Tuple[List[Path], np.ndarray]:
    """``images.txt`` -> frame paths and times (checked: files exist, times increase)."""
    path = ecd / "images.txt"
    frames: List[Path] = []
    times: List[float] = []
    for row in read_time_list(path, ("time", "image path"), name_column=1):
        frame = ecd / row.name
        if not frame.is_file():
            raise RawInputError(f"{path}:{row.lineno}: image {frame} does not exist")
        frames.append(frame)
        times.append(row.times[0])
    if not frames:
        raise RawInputError(f"{path}: no images listed")
    t_arr = np.asarray(times)
    if np.any(np.diff(t_arr) <= 0):
        raise RawInputError(f"{path}: times must increase strictly")
    return frames, t_arr


def interpolate_poses(gt_t: np.ndarray, gt_c2w: np.ndarray, times: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
    """Camera-to-world at ``times`` (linear position, slerp rotation: :class:`agrinerf_ns.trajectory.CameraTrajectory`)
    and which times lie inside the ground truth; identity outside it."""
    from agrinerf_ns.trajectory import CameraTrajectory

    inside = (times >= gt_t[0]) & (times <= gt_t[-1])
    out = np.tile(np.eye(4), (len(times), 1, 1))
    if inside.any():
        out[inside, :3, :4] = CameraTrajectory(gt_t, gt_c2w).poses_at(times[inside])
    return out, inside


def ecd_to_raw(ecd: Path, out: Path, chunk_size: int = 2_000_000) -> Path:
    """Convert the ECD folder ``ecd`` into the raw capture folder ``out`` (docs/formats.md) and return it."""
    import cv2

    ecd, out = Path(ecd), Path(out)
    if not ecd.is_dir():
        raise RawInputError(f"{ecd}: ECD folder does not exist")
    for name in ECD_FILES:
        if not (ecd / name).exists():
            raise RawInputError(f"{ecd / name}: missing (an ECD folder has {', '.join(ECD_FILES)})")
    if out.exists() and any(out.iterdir()):
        raise FileExistsError(f"{out}: folder exists and is not empty")
    intr, dist = read_ecd_calib(ecd / "calib.txt")
    frames, times = read_ecd_images(ecd)
    first = cv2.imread(str(frames[0]), cv2.IMREAD_UNCHANGED)
    if first is None:
        raise RawInputError(f"{frames[0]}: cannot decode image")
    h, w = first.shape[:2]
    try:
        gt_t, gt_c2w = read_tum(ecd / "groundtruth.txt")
    except TrajectoryError as err:
        raise RawInputError(str(err)) from err
    if np.any(np.diff(gt_t) <= 0):
        raise RawInputError(f"{ecd / 'groundtruth.txt'}: times must increase strictly")
    c2w, inside = interpolate_poses(gt_t, gt_c2w, times)
    if not inside.any():
        raise RawInputError(
            f"{ecd / 'groundtruth.txt'}: ground truth {gt_t[0]:.3f}..{gt_t[-1]:.3f} s covers none of the image times "
            f"{times[0]:.3f}..{times[-1]:.3f} s"
        )
    with atomic_output_dir(out, overwrite=False) as tmp:
        (tmp / "rgb").mkdir()
        cam = {
            "camera_model": "pinhole",
            "intrinsics": [float(v) for v in intr],
            "distortion_model": "radtan",
            "distortion_coeffs": [float(v) for v in dist],
            "resolution": [int(w), int(h)],
        }
        calib = {
            "cam0": {**cam, "modality": "rgb"},
            "cam1": {**cam, "modality": "event", "T_cn_cnm1": np.eye(4).tolist()},
        }
        (tmp / "calib.yaml").write_text(yaml.safe_dump(calib, sort_keys=False))
        lines = []
        for frame, t in zip(frames, times, strict=True):
            shutil.copyfile(frame, tmp / "rgb" / frame.name)
            lines.append(f"{frame.name} {t:.9f}")
        (tmp / "rgb" / "timestamps.txt").write_text("\n".join(lines) + "\n")
        odo = []
        for t, T in zip(times[inside], c2w[inside], strict=True):
            from scipy.spatial.transform import Rotation

            q = Rotation.from_matrix(T[:3, :3]).as_quat()  # x y z w
            odo.append(" ".join(f"{v:.9f}" for v in (t, *T[:3, 3], *q)))
        (tmp / "odometry.txt").write_text("\n".join(odo) + "\n")
        sink = EventH5Writer(tmp / "events", chunk_size)
        for c in readers.iter_event_chunks(ecd / "events.txt", chunk_size, sensor_wh=(w, h)):
            sink.add(c.x, c.y, c.t, c.p)
        sink.close(0, {"clock": "ecd", "source": "events.txt"})
        if sink.n == 0:
            raise RawInputError(f"{ecd / 'events.txt'}: no events")
    return out


@dataclass
class EcdArgs:
    """Convert an Event Camera Dataset folder into a raw capture folder (then: agrinerf-process --poses given)."""

    ecd: Path
    """ECD folder (events.txt, images.txt, images/, groundtruth.txt, calib.txt)."""
    out: Path
    """Raw capture folder to write."""


if __name__ == "__main__":
    a = tyro.cli(EcdArgs)
    ecd_to_raw(a.ecd, a.out)
