"""Write YOLO dataset folders (images/, labels/, data.yaml) from a scene's truth images, thermal frames or renders."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, List, Literal, Optional, Sequence

import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.dataset_format import IMAGE, THERMAL, THERMAL_MASK, TRANSFORMS
from agrinerf_ns.detect.boxes import TRUTH_RGB_DIR, MissingTruthError, SceneTruth, list_images, write_yolo_labels

CLASS_NAMES = ("fruit",)


@dataclass(frozen=True)
class LabelledImage:
    """One training image of the detector with its true boxes."""

    image: Path
    boxes: Float[np.ndarray, "m 4"]
    """Normalised ``cx cy w h`` (boxes with fewer visible pixels than the truth's ``min_pixels`` left out)."""
    name: str
    """Unique file stem in the written dataset (``<source>_<frame>``)."""


def rgb_truth_images(truth: SceneTruth, exclude: Iterable[str] = ()) -> List[LabelledImage]:
    """Clean RGB truth views (``truth/rgb_clean``) with their boxes; frames in ``exclude`` (stems) are left out."""
    folder = truth.scene / TRUTH_RGB_DIR
    if not folder.is_dir() or not list_images(folder):
        raise MissingTruthError(f"{truth.scene}: no clean RGB truth images in {folder}")
    skip = set(exclude)
    return [
        LabelledImage(p, truth.frame(p.stem, p).counted, f"rgb_{p.stem}")
        for p in list_images(folder)
        if p.stem not in skip
    ]


def dataset_images(
    truth: SceneTruth, dataset: Path, modality: Literal["rgb", "thermal"], exclude: Iterable[str] = ()
) -> List[LabelledImage]:
    """Frames of a processed dataset: its RGB images (``file_path``) or its thermal frames (``thermal_file_path``,
    warped into the RGB camera, so the RGB truth boxes apply).

    Frames are read from ``dataset/transforms.json``; each is paired with the truth boxes of its RGB frame by the stem
    of ``file_path``. A thermal frame keeps only the boxes whose centre its ``thermal_mask_path`` marks as seen by the
    thermal camera (the rest of a warped frame is black fill, where no detector can find fruit).
    """
    transforms = Path(dataset) / TRANSFORMS
    if not transforms.is_file():
        raise FileNotFoundError(f"{dataset}: not a processed dataset: {transforms} does not exist")
    key = IMAGE.key if modality == "rgb" else THERMAL.key
    frames = [f for f in json.loads(transforms.read_text()).get("frames", []) if key in f]
    if not frames:
        raise ValueError(f"{transforms}: no frame has a {key}, so a {modality} detector cannot be trained from it")
    skip = set(exclude)
    items = []
    for frame in frames:
        stem = Path(frame[IMAGE.key]).stem
        if stem in skip:
            continue
        image = Path(dataset) / frame[key]
        if not image.is_file():
            raise FileNotFoundError(f"{transforms}: {modality} image {image} of frame {frame['file_path']} is missing")
        boxes = truth.frame(stem, image).counted
        if modality == "thermal" and THERMAL_MASK.key in frame:
            boxes = boxes[centres_in_mask(boxes, Path(dataset) / frame[THERMAL_MASK.key])]
        items.append(LabelledImage(image, boxes, f"{modality}_{stem}"))
    return items


def centres_in_mask(boxes: Float[np.ndarray, "m 4"], mask_path: Path) -> Bool[np.ndarray, " m"]:
    """Whether each normalised box's centre pixel is non-zero in the mask image (any resolution)."""
    import cv2

    mask = cv2.imread(str(mask_path), cv2.IMREAD_GRAYSCALE)
    if mask is None:
        raise FileNotFoundError(f"{mask_path}: thermal mask missing or unreadable")
    height, width = mask.shape
    cols = np.clip((boxes[:, 0] * width).astype(int), 0, width - 1)
    rows = np.clip((boxes[:, 1] * height).astype(int), 0, height - 1)
    return mask[rows, cols] > 0


def rendered_images(truth: SceneTruth, render_dir: Path, prefix: str = "render") -> List[LabelledImage]:
    """Rendered views (``<frame>.png``) with the truth boxes of their frames."""
    images = list_images(render_dir)
    if not images:
        raise FileNotFoundError(f"{render_dir}: empty render folder (no .png/.jpg images)")
    return [LabelledImage(p, truth.frame(p.stem, p).counted, f"{prefix}_{p.stem}") for p in images]


def subsample(items: Sequence[LabelledImage], fraction: float, seed: int) -> List[LabelledImage]:
    """A deterministic random subset of about ``fraction`` of ``items`` (at least one when fraction > 0)."""
    if fraction <= 0 or not items:
        return []
    count = max(1, int(round(fraction * len(items))))
    order = np.random.default_rng(seed).permutation(len(items))[:count]
    return [items[i] for i in sorted(order)]


def write_yolo_dataset(
    out: Path, train: Sequence[LabelledImage], val: Optional[Sequence[LabelledImage]] = None, val_every: int = 5
) -> Path:
    """Write ``out/images/{train,val}``, ``out/labels/{train,val}`` and ``out/data.yaml``; returns data.yaml.

    Without ``val``, every ``val_every``-th training image is also used for validation (they stay in train: the
    detector is scored on rendered views, not on this split).
    """
    if not train:
        raise ValueError(f"{out}: no training images for the detector")
    names = [item.name for item in train]
    if len(set(names)) != len(names):
        raise ValueError(f"{out}: duplicate image names in the detector training set")
    out = Path(out)
    if out.exists():
        shutil.rmtree(out)
    val = list(val) if val else list(train[::val_every])
    for split, items in (("train", train), ("val", val)):
        (out / "images" / split).mkdir(parents=True)
        (out / "labels" / split).mkdir(parents=True)
        for item in items:
            shutil.copyfile(item.image, out / "images" / split / f"{item.name}{item.image.suffix.lower()}")
            write_yolo_labels(out / "labels" / split / f"{item.name}.txt", item.boxes)
    data_yaml = out / "data.yaml"
    names_yaml = "".join(f"  {i}: {n}\n" for i, n in enumerate(CLASS_NAMES))
    data_yaml.write_text(f"path: {out.resolve()}\ntrain: images/train\nval: images/val\nnames:\n{names_yaml}")
    return data_yaml
