"""A scene's detectors: trained without the held-out frames, reused when their record matches, or taken from an
earlier evaluation.

Each detector's folder ``detector_<modality>/`` holds Ultralytics' run (``weights/best.pt``) and the record it was
trained from, ``agrinerf_detect.json``: the detector settings, ``min_box_pixels``, the training images and the start
weights (path and SHA-256). Weights are reused only when the record of a new request is equal.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import Dict, List, Optional, Set

from agrinerf_ns.detect.boxes import SceneTruth
from agrinerf_ns.detect.detector import train_detector, trained_weights
from agrinerf_ns.detect.eval_plan import DetectorInput, SceneSpec
from agrinerf_ns.detect.settings import EvalSettings
from agrinerf_ns.detect.yolo_data import (
    LabelledImage,
    dataset_images,
    rendered_images,
    rgb_truth_images,
    subsample,
    write_yolo_dataset,
)

RECORD = "agrinerf_detect.json"


def detector_folder(work: Path, modality: DetectorInput) -> Path:
    """Where a scene's work folder keeps its ``modality`` detector."""
    return Path(work) / f"detector_{modality}"


def training_images(
    scene: SceneSpec, modality: DetectorInput, exclude: List[str], cross_spectral: List[Path], settings: EvalSettings
) -> List[LabelledImage]:
    """The labelled images a detector trains on, none of them a frame in ``exclude`` (the held-out views).

    RGB: the clean truth views (or the dataset's captured frames). Thermal: the dataset's thermal frames plus
    cross-spectral renders of training views, ``cross_spectral_fraction`` of their number.
    """
    truth = SceneTruth(scene.raw, settings.min_box_pixels)
    if modality == "rgb" and settings.rgb_source == "clean":
        return rgb_truth_images(truth, exclude)
    if modality == "rgb":
        if scene.dataset is None:
            raise ValueError(f"scene {scene.name}: rgb_source 'captured' needs the scene's processed dataset")
        return dataset_images(truth, scene.dataset, "rgb", exclude)
    assert scene.dataset is not None
    items = dataset_images(truth, scene.dataset, "thermal", exclude)
    extra: List[LabelledImage] = []
    for folder in cross_spectral:
        renders = rendered_images(truth, folder, f"xspec_{folder.name}")
        extra += [item for item in renders if item.image.stem not in set(exclude)]
    count = settings.cross_spectral_fraction * len(items) / max(1, len(extra))
    return items + subsample(extra, min(1.0, count), settings.detector.seed)


def train_scene_detector(
    scene: SceneSpec,
    modality: DetectorInput,
    exclude: List[str],
    cross_spectral: List[Path],
    work: Path,
    settings: EvalSettings,
    init: Optional[Path] = None,
) -> Path:
    """Train (or reuse) the scene's RGB or thermal detector without the held-out frames; returns its weights.

    ``init``: weights to start from (else from scratch). Weights in the work folder are reused only when they were
    trained with the same settings on the same images from the same start (the record in the detector's folder).
    """
    run_dir = detector_folder(work, modality)
    items = training_images(scene, modality, exclude, cross_spectral, settings)
    record = {
        "detector": asdict(settings.detector),
        "min_box_pixels": settings.min_box_pixels,
        "images": [str(item.image) for item in items],
        "init": None if init is None else {"path": str(init), "sha256": _sha256(init)},
    }
    record_path = run_dir / RECORD
    if settings.reuse and record_path.is_file() and json.loads(record_path.read_text()) == record:
        reused = trained_weights(run_dir)
        if reused is not None:
            return reused
    data_yaml = write_yolo_dataset(Path(work) / f"yolo_{modality}", items)
    weights = train_detector(data_yaml, run_dir, settings.detector, init)
    record_path.write_text(json.dumps(record, indent=1))
    return weights


def train_scene_detectors(
    scene: SceneSpec,
    modalities: Set[DetectorInput],
    exclude: List[str],
    cross_spectral: List[Path],
    work: Path,
    settings: EvalSettings,
) -> Dict[DetectorInput, Path]:
    """The detectors a scene's methods need; with ``thermal_init`` "rgb" the RGB one is trained first (even when no
    method uses it) and the thermal one starts from its weights."""
    weights: Dict[DetectorInput, Path] = {}
    if "rgb" in modalities or ("thermal" in modalities and settings.thermal_init == "rgb"):
        weights["rgb"] = train_scene_detector(scene, "rgb", exclude, cross_spectral, work, settings)
    if "thermal" in modalities:
        init, thermal_settings = None, settings
        if settings.thermal_init == "rgb":
            init = weights["rgb"]
            thermal_settings = replace(settings, detector=replace(settings.detector, lr0=settings.thermal_init_lr0))
        weights["thermal"] = train_scene_detector(
            scene, "thermal", exclude, cross_spectral, work, thermal_settings, init
        )
    return weights


def trained_scene_detectors(
    folder: Path, modalities: Set[DetectorInput], held_out: List[str], min_box_pixels: int
) -> Dict[DetectorInput, Path]:
    """The detectors an earlier evaluation trained for a scene (``folder`` = its ``work/<scene>_<lighting>``), checked
    against their records: none may have trained on a held-out view, and their labels must have left out the same
    small fruit the scoring ignores."""
    weights: Dict[DetectorInput, Path] = {}
    for modality in sorted(modalities):
        run_dir = detector_folder(folder, modality)
        record_path = run_dir / RECORD
        found = trained_weights(run_dir)
        if not record_path.is_file() or found is None:
            raise FileNotFoundError(f"{run_dir}: no trained {modality} detector there (weights/best.pt and "
                                    f"{RECORD}, as agrinerf-detect evaluate writes them)")  # fmt: skip
        record = json.loads(record_path.read_text())
        leaked = sorted({Path(image).stem for image in record["images"]} & set(held_out))
        if leaked:
            raise ValueError(f"{record_path}: the {modality} detector trained on held-out views {leaked}; it cannot "
                             "score them")  # fmt: skip
        if record.get("min_box_pixels") != min_box_pixels:
            raise ValueError(f"{record_path}: trained with min_box_pixels {record.get('min_box_pixels')}, this "
                             f"evaluation ignores fruit under {min_box_pixels}")  # fmt: skip
        weights[modality] = found
    return weights


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()
