"""The raw capture as ``agrinerf-process`` finds it: calibration, frame lists and event file, checked against each
other before any output is written."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np

from agrinerf_ns.process import readers
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.event_codecs import read_raw_header
from agrinerf_ns.process.trigger_sync import TriggerSync


@dataclass
class Capture:
    """What the raw capture holds, checked before any output is written (:func:`inspect_capture`)."""

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


def inspect_capture(raw: Path) -> Capture:
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
    return Capture(calib, rgb, thermal, event_file, num_events, warnings)


def frame_interval(times: np.ndarray) -> float:
    """Median time between frames (s); 0 for a single frame."""
    return float(np.median(np.diff(times))) if len(times) > 1 else 0.0
