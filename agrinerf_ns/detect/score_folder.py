"""Score a folder of rendered views: detect with a trained detector, match against the scene's true boxes."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional

from agrinerf_ns.detect.bootstrap import MatchedImages
from agrinerf_ns.detect.box_metrics import DetectionMetrics, ImageBoxes, score_detections
from agrinerf_ns.detect.boxes import SceneTruth, list_images, yolo_to_xyxy
from agrinerf_ns.detect.detector import predict_folder
from agrinerf_ns.detect.figure import PanelBoxes


@dataclass(frozen=True, eq=False)
class ScoredViews:
    """One method's rendered views, scored."""

    metrics: DetectionMetrics
    panels: Dict[str, PanelBoxes]
    """Per frame: the view with its true and detected boxes (for the picture)."""
    matched: MatchedImages
    """Per frame: the detections matched at each IoU threshold (for the bootstrap intervals)."""


def score_render_folder(
    raw: Path,
    renders: Path,
    weights: Path,
    conf_threshold: float,
    min_box_pixels: int,
    device: str = "auto",
    imgsz: Optional[int] = None,
) -> ScoredViews:
    """Detect on every rendered view (at ``imgsz``, default the detector's training size) and score against the
    scene's true boxes (those under ``min_box_pixels`` visible pixels ignored); P/R/F1 at ``conf_threshold``."""
    truth = SceneTruth(raw, min_box_pixels)
    detections = predict_folder(weights, renders, imgsz=imgsz, device=device)
    images, panels = [], {}
    for path in list_images(renders):
        boxes, scores, (width, height) = detections[path.stem]
        frame = truth.frame(path.stem, path)
        true = yolo_to_xyxy(frame.counted, width, height)
        images.append(ImageBoxes(boxes, scores, true, yolo_to_xyxy(frame.ignored, width, height)))
        panels[path.stem] = PanelBoxes(path, true, boxes, scores)
    metrics = score_detections(images, conf_threshold=conf_threshold)
    return ScoredViews(metrics, panels, MatchedImages.from_images(list(panels), images))
