"""A YOLO box predictor (Ultralytics YOLOv8, AGPL-3.0, optional extra), loaded and run offline.

:func:`configure_offline` sets the environment and Ultralytics settings so that no network call, hub sync or experiment
logger (Comet, W&B, MLflow, ClearML, DVC, Ray Tune, TensorBoard) runs. Ultralytics is imported only inside these
functions. Training lives with the detector (:mod:`agrinerf_ns.detect.detector`).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Callable, Optional, Tuple

import numpy as np
from jaxtyping import Float, UInt8

from agrinerf_ns.machine import yolo_device

INSTALL_HINT = (
    "Ultralytics is not installed. It is an optional extra (AGPL-3.0): run scripts/install_detect.sh "
    "(keeps opencv-contrib-python-headless as the cv2 provider) or pip install 'agrinerf-ns[detect]'."
)
_OFFLINE_ENV = {
    "YOLO_OFFLINE": "1",  # ultralytics.utils.is_online() -> False: no downloads, no hub, no update checks
    "YOLO_VERBOSE": "False",
    "COMET_MODE": "disabled",
    "WANDB_MODE": "disabled",
    "WANDB_DISABLED": "true",
    "MLFLOW_TRACKING_URI": "",
    "CLEARML_OFFLINE_MODE": "1",
}
_INTEGRATIONS = ("sync", "hub", "comet", "wandb", "mlflow", "clearml", "dvc", "raytune", "tensorboard", "neptune")


def configure_offline(config_dir: Path | None = None) -> None:
    """Make Ultralytics run offline with every logger off. Call before training or prediction.

    ``config_dir`` (``YOLO_CONFIG_DIR``) takes effect only if Ultralytics has not been imported yet; by default the
    user's Ultralytics settings file is used and its integration switches are turned off.
    """
    for key, value in _OFFLINE_ENV.items():
        os.environ.setdefault(key, value)
    if config_dir is not None:
        Path(config_dir).mkdir(parents=True, exist_ok=True)
        os.environ.setdefault("YOLO_CONFIG_DIR", str(config_dir))
    try:
        from ultralytics import settings
    except ImportError as err:
        raise ImportError(INSTALL_HINT) from err
    off = {key: False for key in _INTEGRATIONS if key in settings}
    if any(settings.get(key) for key in off):
        settings.update(off)


BoxPredictor = Callable[[UInt8[np.ndarray, "h w 3"]], Tuple[Float[np.ndarray, "n 4"], Float[np.ndarray, " n"]]]
"""An 8-bit BGR image -> its pixel ``x1 y1 x2 y2`` boxes and their scores."""


def load_yolo(weights: Optional[Path], hint: str = "") -> Tuple[Any, int]:
    """The YOLO model of ``weights``, loaded offline, and the image size it was trained at. FileNotFoundError naming
    ``weights`` (and ``hint``, what the caller's user gives them with) where there is no such file."""
    if weights is None or not Path(weights).is_file():
        raise FileNotFoundError(f"{weights}: YOLO weights not found" + (f" ({hint})" if hint else ""))
    configure_offline()
    from ultralytics import YOLO

    model = YOLO(str(weights))
    return model, int(model.overrides.get("imgsz", 640))


def box_predictor(weights: Optional[Path], conf: float, device: str = "auto", hint: str = "") -> BoxPredictor:
    """Load YOLO ``weights`` once (:func:`load_yolo`) and return a function that detects on one image, keeping boxes
    scored ``conf`` or more at the size the detector was trained at."""
    model, imgsz = load_yolo(weights, hint)
    where = yolo_device(device)

    def predict(image: UInt8[np.ndarray, "h w 3"]) -> Tuple[Float[np.ndarray, "n 4"], Float[np.ndarray, " n"]]:
        result = model.predict(image, imgsz=imgsz, conf=conf, device=where, verbose=False)[0]
        boxes = result.boxes.xyxy.cpu().numpy().astype(np.float64).reshape(-1, 4)
        return boxes, result.boxes.conf.cpu().numpy().astype(np.float64).reshape(-1)

    return predict
