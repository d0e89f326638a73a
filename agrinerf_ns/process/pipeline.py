"""Raw capture folder -> tri-modal dataset folder (``process_capture``); the steps are in the sibling modules."""

from __future__ import annotations

import json
import math
import shutil
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Literal, Optional, Union

import numpy as np
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from agrinerf_ns import temperature
from agrinerf_ns.images import to_uint8, write_png
from agrinerf_ns.process import align, event_frames, exposure, radiometric, readers
from agrinerf_ns.process import poses as pose_utils
from agrinerf_ns.process.dataset_writer import (
    atomic_output_dir,
    check_output,
    intrinsics_block,
    remove_files,
    write_trajectory,
    write_transforms,
)
from agrinerf_ns.process.event_frames import EventFrameConfig
from agrinerf_ns.process.event_h5 import EventH5Writer
from agrinerf_ns.process.readers import RawInputError
from agrinerf_ns.process.thermal_rescale import ThermalRescaleConfig, ThermalRescaler
from agrinerf_ns.process.trigger_sync import TriggerSync, fit_trigger_sync

CONSOLE = Console(stderr=True)


@dataclass
class ProcessConfig:
    """Options of ``agrinerf-process`` (and :func:`process_capture`)."""

    poses: Literal["auto", "sfm-rgb", "sfm-thermal", "given"] = "auto"
    """Pose source: SfM on RGB, on the rescaled aligned thermal frames, auto (RGB first; thermal too unless RGB
    registered every frame; keep whichever registers more, RGB on a tie), or the capture's odometry.txt."""
    thermal: ThermalRescaleConfig = field(default_factory=ThermalRescaleConfig)
    """Thermal rescaling."""
    events: EventFrameConfig = field(default_factory=EventFrameConfig)
    """Event frames."""
    sfm: pose_utils.SfmConfig = field(default_factory=pose_utils.SfmConfig)
    """pycolmap settings."""
    plane_depth: float = float("inf")
    """Depth (m, RGB camera frame) of the plane used to warp thermal/event frames into the RGB camera."""
    eval_every: int = 8
    """Every n-th frame goes to the val/test split lists written into transforms.json."""
    max_time_offset_s: Optional[float] = None
    """Largest time gap when pairing RGB frames with thermal frames / odometry (None: half a frame interval of the
    slower sensor)."""
    sync: Literal["recorded", "trigger"] = "recorded"
    """Event windows at the recorded frame times, or at the frame times mapped into event time through the
    event camera's external-trigger edges (the rig triggers its cameras; residual in agrinerf.events.sync)."""
    trigger_edge: Literal["rising", "falling"] = "rising"
    """--sync trigger: the edge that triggers a frame."""
    trigger_channel: Optional[int] = None
    """--sync trigger: only trigger events of this channel id (None: all)."""
    trigger_offset_s: float = 0.0
    """--sync trigger: coarse offset (event clock minus frame clock, s) before frames are matched to the nearest
    edge; 0 when event times are on the frames' clock (agrinerf_ns.process.rosbag's default event_clock)."""
    exposure_time: Optional[float] = None
    """RGB exposure time in seconds for every frame (captures without rgb/exposures.txt, or to override it); None:
    rgb/exposures.txt when the capture has one, else no exposure intervals in the dataset."""
    exposure_timestamp: exposure.TimestampAt = "middle"
    """Where a frame's timestamp lies in its exposure, for --exposure-time: middle, start or end."""
    min_registered_frac: float = 0.5
    """Fail when SfM registers fewer than this fraction of the frames."""
    overwrite: bool = False
    """Replace an existing non-empty output folder."""
    show_progress: bool = True
    """Rich progress bars."""


@dataclass
class _Capture:
    calib: readers.RigCalib
    rgb: readers.FrameList
    thermal: Optional[readers.FrameList]
    event_file: Optional[Path]
    num_events: int
    warnings: List[str]
    exposure: Optional[np.ndarray] = None
    """(start, end) seconds of each RGB frame's exposure, or None when unknown."""
    exposure_meta: Dict = field(default_factory=dict)
    sync: Optional[TriggerSync] = None


