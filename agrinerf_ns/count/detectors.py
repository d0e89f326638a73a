"""Fruit detectors for counting: ``blobs`` (OpenCV, the default; :mod:`agrinerf_ns.fruit.blobs`) or ``yolo``
(weights trained by ``agrinerf-detect``; Ultralytics is the optional AGPL-3.0 extra and is imported only here,
by :func:`agrinerf_ns.fruit.yolo.box_predictor`, when it is asked for)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Callable, List, Literal, Optional

import numpy as np
import tyro

from agrinerf_ns.count.render import RenderedView
from agrinerf_ns.count.source_table import rgb_eight_bit, source_row
from agrinerf_ns.count.sources import SourceChoice, resolve_source
from agrinerf_ns.fruit.blobs import BlobConfig, Detection
from agrinerf_ns.fruit.ellipse import inscribed_ellipse
from agrinerf_ns.fruit.view import MIN_ACCUMULATION

DetectorName = Literal["blobs", "yolo"]


@dataclass(frozen=True)
class DetectorConfig:
    """Which detector finds fruit in the rendered views, and on which output."""

    detector: DetectorName = "blobs"
    """``blobs``: fruit-sized blobs found with OpenCV (no weights); ``yolo``: a YOLOv8 detector (``--weights``,
    e.g. trained by ``agrinerf-detect``; needs the optional AGPL-3.0 Ultralytics extra)."""
    source: SourceChoice = "auto"
    """The output fruit are found in: ``fruit`` (the fruit head's probability, a run trained with fruit masks; its
    regions), ``temperature`` (degrees C, where the run has one: fruit differ from leaves in temperature), the
    cross-spectral ``thermal`` or ``rgb``; ``auto``: rgb on a run whose RGB frames are lit, else the
    first of temperature, thermal, rgb the renders have (YOLO: thermal, rgb), as :mod:`agrinerf_ns.count.sources`
    resolves it."""
    weights: Optional[Path] = None
    """YOLO weights (``.pt``), for ``--detector yolo``."""
    confidence: float = 0.25
    """YOLO: lowest box score kept."""
    fruit_depth: bool = False
    """On the ``fruit`` source, lift each region by the fruit head's depth (``fruit_depth``: where along the ray the
    head puts the fruit) rather than the rendered median depth; renders without it keep the rendered depth."""
    blobs: Annotated[BlobConfig, tyro.conf.arg(name="")] = field(default_factory=BlobConfig)
    """Settings of ``--detector blobs``."""


Detector = Callable[[RenderedView, float], List[Detection]]
"""(view, dataparser scale: Nerfstudio units per dataset unit) -> the view's fruit."""


def make_detector(config: DetectorConfig) -> Detector:
    """The detector ``config`` asks for (YOLO weights are loaded once, here); ``auto`` is resolved per view, its run's
    light not known (:func:`agrinerf_ns.count.pipeline.run_count` resolves it for the whole run first)."""
    if config.detector == "yolo":
        return yolo_detector(config)

    def detect(view: RenderedView, scale: float) -> List[Detection]:
        return fruit_in_view(view, view_source(config, view), scale, config.blobs)

    return detect


def fruit_in_view(view: RenderedView, source: str, scale: float, blobs: BlobConfig = BlobConfig()) -> List[Detection]:
    """The fruit of ``view`` found as ``source``'s row finds them (contrast blobs of its image, or the fruit head's
    regions); ``scale``: the dataparser scale (Nerfstudio units per dataset unit)."""
    return source_row(source).find(view, scale, blobs)


def view_source(config: DetectorConfig, view: RenderedView) -> str:
    """The source ``config`` detects on in ``view`` (:func:`agrinerf_ns.count.sources.resolve_source`)."""
    return resolve_source(config.source, "views", view.outputs(), config.detector)[0]


def yolo_detector(config: DetectorConfig) -> Detector:
    """YOLO boxes on a view's ``config.source`` image; a box's pixels are its inscribed ellipse (where rendered)."""
    from agrinerf_ns.fruit.yolo import box_predictor

    predict = box_predictor(config.weights, config.confidence, hint="--detector yolo needs --weights PATH")

    def detect(view: RenderedView, scale: float) -> List[Detection]:
        boxes, scores = predict(eight_bit_image(view, view_source(config, view)))
        rendered = view.accumulation >= MIN_ACCUMULATION
        height, width = rendered.shape
        return [Detection(inscribed_ellipse(height, width, box) & rendered, float(s))
                for box, s in zip(boxes, scores, strict=True)]  # fmt: skip

    return detect


def eight_bit_image(view: RenderedView, source: str) -> np.ndarray:
    """The 8-bit BGR image a YOLO detector trained by agrinerf-detect sees on ``source`` (its renders are 8-bit PNGs):
    as the source's row makes it, else the RGB render."""
    return (source_row(source).eight_bit or rgb_eight_bit)(view)
