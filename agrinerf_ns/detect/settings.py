"""The settings of a detection evaluation, declared once: ``agrinerf-detect evaluate`` nests them as its options."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal, Optional

import tyro
from typing_extensions import Annotated

from agrinerf_ns.detect.boxes import MIN_BOX_PIXELS
from agrinerf_ns.detect.detector import DetectorConfig

MinBoxPixels = Annotated[
    int,
    tyro.conf.arg(
        help="A fruit counts when at least this many of its pixels are visible in the truth view (`area` in "
        "truth/boxes_coco.json; about a third of a whole fruit in the 320x240 detect profile). Smaller ones, mostly "
        "fruit behind leaves, are ignored in scoring (COCO ignore regions) and left out of the detectors' training "
        "labels. 0 counts every box (and needs no boxes_coco.json)."
    ),
]
RaysPerChunk = Annotated[
    Optional[int],
    tyro.conf.arg(
        help="Rays rendered at once (eval_num_rays_per_chunk). Default: 1024 on a CPU (faster and far less memory "
        "than the configs' GPU-sized chunks there; docs/detect.md), the run config's on a GPU. The image does not "
        "depend on it."
    ),
]


@dataclass
class EvalSettings:
    """How every scene of an evaluation is rendered, its detectors trained, and its views scored."""

    detector: Annotated[DetectorConfig, tyro.conf.arg(name="detector")] = field(default_factory=DetectorConfig)
    """Training settings of the YOLOv8 detectors."""
    conf_threshold: float = 0.25
    """Score threshold for precision, recall, F1 and the picture (mAPs use every detection down to 0.001)."""
    cross_spectral_fraction: float = 0.25
    """Cross-spectral renders of training views added to the thermal detector's set, as a fraction of its thermal
    frames."""
    max_render_views: Optional[int] = None
    """Render at most this many held-out views per method, evenly spaced (None: all)."""
    rays_per_chunk: RaysPerChunk = None
    reuse: bool = True
    """Reuse renders and detector weights already in the work folder (OUT/work)."""
    rgb_source: Literal["clean", "captured"] = "clean"
    """RGB detector training images: truth/rgb_clean (noise-free, well exposed) or the dataset's captured frames (the
    paper labels "the original dataset images")."""
    thermal_init: Literal["rgb", "scratch"] = "rgb"
    """Start the thermal detector from the scene's RGB detector (trained here, from scratch, on the clean RGB truth
    without the held-out frames) or from random weights (docs/detect.md: from scratch it learnt nothing from the dark
    garden's 21 thermal frames in 120 CPU epochs)."""
    thermal_init_lr0: float = 0.002
    """AdamW learning rate of the thermal detector when it starts from the RGB detector (a fine-tune; the RGB one,
    from scratch, uses --detector.lr0)."""
    min_box_pixels: MinBoxPixels = MIN_BOX_PIXELS
    detectors_from: Optional[Path] = None
    """An earlier evaluation's output folder whose detectors (work/<scene>_<lighting>/detector_<modality>) score this
    one's renders instead of detectors trained here: e.g. Table IV's ablations scored with the detectors of the same
    scene's Table III. Refused when they trained on a held-out view or with another min_box_pixels."""
