"""YOLOv8 fruit detector (Ultralytics, AGPL-3.0, optional extra), trained from scratch and run offline.

The model is built from ``yolov8n.yaml`` (no pretrained weights, nothing downloaded); loading and running it offline is
:mod:`agrinerf_ns.fruit.yolo`'s (:func:`~agrinerf_ns.fruit.yolo.configure_offline`). Ultralytics is imported only
inside these functions.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.detect.boxes import list_images
from agrinerf_ns.fruit.yolo import configure_offline, load_yolo
from agrinerf_ns.machine import yolo_device


@dataclass(frozen=True)
class DetectorConfig:
    """Training settings of the YOLOv8 detector (the paper trains 250 epochs; CPU budgets use far fewer)."""

    model: str = "yolov8n.yaml"
    """Ultralytics model YAML (architecture only: built from scratch)."""
    epochs: int = 50
    imgsz: int = 128
    """Training and inference image size (pixels, multiple of 32)."""
    batch: int = 16
    seed: int = 0
    device: str = "auto"
    """Ultralytics device: "auto" (the first CUDA device where there is one, else "cpu"), "cpu", "0", ..."""
    patience: int = 0
    """Early-stopping patience in epochs (0: off)."""
    warmup_epochs: float = 0.0
    """Ultralytics' learning-rate warm-up; when on it lasts at least 100 iterations, which for a few dozen images is
    the whole run (nothing is learnt), hence off by default."""
    lr0: float = 0.002
    """Initial learning rate (AdamW)."""


def train_detector(
    data_yaml: Path, out_dir: Path, config: DetectorConfig = DetectorConfig(), init: Optional[Path] = None
) -> Path:
    """Train YOLOv8 on a YOLO dataset (``data.yaml``); returns the trained weights file.

    From scratch (``config.model``, random weights) unless ``init`` names weights trained here before (e.g. the
    scene's RGB detector, to start the thermal one from): nothing is ever downloaded.
    """
    configure_offline()
    from ultralytics import YOLO

    out_dir = Path(out_dir).resolve()
    if init is not None and not Path(init).is_file():
        raise FileNotFoundError(f"{init}: detector weights to start from do not exist")
    model = YOLO(str(init) if init is not None else config.model)
    model.train(
        data=str(Path(data_yaml).resolve()),
        epochs=config.epochs,
        imgsz=config.imgsz,
        batch=config.batch,
        seed=config.seed,
        deterministic=True,
        device=yolo_device(config.device),
        workers=0,
        pretrained=init is not None,  # False would drop the init weights (ultralytics Model.train)
        amp=False,
        plots=False,
        patience=config.patience if config.patience > 0 else config.epochs + 1,
        warmup_epochs=config.warmup_epochs,
        optimizer="AdamW",
        lr0=config.lr0,
        project=str(out_dir.parent),
        name=out_dir.name,
        exist_ok=True,
        verbose=False,
    )
    weights = trained_weights(out_dir)
    if weights is not None:
        return weights
    raise RuntimeError(f"{out_dir}: Ultralytics training finished without writing weights/best.pt or last.pt")


def trained_weights(run_dir: Path) -> Optional[Path]:
    """A detector run's ``weights/best.pt``, else ``weights/last.pt``, else None."""
    for name in ("best.pt", "last.pt"):
        weights = Path(run_dir) / "weights" / name
        if weights.is_file():
            return weights
    return None


def predict_folder(
    weights: Path,
    image_dir: Path,
    imgsz: Optional[int] = None,
    conf: float = 0.001,
    device: str = "auto",
    max_det: int = 100,
) -> Dict[str, Tuple[Float[np.ndarray, "n 4"], Float[np.ndarray, " n"], Tuple[int, int]]]:
    """Run the detector on every image in ``image_dir``: stem -> (pixel xyxy boxes, scores, (width, height)).

    ``imgsz`` defaults to the size the detector was trained at. ``conf`` is the lowest score kept (low, as for mAP);
    precision/recall thresholds are applied when scoring.
    """
    images = list_images(image_dir)
    if not images:
        raise FileNotFoundError(f"{image_dir}: empty render folder (no .png/.jpg images to detect on)")
    model, trained_size = load_yolo(weights)
    imgsz = imgsz or trained_size
    detections = {}
    for chunk in _chunks(images, 16):
        for path, result in zip(
            chunk,
            model.predict(
                [str(p) for p in chunk],
                imgsz=imgsz,
                conf=conf,
                device=yolo_device(device),
                max_det=max_det,
                verbose=False,
            ),
            strict=True,
        ):
            boxes = result.boxes
            height, width = result.orig_shape
            detections[path.stem] = (
                boxes.xyxy.cpu().numpy().astype(np.float64).reshape(-1, 4),
                boxes.conf.cpu().numpy().astype(np.float64).reshape(-1),
                (int(width), int(height)),
            )
    return detections


def _chunks(items: Sequence[Path], size: int) -> List[Sequence[Path]]:
    return [items[i : i + size] for i in range(0, len(items), size)]
