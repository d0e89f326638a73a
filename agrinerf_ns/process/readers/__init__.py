"""Readers for a raw capture folder (layout in docs/formats.md), one module per format:

- :mod:`~agrinerf_ns.process.readers.frames`: frame lists (``timestamps.txt``), RGB and raw thermal frames;
- :mod:`~agrinerf_ns.process.readers.calibration`: the rig calibration ``calib.yaml``;
- :mod:`~agrinerf_ns.process.readers.events`: event files, read in chunks, and their external-trigger events;
- :mod:`~agrinerf_ns.process.readers.time_list`: the parser of "<file name> <time>" lists the others share.

TUM trajectories (``odometry.txt``, ``truth/poses.txt``) are read with the trajectory (:func:`agrinerf_ns.trajectory.read_tum`).

Every reader raises :class:`~agrinerf_ns.process.errors.RawInputError` naming the file and the problem; none writes
anything. The names below are the readers' public interface (``from agrinerf_ns.process.readers import ...``).
"""

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.readers.calibration import CameraCalib, RigCalib, read_calibration
from agrinerf_ns.process.readers.events import (
    EVENT_FILE_NAMES,
    EventChunk,
    TriggerEvents,
    count_events,
    find_event_file,
    iter_event_chunks,
    read_triggers,
)
from agrinerf_ns.process.readers.frames import FrameList, read_rgb, read_thermal, read_timestamps
from agrinerf_ns.process.readers.time_list import TimeListLine, read_time_list

__all__ = [
    "EVENT_FILE_NAMES",
    "CameraCalib",
    "EventChunk",
    "FrameList",
    "RawInputError",
    "RigCalib",
    "TimeListLine",
    "TriggerEvents",
    "count_events",
    "find_event_file",
    "iter_event_chunks",
    "read_calibration",
    "read_rgb",
    "read_thermal",
    "read_time_list",
    "read_timestamps",
    "read_triggers",
]