def inspect_capture(raw: Path) -> _Capture:
    """Read the calibration and timestamps and check that the sensors' data agree with each other."""
    if not raw.is_dir():
        raise RawInputError(f"{raw}: raw capture folder does not exist")
    calib_path = raw / "calib.yaml"
    calib = readers.read_calibration(calib_path)
    rgb = readers.read_timestamps(raw / "rgb")
    warnings: List[str] = []
    thermal = None
    if (raw / "thermal").is_dir():
        if calib.thermal is None:
            raise RawInputError(
                f"{calib_path}: thermal frames in {raw / 'thermal'} but no camera with modality: thermal"
            )
        thermal = readers.read_timestamps(raw / "thermal")
    elif calib.thermal is not None:
        warnings.append(f"{calib_path}: a thermal camera is calibrated but {raw / 'thermal'} does not exist")
    event_file = readers.find_event_file(raw / "events")
    num_events = 0
    if event_file is not None:
        if calib.event is None:
            raise RawInputError(f"{calib_path}: events in {event_file} but no camera with modality: event")
        if event_file.suffix == ".raw":
            from agrinerf_ns.process.event_codecs import read_raw_header

            head = read_raw_header(event_file)
            if head.width is not None and (head.width, head.height) != (calib.event.width, calib.event.height):
                raise RawInputError(
                    f"{event_file}: the header says a {head.width}x{head.height} sensor but {calib_path} gives the "
                    f"event camera {calib.event.width}x{calib.event.height}"
                )
        try:
            num_events = readers.count_events(event_file)
        except (OSError, KeyError, ValueError) as err:
            raise RawInputError(f"{event_file}: cannot read event file ({err})") from err
        if num_events == 0:
            warnings.append(f"{event_file}: event file is empty; the dataset will have no event frames")
            event_file = None
    elif calib.event is not None:
        warnings.append(f"{calib_path}: an event camera is calibrated but {raw / 'events'} has no event file")
    return _Capture(calib, rgb, thermal, event_file, num_events, warnings)


def _interval(times: np.ndarray) -> float:
    return float(np.median(np.diff(times))) if len(times) > 1 else 0.0


