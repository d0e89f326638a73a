"""The thermal step of ``agrinerf-process``: raw thermal frames paired with the RGB frames by time, rescaled to 8 bit
with the sequence's statistics, warped into the RGB camera, and, where the capture gives a counts-to-temperature map,
written as temperature images too."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Dict, List, Tuple, Union

import numpy as np
from rich.progress import Progress

from agrinerf_ns import temperature
from agrinerf_ns.dataset_format import TEMPERATURE, THERMAL, THERMAL_MASK, THERMAL_TIMESTAMP
from agrinerf_ns.images import write_png
from agrinerf_ns.process import align, flir, radiometric, readers
from agrinerf_ns.process import poses as pose_utils
from agrinerf_ns.process.config import ProcessConfig
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.raw_capture import Capture, frame_interval
from agrinerf_ns.process.thermal_rescale import ThermalRescaler


def write_thermal_frames(
    raw: Path, tmp: Path, cap: Capture, config: ProcessConfig, names: List[str], frames: List[Dict], progress: Progress
) -> Tuple[Dict[int, str], Dict]:
    """Write the thermal files of every RGB frame that has a thermal frame within the time tolerance; returns the
    frames left without one (index: reason) and the dataset's thermal metadata."""
    assert cap.thermal is not None and cap.calib.thermal is not None
    rgb_cam, th_cam, th = cap.calib.rgb, cap.calib.thermal, cap.thermal
    n = len(frames)
    dropped: Dict[int, str] = {}
    meta: Dict = {}
    tol = config.max_time_offset_s
    if tol is None:
        tol = 0.5 * max(frame_interval(cap.rgb.times), frame_interval(th.times)) + 1e-6
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
            frames[i][THERMAL.key] = THERMAL.path(names[i])
            frames[i][THERMAL_MASK.key] = THERMAL_MASK.path(names[i])
            frames[i]["raw_thermal"] = str(th.paths[j].relative_to(raw))
            frames[i][THERMAL_TIMESTAMP] = float(th.times[j])  # its own time: the rig moves between the two
            write_png(tmp / frames[i][THERMAL.key], align.warp_image(img8, maps))
            write_png(tmp / frames[i][THERMAL_MASK.key], mask)
            if calibration is not None:
                frames[i][TEMPERATURE.key] = TEMPERATURE.path(names[i])
                write_png(tmp / frames[i][TEMPERATURE.key],
                          stats.add(_temperature_image(calibration, counts, maps)))  # fmt: skip
        progress.advance(task)
    if calibration is not None:
        meta["thermal_radiometric"] = calibration.as_dict()
        meta["thermal_temperature"] = {"encoding": temperature.ENCODING, "calibration": calibration.source,
                                       **stats.as_dict()}  # fmt: skip
    meta["thermal_rescale"] = rescaler.params()
    if th.paths[0].suffix.lower() in (".jpg", ".jpeg"):
        # the JPEG's camera info, and the map the temperatures use (the JPEG's, unless calib.yaml gives one)
        meta["thermal_radiometric"] = {
            "source": "FLIR radiometric JPEG (first frame's camera info)",
            "counts_to_kelvin": flir.MAP,
            **flir.read_flir(th.paths[0]).metadata,
            **(calibration.as_dict() if calibration is not None else {}),
        }
    meta["thermal_time_tolerance_s"] = tol
    return dropped, meta


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
