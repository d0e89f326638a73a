"""Raw capture folder -> tri-modal dataset folder (:func:`process_capture`).

The capture is checked first (:mod:`~agrinerf_ns.process.raw_capture`), then each modality has its step: RGB
(:mod:`~agrinerf_ns.process.step_rgb`), thermal (:mod:`~agrinerf_ns.process.step_thermal`), events
(:mod:`~agrinerf_ns.process.step_events`) and poses (:mod:`~agrinerf_ns.process.step_poses`); this module runs them
into a temporary folder and writes the frames that keep a pose and the metadata as ``transforms.json``.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from agrinerf_ns.dataset_format import BLOCK, EXPOSURE_END, EXPOSURE_START, FRAME_FILES, IMAGE, TIMESTAMP, TRANSFORMS
from agrinerf_ns.process import exposure
from agrinerf_ns.process import poses as pose_utils
from agrinerf_ns.process.config import ProcessConfig
from agrinerf_ns.process.console import CONSOLE
from agrinerf_ns.process.dataset_writer import (
    atomic_output_dir,
    check_output,
    intrinsics_block,
    remove_files,
    write_transforms,
)
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.fruit_mask_makers import check_mask_maker, make_fruit_masks, rgb_views_of, thermal_views
from agrinerf_ns.process.raw_capture import Capture, inspect_capture
from agrinerf_ns.process.readers import read_triggers
from agrinerf_ns.process.step_events import write_event_frames
from agrinerf_ns.process.step_fruit_masks import check_fruit_masks, find_fruit_masks, write_fruit_masks
from agrinerf_ns.process.step_poses import estimate_poses, write_odometry_trajectory
from agrinerf_ns.process.step_rgb import write_rgb_frames
from agrinerf_ns.process.step_thermal import write_thermal_frames
from agrinerf_ns.process.trigger_sync import fit_trigger_sync
from agrinerf_ns.trajectory import TrajectoryError, read_tum

__all__ = ["CONSOLE", "ProcessConfig", "inspect_capture", "process_capture", "recorded_plane_depth"]


def recorded_plane_depth(dataset: Path) -> float:
    """The warp plane depth (m) a dataset was processed with (``inf`` also when the dataset does not record one)."""
    meta = json.loads((Path(dataset) / TRANSFORMS).read_text()).get(BLOCK, {})
    return float(meta.get("alignment", {}).get("plane_depth", "inf"))


def process_capture(raw: Path, out: Path, config: ProcessConfig) -> Path:
    """Process the raw capture folder ``raw`` into the dataset folder ``out`` (written atomically) and return it.

    Raises :class:`RawInputError` (message names the file and the problem) on bad input; nothing is left at
    ``out`` then, and ``raw`` is never written to.
    """
    raw, out = Path(raw), Path(out)
    if not config.plane_depth > 0:
        raise ValueError(f"plane depth must be positive (or inf), got {config.plane_depth}")
    if not raw.is_dir():
        raise RawInputError(f"{raw}: raw capture folder does not exist")
    check_output(raw, out, config.overwrite)
    cap = inspect_capture(raw)
    cap.exposure, cap.exposure_meta = exposure.frame_exposures(raw, cap.rgb, config.exposure_time,
                                                                config.exposure_timestamp)  # fmt: skip
    for w in cap.warnings:
        CONSOLE.log(f"[yellow]Warning: {w}")
    if config.poses == "sfm-thermal" and cap.thermal is None:
        raise RawInputError(f"{raw}: --poses sfm-thermal needs thermal frames")
    if config.poses in ("given", "sfm-on-odometry"):
        if not (raw / "odometry.txt").is_file():
            raise RawInputError(f"{raw / 'odometry.txt'}: missing; --poses {config.poses} needs the odometry file")
        try:  # every line checked (8 finite numbers) before any output is written
            read_tum(raw / "odometry.txt")
        except TrajectoryError as err:
            raise RawInputError(str(err)) from err
    if config.sync == "trigger":
        if cap.event_file is None:
            raise RawInputError(f"{raw / 'events'}: --sync trigger needs an event file with trigger events")
        cap.sync = fit_trigger_sync(
            cap.rgb.times,
            read_triggers(cap.event_file),
            cap.event_file,
            config.trigger_edge,
            config.trigger_channel,
            config.trigger_offset_s,
        )
        CONSOLE.log(
            f"Trigger sync: {cap.sync.matched} of {cap.sync.frames} frames matched, residual rms "
            f"{cap.sync.residual_rms_us:.1f} us (max {cap.sync.residual_max_us:.1f} us)"
        )

    fruit_masks = None
    if config.fruit_masks is not None and config.fruit_mask_maker != "none":
        raise ValueError("give either --fruit-masks DIR or --fruit-mask-maker, not both")
    check_mask_maker(config.fruit_mask_maker, config.mask_maker)
    if config.fruit_masks is not None:  # every mask found and read before any output is written
        fruit_masks = find_fruit_masks(config.fruit_masks, cap.rgb.paths)
        check_fruit_masks(fruit_masks, cap.calib.rgb.width, cap.calib.rgb.height)
    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=CONSOLE,
        disable=not config.show_progress,
    )
    with atomic_output_dir(out, config.overwrite) as tmp, progress:
        return _process(raw, out, tmp, cap, config, progress, fruit_masks)


def _process(
    raw: Path,
    out: Path,
    tmp: Path,
    cap: Capture,
    config: ProcessConfig,
    progress: Progress,
    fruit_masks: Optional[List[Path]] = None,
) -> Path:
    calib = cap.calib
    n = len(cap.rgb)
    names = [f"{i:06d}" for i in range(n)]
    frames: List[Dict] = [
        {
            IMAGE.key: IMAGE.path(names[i]),
            TIMESTAMP: float(cap.rgb.times[i]),
            "raw_rgb": str(cap.rgb.paths[i].relative_to(raw)),
        }
        for i in range(n)
    ]
    if cap.exposure is not None:
        for i in range(n):
            frames[i][EXPOSURE_START], frames[i][EXPOSURE_END] = (float(v) for v in cap.exposure[i])
    dropped: Dict[int, str] = {}
    modalities = ["rgb"]
    meta: Dict = {"version": 1, "warnings": list(cap.warnings), "exposure": cap.exposure_meta}

    write_rgb_frames(cap, tmp, frames, progress)
    if fruit_masks is not None:
        meta["fruit_masks"] = write_fruit_masks(fruit_masks, calib.rgb, tmp, frames, names)
    if cap.thermal is not None and calib.thermal is not None:
        thermal_dropped, thermal_meta = write_thermal_frames(raw, tmp, cap, config, names, frames, progress)
        dropped.update(thermal_dropped)
        meta.update(thermal_meta)
        modalities.append("thermal")
    if cap.event_file is not None and calib.event is not None:
        meta["events"] = write_event_frames(raw, tmp, cap, config, names, frames, progress)
        modalities.append("events")

    keep = np.array([i not in dropped for i in range(n)])
    c2w, pose_meta = estimate_poses(raw, tmp, cap, config, frames, keep, progress)
    if config.fruit_mask_maker != "none":  # after the poses: the thermal bodies rule places blobs in 3D
        posed = np.asarray(pose_meta["has_pose"]) & keep
        views = thermal_views(frames, c2w, posed, calib, config.plane_depth)
        meta["fruit_masks"] = make_fruit_masks(tmp, frames, names, config.fruit_mask_maker, config.mask_maker, views,
                                               rgb_views_of(c2w, posed, calib))  # fmt: skip
    for i in range(n):
        if keep[i] and not pose_meta["has_pose"][i]:
            dropped[i] = "no pose" if pose_meta["source"] == "given" else "not registered by SfM"
    del pose_meta["has_pose"]
    if pose_meta["source"] in ("given", "sfm-on-odometry"):  # the odometry shares the poses' frame
        meta["trajectory"] = write_odometry_trajectory(raw, tmp)
    kept_frames = _keep_posed_frames(raw, tmp, cap, frames, pose_utils.opencv_to_opengl(c2w), dropped)
    pose_meta["dropped_frames"] = [
        {"file": str(cap.rgb.paths[i].relative_to(raw)), "reason": r} for i, r in sorted(dropped.items())
    ]
    meta.update(
        modalities=modalities,
        calibration={
            k: c.as_dict()
            for k, c in (("rgb", calib.rgb), ("thermal", calib.thermal), ("event", calib.event))
            if c is not None
        },
        alignment={
            "target": "rgb",
            "method": "plane homography + radtan distortion, one cv2.remap",
            "plane_depth": "inf" if not np.isfinite(config.plane_depth) else float(config.plane_depth),
        },
        poses=pose_meta,
        raw=str(raw.resolve()),
    )
    rgb_cam = calib.rgb
    write_transforms(
        tmp, intrinsics_block(rgb_cam.K, rgb_cam.width, rgb_cam.height), kept_frames, meta, config.eval_every
    )
    CONSOLE.log(f"Wrote {len(kept_frames)} frames ({', '.join(modalities)}) to {out}")
    return out


def _keep_posed_frames(raw: Path, tmp: Path, cap: Capture, frames: List[Dict], gl: np.ndarray, dropped: Dict[int, str]):
    """The frames not dropped, each with its pose (OpenGL axes); the dropped frames' files are removed."""
    kept_frames = []
    for i in range(len(frames)):
        if i in dropped:
            remove_files(tmp, [frames[i].get(f.key) for f in FRAME_FILES])
            continue
        frames[i]["transform_matrix"] = gl[i].tolist()
        kept_frames.append(frames[i])
    if len(kept_frames) < 2:
        raise RawInputError(f"{raw}: fewer than 2 frames left after pairing and posing ({len(dropped)} dropped)")
    if dropped:
        CONSOLE.log(f"[yellow]Dropped {len(dropped)} of {len(frames)} frames (see agrinerf.poses.dropped_frames)")
    return kept_frames