def recorded_plane_depth(dataset: Path) -> float:
    """The warp plane depth (m) a dataset was processed with (``inf`` also when the dataset does not record one)."""
    meta = json.loads((Path(dataset) / "transforms.json").read_text()).get("agrinerf", {})
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
    if config.poses == "given" and not (raw / "odometry.txt").is_file():
        raise RawInputError(f"{raw / 'odometry.txt'}: missing; --poses given needs the odometry file")
    if config.sync == "trigger":
        if cap.event_file is None:
            raise RawInputError(f"{raw / 'events'}: --sync trigger needs an event file with trigger events")
        cap.sync = fit_trigger_sync(
            cap.rgb.times,
            readers.read_triggers(cap.event_file),
            cap.event_file,
            config.trigger_edge,
            config.trigger_channel,
            config.trigger_offset_s,
        )
        CONSOLE.log(
            f"Trigger sync: {cap.sync.matched} of {cap.sync.frames} frames matched, residual rms "
            f"{cap.sync.residual_rms_us:.1f} us (max {cap.sync.residual_max_us:.1f} us)"
        )

    progress = Progress(
        TextColumn("{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=CONSOLE,
        disable=not config.show_progress,
    )
    with atomic_output_dir(out, config.overwrite) as tmp, progress:
        return _process(raw, out, tmp, cap, config, progress)


def _process(raw: Path, out: Path, tmp: Path, cap: _Capture, config: ProcessConfig, progress: Progress) -> Path:
    calib = cap.calib
    rgb_cam = calib.rgb
    n = len(cap.rgb)
    names = [f"{i:06d}" for i in range(n)]
    frames: List[Dict] = [
        {
            "file_path": f"images/{names[i]}.png",
            "timestamp": float(cap.rgb.times[i]),
            "raw_rgb": str(cap.rgb.paths[i].relative_to(raw)),
        }
        for i in range(n)
    ]
    if cap.exposure is not None:
        for i in range(n):
            frames[i]["exposure_start"], frames[i]["exposure_end"] = (float(v) for v in cap.exposure[i])
    dropped: Dict[int, str] = {}
    modalities = ["rgb"]
    meta: Dict = {"version": 1, "warnings": list(cap.warnings), "exposure": cap.exposure_meta}

    # --- RGB: check, undistort, write
    und = align.undistort_maps(rgb_cam)
    task = progress.add_task("RGB frames", total=n)
    for i, path in enumerate(cap.rgb.paths):
        img = readers.read_rgb(path)
        if img.shape[:2] != (rgb_cam.height, rgb_cam.width):
            raise RawInputError(
                f"{path}: RGB frame is {img.shape[1]}x{img.shape[0]} but calibration cam0 says "
                f"{rgb_cam.width}x{rgb_cam.height}"
            )
        if und is not None:
            import cv2

            img = cv2.remap(img, und[0], und[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        write_png(tmp / frames[i]["file_path"], img)
        progress.advance(task)

    # --- thermal: pair, rescale with sequence statistics, warp into the RGB camera
    if cap.thermal is not None and calib.thermal is not None:
        th_cam, th = calib.thermal, cap.thermal
        tol = config.max_time_offset_s
        if tol is None:
            tol = 0.5 * max(_interval(cap.rgb.times), _interval(th.times)) + 1e-6
        match = pose_utils.match_times(cap.rgb.times, th.times, tol)
        if np.all(match < 0):
            raise RawInputError(
                f"{raw / 'thermal' / 'timestamps.txt'}: thermal times {th.times[0]:.3f}..{th.times[-1]:.3f} s do not "
                f"overlap the RGB times {cap.rgb.times[0]:.3f}..{cap.rgb.times[-1]:.3f} s (tolerance {tol:.4f} s)"
            )
        for i in np.flatnonzero(match < 0):
            dropped[int(i)] = "no thermal frame within the time tolerance"
        hw = (th_cam.height, th_cam.width)
        task = progress.add_task("thermal statistics", total=len(th))
        rescaler = ThermalRescaler(config.thermal).fit(_ThermalFrames(th.paths, hw, progress, task))
        maps = align.warp_maps(rgb_cam, th_cam, config.plane_depth)
        mask = (maps[2] * 255).astype(np.uint8)
        # temperatures only where the capture gives a counts-to-temperature map (calib.yaml or FLIR JPEGs)
        calibration = radiometric.capture_calibration(th_cam.radiometric, th.paths[0])
        stats = _TemperatureStats()
        task = progress.add_task("thermal frames", total=n)
        for i in range(n):
            j = int(match[i])
            if j >= 0:
                counts = readers.read_thermal(th.paths[j], hw)
                img8 = rescaler.apply(counts, j)
                frames[i]["thermal_file_path"] = f"thermal/{names[i]}.png"
                frames[i]["thermal_mask_path"] = f"thermal_masks/{names[i]}.png"
                frames[i]["raw_thermal"] = str(th.paths[j].relative_to(raw))
                write_png(tmp / frames[i]["thermal_file_path"], align.warp_image(img8, maps))
                write_png(tmp / frames[i]["thermal_mask_path"], mask)
                if calibration is not None:
                    frames[i]["thermal_temperature_path"] = f"thermal_temperature/{names[i]}.png"
                    write_png(tmp / frames[i]["thermal_temperature_path"],
                              stats.add(_temperature_image(calibration, counts, maps)))  # fmt: skip
            progress.advance(task)
        modalities.append("thermal")
        if calibration is not None:
            meta["thermal_radiometric"] = calibration.as_dict()
            meta["thermal_temperature"] = {"encoding": temperature.ENCODING, "calibration": calibration.source,
                                           **stats.as_dict()}  # fmt: skip
        meta["thermal_rescale"] = rescaler.params()
        if th.paths[0].suffix.lower() in (".jpg", ".jpeg"):
            from agrinerf_ns.process import flir

            # the JPEG's camera info, and the map the temperatures use (the JPEG's, unless calib.yaml gives one)
            meta["thermal_radiometric"] = {
                "source": "FLIR radiometric JPEG (first frame's camera info)",
                "counts_to_kelvin": flir.MAP,
                **flir.read_flir(th.paths[0]).metadata,
                **(calibration.as_dict() if calibration is not None else {}),
            }
        meta["thermal_time_tolerance_s"] = tol

    # --- events: windows at the RGB timestamps, streamed
    if cap.event_file is not None and calib.event is not None:
        meta["events"] = _process_events(raw, tmp, cap, config, names, frames, progress)
        modalities.append("events")

    # --- poses
    keep = np.array([i not in dropped for i in range(n)])
    c2w, pose_meta = _estimate_poses(raw, tmp, cap, config, frames, keep, progress)
    for i in range(n):
        if keep[i] and not pose_meta["has_pose"][i]:
            dropped[i] = "no pose" if pose_meta["source"] == "given" else "not registered by SfM"
    del pose_meta["has_pose"]
    gl = pose_utils.opencv_to_opengl(c2w)
    if pose_meta["source"] == "given":  # the whole odometry, for poses between frames (agrinerf_ns.trajectory)
        odo_t, odo_c2w = readers.read_tum(raw / "odometry.txt")
        write_trajectory(tmp / "trajectory.txt", odo_t, pose_utils.opencv_to_opengl(odo_c2w))
        meta["trajectory"] = {"file": "trajectory.txt", "source": "odometry.txt", "samples": int(len(odo_t))}
    kept_frames = []
    for i in range(n):
        if i in dropped:
            remove_files(tmp, [frames[i].get(k) for k in _FILE_KEYS])
            continue
        frames[i]["transform_matrix"] = gl[i].tolist()
        kept_frames.append(frames[i])
    if len(kept_frames) < 2:
        raise RawInputError(f"{raw}: fewer than 2 frames left after pairing and posing ({len(dropped)} dropped)")
    pose_meta["dropped_frames"] = [
        {"file": str(cap.rgb.paths[i].relative_to(raw)), "reason": r} for i, r in sorted(dropped.items())
    ]
    if dropped:
        CONSOLE.log(f"[yellow]Dropped {len(dropped)} of {n} frames (see agrinerf.poses.dropped_frames)")

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
    write_transforms(
        tmp, intrinsics_block(rgb_cam.K, rgb_cam.width, rgb_cam.height), kept_frames, meta, config.eval_every
    )
    CONSOLE.log(f"Wrote {len(kept_frames)} frames ({', '.join(modalities)}) to {out}")
    return out


_FILE_KEYS = (
    "file_path",
    "thermal_file_path",
    "thermal_mask_path",
    "thermal_temperature_path",
    "event_file_path",
    "event_mask_path",
    "event_sums_path",
)


def _temperature_image(calibration: radiometric.RadiometricCalibration, counts: np.ndarray, maps) -> np.ndarray:
    """One raw thermal frame as the dataset's temperature PNG (centikelvin, agrinerf_ns.temperature), warped into the
    RGB camera like the rescaled frame (bilinear in degrees C); 0 outside the thermal camera's view or where the
    calibration cannot map the counts."""
    celsius = align.warp_image(calibration.celsius(counts).astype(np.float32), maps)
    png = temperature.encode_celsius(celsius)
    png[~maps[2]] = 0
    return png


class _TemperatureStats:
    """Mean, standard deviation and range (degrees C) of the valid pixels of the temperature images written."""

    def __init__(self) -> None:
        self.n, self.total, self.squares = 0, 0.0, 0.0
        self.lo, self.hi = math.inf, -math.inf

    def add(self, png: np.ndarray) -> np.ndarray:
        celsius, valid = temperature.decode_celsius(png)
        values = celsius[valid].astype(np.float64)
        if values.size:
            self.n += int(values.size)
            self.total += float(values.sum())
            self.squares += float(np.square(values).sum())
            self.lo, self.hi = min(self.lo, float(values.min())), max(self.hi, float(values.max()))
        return png

    def as_dict(self) -> Dict[str, Union[int, float]]:
        if self.n == 0:
            return {"pixels": 0}
        mean = self.total / self.n
        std = math.sqrt(max(self.squares / self.n - mean * mean, 0.0))
        return {"pixels": self.n, "mean_c": round(mean, 4), "std_c": round(std, 4), "min_c": round(self.lo, 2),
                "max_c": round(self.hi, 2)}  # fmt: skip


class _ThermalFrames:
    """Re-iterable raw thermal frames (read on demand, size-checked), advancing a progress task."""

    def __init__(self, paths: List[Path], hw, progress: Progress, task) -> None:
        self.paths, self.hw, self.progress, self.task = paths, hw, progress, task

    def __iter__(self):
        for p in self.paths:
            yield readers.read_thermal(p, self.hw)
            self.progress.advance(self.task)


def _process_events(raw, tmp, cap: _Capture, config: ProcessConfig, names, frames, progress) -> Dict:
    ev_cam, rgb_cam = cap.calib.event, cap.calib.rgb
    ecfg = config.events
    # windows in the frames' clock (what the dataset and the trajectory use), read in the event camera's
    t_start, t_end, window = event_frames.event_windows(cap.rgb.times, ecfg)
    to_event_clock = cap.sync.apply if cap.sync is not None else (lambda t: np.asarray(t, np.float64))
    maps = align.warp_maps(rgb_cam, ev_cam, config.plane_depth)
    mask8 = (maps[2] * 255).astype(np.uint8)
    stream = EventH5Writer(tmp / "events", ecfg.chunk_size, STREAM_FILE)
    chunks = _stream_copy(
        readers.iter_event_chunks(cap.event_file, ecfg.chunk_size, sensor_wh=(ev_cam.width, ev_cam.height)),
        stream,
        cap.sync,
        float(to_event_clock(t_start[:1])[0]),
        float(to_event_clock(t_end[-1:])[0]),
    )
    task = progress.add_task("event windows", total=len(names))
    percentiles = []
    total_in_windows = 0
    windows = event_frames.accumulate_windows(
        chunks, to_event_clock(t_start), to_event_clock(t_end), ev_cam.width, ev_cam.height
    )
    for k, pos, neg in windows:
        total_in_windows += int(pos.sum() + neg.sum())
        pos_al = align.warp_image(pos.astype(np.float32), maps, nearest=True)
        neg_al = align.warp_image(neg.astype(np.float32), maps, nearest=True)
        percentiles.append(
            event_frames.window_percentile(event_frames.frame_value(pos_al, neg_al, ecfg.representation))
        )
        rel = f"events/{names[k]}.npz"
        (tmp / "events").mkdir(exist_ok=True)
        np.savez_compressed(
            tmp / rel,
            pos=np.clip(pos_al, 0, 65535).astype(np.uint16),
            neg=np.clip(neg_al, 0, 65535).astype(np.uint16),
            mask=maps[2],
            t_start=np.float64(t_start[k]),
            t_end=np.float64(t_end[k]),
        )
        frames[k]["event_sums_path"] = rel
        progress.advance(task)
    stream.close(0, {"clock": "frame", "width": ev_cam.width, "height": ev_cam.height})
    if total_in_windows == 0:
        raise RawInputError(
            f"{cap.event_file}: none of its {cap.num_events} events falls in a window of the RGB frames "
            f"({t_start[0]:.3f}..{t_end[-1]:.3f} s): event and RGB timestamps do not overlap"
        )
    scale = float(ecfg.clip_count) if ecfg.clip_count else event_frames.robust_scale(percentiles)
    task = progress.add_task("event frames", total=len(names))
    for k in range(len(names)):
        with np.load(tmp / frames[k]["event_sums_path"]) as z:
            value = event_frames.frame_value(
                z["pos"].astype(np.float32), z["neg"].astype(np.float32), ecfg.representation
            )
        png = to_uint8(event_frames.to_unit_frame(value, scale, ecfg.representation))
        frames[k]["event_file_path"] = f"events/{names[k]}.png"
        frames[k]["event_mask_path"] = f"event_masks/{names[k]}.png"
        write_png(tmp / frames[k]["event_file_path"], png)
        write_png(tmp / frames[k]["event_mask_path"], mask8)
        progress.advance(task)
    return {
        **ecfg.as_dict(),
        "window_s": window,
        "scale": scale,
        "num_events": cap.num_events,
        "events_in_windows": total_in_windows,
        "file": str(cap.event_file.relative_to(raw)),
        "sync": {"method": "trigger", **cap.sync.as_dict(), "edge": config.trigger_edge}
        if cap.sync is not None
        else {"method": "recorded"},
        "png_encoding": "value = png / 255; signed: 0.5 (png 128) = no change",
        "sums": "event_sums_path: npz with pos, neg (uint16 ON/OFF counts in RGB pixels, nearest warp), mask, "
        "t_start, t_end (s, frame clock)",
        "stream": f"events/{STREAM_FILE}",
    }


STREAM_FILE = "stream.h5"
"""The dataset's copy of the events inside the frames' windows, at the event camera's pixels, times in microseconds of
the frames' clock (the event loss reads it: ``agrinerf_ns.model.event_stream``)."""


def _stream_copy(chunks, sink: EventH5Writer, sync, start_s: float, end_s: float):
    """Pass the chunks through, writing their events in ``[start_s, end_s)`` (event clock) to `sink` with times
    moved into the frames' clock."""
    lo, hi = round(start_s * 1e6), round(end_s * 1e6)
    for chunk in chunks:
        a, b = np.searchsorted(chunk.t, [lo, hi], side="left")
        if b > a:
            t = chunk.t[a:b].astype(np.float64) * 1e-6
            if sync is not None:
                t = (t - sync.offset_s) / sync.scale
            sink.add(chunk.x[a:b], chunk.y[a:b], np.round(t * 1e6).astype(np.int64), chunk.p[a:b])
        yield chunk


def _estimate_poses(raw, tmp, cap: _Capture, config: ProcessConfig, frames, keep, progress):
    """Camera-to-world (OpenCV axes) for every RGB frame, and the poses metadata (with a has_pose list)."""
    n = len(frames)
    if config.poses == "given":
        tol = config.max_time_offset_s if config.max_time_offset_s is not None else 0.5 * _interval(cap.rgb.times)
        c2w, ok = pose_utils.poses_from_odometry(raw / "odometry.txt", cap.rgb.times, max(tol, 1e-6))
        return c2w, {"source": "given", "requested": "given", "file": "odometry.txt", "has_pose": ok.tolist()}
    import cv2

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
            images = [cv2.cvtColor(cv2.imread(str(tmp / frames[i]["file_path"])), cv2.COLOR_BGR2RGB) for i in idx]
            masks = None
        else:
            images = [cv2.imread(str(tmp / frames[i]["thermal_file_path"]), cv2.IMREAD_GRAYSCALE) for i in idx]
            if config.sfm.thermal_clahe:
                clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(4, 4))
                images = [clahe.apply(im) for im in images]
            masks = [cv2.imread(str(tmp / frames[i]["thermal_mask_path"]), cv2.IMREAD_GRAYSCALE) for i in idx]
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
