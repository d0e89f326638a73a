"""The dataset format in one table: the files, keys and folders of a processed dataset (docs/formats.md, "Dataset
folder"), which ``agrinerf-process`` writes, the dataparser reads and the counter and detector read back.

Each per-frame file of ``transforms.json`` is one :class:`FrameFile` row of :data:`FRAME_FILES`: the key a frame names
it by, the modality it belongs to, the folder the processing writes it in, and the ``DataparserOutputs.metadata`` key
the dataparser hands its paths on by (in the order of ``image_filenames``). The encodings of the values live beside
their readers and writers: fruit masks in :mod:`agrinerf_ns.fruit_mask_format`, temperatures in
:mod:`agrinerf_ns.temperature`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Sequence, Tuple

TRANSFORMS = "transforms.json"
"""The dataset's Nerfstudio file of the RGB camera (frames, intrinsics, split and the ``agrinerf`` block)."""
THERMAL_TRANSFORMS = "transforms_thermal.json"
"""The same frames and poses with the thermal frame as ``file_path`` and its valid mask as ``mask_path``."""
TRAJECTORY = "trajectory.txt"
"""The capture's odometry as TUM lines (with ``--poses given``)."""
EVENT_STREAM = "events/stream.h5"
"""The dataset's copy of the events inside the frames' windows, at the event camera's pixels, times in microseconds of
the frames' clock (the event loss reads it: ``agrinerf_ns.dataparsers.event_stream``)."""

FRUIT_BODIES = "fruit_bodies.json"
"""Where the data stage placed the fruit in 3D, one sighting per frame that saw each (frame, camera, centre in the
poses' world frame, diameter, temperature, ray): the thermal bodies of dark and dim frames and the lit masks' fruit;
what ``agrinerf-count --path bodies`` counts (docs/formats.md)."""
BODY_CAMERAS = ("rgb", "thermal")
"""The cameras a fruit body's sighting names (``camera``); a sighting without one is the thermal camera's (the
files written before the lit masks' bodies)."""


def sighting_cameras(sightings: Sequence[dict]) -> Dict[str, int]:
    """The sightings of a ``FRUIT_BODIES`` file per camera (:data:`BODY_CAMERAS`)."""
    cameras = [row.get("camera", "thermal") for row in sightings]
    return {camera: cameras.count(camera) for camera in BODY_CAMERAS}


@dataclass(frozen=True)
class FrameFile:
    """A file every frame of a dataset may name (in every frame or none)."""

    key: str
    """The frame's key in ``transforms.json``."""
    modality: str
    """``rgb``, ``thermal``, ``events`` or ``fruit``: loaded only when the dataparser loads that modality."""
    folder: str
    """Where ``agrinerf-process`` writes it (``<folder>/<frame>.<suffix>``)."""
    metadata: str
    """Where the dataparser hands the frames' paths on: a ``DataparserOutputs.metadata`` key (for the RGB frame
    Nerfstudio's own ``DataparserOutputs.image_filenames``)."""
    valid_mask: bool = False
    """A mask of where another file of its modality holds values (255 seen), not an image of its own."""
    suffix: str = ".png"

    def path(self, frame: str) -> str:
        """The dataset-relative path ``agrinerf-process`` writes frame ``frame``'s file at."""
        return f"{self.folder}/{frame}{self.suffix}"


IMAGE = FrameFile("file_path", "rgb", "images", "image_filenames")
"""The RGB frame (8-bit PNG), Nerfstudio's own key."""
THERMAL = FrameFile("thermal_file_path", "thermal", "thermal", "thermal_filenames")
"""The rescaled thermal frame warped into the RGB camera (8-bit single-channel PNG)."""
THERMAL_MASK = FrameFile("thermal_mask_path", "thermal", "thermal_masks", "thermal_mask_filenames", valid_mask=True)
"""255 where the thermal camera saw the pixel."""
TEMPERATURE = FrameFile("thermal_temperature_path", "thermal", "thermal_temperature", "temperature_filenames")
"""The linear temperature warped into the RGB camera (16-bit PNG in centikelvin, :mod:`agrinerf_ns.temperature`);
only where the thermal camera has a radiometric calibration."""
EVENTS = FrameFile("event_file_path", "events", "events", "event_filenames")
"""The signed polarity sum of the frame's window (8-bit PNG, 128: no change)."""
EVENT_MASK = FrameFile("event_mask_path", "events", "event_masks", "event_mask_filenames", valid_mask=True)
"""255 where the event camera saw the pixel."""
EVENT_SUMS = FrameFile("event_sums_path", "events", "events", "event_sums_filenames", suffix=".npz")
"""ON and OFF counts per RGB pixel of the frame's window (``pos``, ``neg``, ``mask``, ``t_start``, ``t_end``)."""
FRUIT_MASK = FrameFile("fruit_mask_file_path", "fruit", "fruit_masks", "fruit_mask_filenames")
"""The frame's fruit mask (8-bit, :mod:`agrinerf_ns.fruit_mask_format`), in every training frame or none."""

FRAME_FILES: Tuple[FrameFile, ...] = (IMAGE, THERMAL, THERMAL_MASK, TEMPERATURE, EVENTS, EVENT_MASK, EVENT_SUMS,
                                      FRUIT_MASK)  # fmt: skip
"""Every file a frame names (a dropped frame's files are these)."""
ALIGNED_FRAMES: Tuple[FrameFile, ...] = (THERMAL, THERMAL_MASK, EVENTS, EVENT_MASK)
"""The thermal and event images and their valid masks: warped into the RGB camera at its resolution, in every frame
or none, and handed on as they are; a modality is in the dataset when its image (not only its mask) is."""

FRUIT_MASK_CAMERA = "fruit_mask_camera"
"""``rgb`` or ``thermal``: whose view a frame's fruit mask holds (absent: rgb)."""
TIMESTAMP = "timestamp"
"""The RGB frame's time in seconds (the capture's clock)."""
THERMAL_TIMESTAMP = "thermal_timestamp"
"""The time of the thermal frame matched to the RGB frame (seconds, the same clock)."""
EXPOSURE_START, EXPOSURE_END = "exposure_start", "exposure_end"
"""The RGB frame's exposure interval (seconds), in every frame or none."""

BLOCK = "agrinerf"
"""The top-level block of ``transforms.json`` that records how the dataset was made."""
