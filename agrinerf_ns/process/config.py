"""Options of ``agrinerf-process`` (:class:`ProcessConfig`), shared by the pipeline and its steps."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

from agrinerf_ns.process import exposure
from agrinerf_ns.process import poses as pose_utils
from agrinerf_ns.process.event_frames import EventFrameConfig
from agrinerf_ns.process.fruit_mask_makers import MaskMaker, MaskMakerConfig
from agrinerf_ns.process.thermal_rescale import ThermalRescaleConfig


@dataclass
class ProcessConfig:
    """Options of ``agrinerf-process`` (and :func:`process_capture`)."""

    poses: Literal["auto", "sfm-rgb", "sfm-thermal", "given", "sfm-on-odometry"] = "auto"
    """Pose source: SfM on RGB, on the rescaled aligned thermal frames, auto (RGB first; thermal too unless RGB
    registered every frame; keep whichever registers more, RGB on a tie), the capture's odometry.txt, or SfM on RGB
    placed in the odometry's frame and scale (``sfm-on-odometry``: a similarity fitted to the odometry's cameras;
    SfM's local geometry, the odometry's world frame and metres; where SfM places fewer than ``min_registered_frac``
    of the frames, as on dark RGB frames, the odometry's poses are kept)."""
    sfm_max_disagreement_deg: float = 0.5
    """``sfm-on-odometry``: SfM's poses are kept where their orientations, once on the odometry, differ from the
    odometry's by at most this many degrees on average; above it SfM has drifted (it did on low-texture gardens)
    and the odometry's poses are kept (chosen on tuning captures: results/fruit-count-lit/README.md)."""
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
    fruit_masks: Optional[Path] = None
    """A folder of fruit masks, one per raw RGB frame named like it (a FruitNeRF dataset folder: its semantics/), from
    the user's segmenter: 0 background, 128 unknown, any other value fruit. They train the fruit head
    (`agrinerf-count --path fruit`)."""
    fruit_mask_maker: MaskMaker = "none"
    """Fruit masks made from the captured frames instead (agrinerf_ns/process/fruit_mask_makers.py): colour (lit RGB
    frames), thermal (temperature contrast, no light needed), auto (colour where the RGB frames are lit, thermal where
    they are dark), yolo (a YOLOv8 detector's boxes on lit RGB frames, --mask-maker.yolo-weights; the AGPL extra),
    none: no masks unless --fruit-masks gives them."""
    mask_maker: MaskMakerConfig = field(default_factory=MaskMakerConfig)
    """Settings of the mask makers."""
    overwrite: bool = False
    """Replace an existing non-empty output folder."""
    show_progress: bool = True
    """Rich progress bars."""
