"""Write YOLO dataset folders (images/, labels/, data.yaml) from a scene's truth images, thermal frames or renders."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, List, Literal, Optional, Sequence

import numpy as np
from jaxtyping import Float

from agrinerf_ns.detect.boxes import (
    TRUTH_RGB_DIR,
    MissingTruthError,
    list_images,
    truth_label_files,
    truth_labels_for,
    write_yolo_labels,
)

CLASS_NAMES = ("fruit",)


@dataclass(frozen=True)
class LabelledImage:
    """One training image of the detector with its true boxes."""

    image: Path
    boxes: Float[np.ndarray, "m 4"]
    """Normalised ``cx cy w h``."""
    name: str
    """Unique file stem in the written dataset (``<source>_<frame>``)."""


def rgb_truth_images(scene: Path, exclude: Iterable[str] = ()) -> List[LabelledImage]:
    """Clean RGB truth views (``truth/rgb_clean``) with their boxes; frames in ``exclude`` (stems) are left out."""
    labels = truth_label_files(scene)
    folder = Path(scene) / TRUTH_RGB_DIR
    if not folder.is_dir() or not list_images(folder):
        raise MissingTruthError(f"{scene}: no clean RGB truth images in {folder}")
    skip = set(exclude)
    return [
        LabelledImage(p, truth_labels_for(scene, p.stem, labels, p), f"rgb_{p.stem}")
        for p in list_images(folder)
        if p.stem not in skip
    ]


def dataset_images(
    scene: Path, dataset: Path, modality: Literal["rgb", "thermal"], exclude: Iterable[str] = ()
) -> List[LabelledImage]:
    """Frames of a processed dataset: its RGB images (``file_path``) or its thermal frames (``thermal_file_path``,
    warped into the RGB camera, so the RGB truth boxes apply).

    Frames are read from ``dataset/transforms.json``; each is paired with the truth boxes of its RGB frame by the stem
    of ``file_path``.
    """
    transforms = Path(dataset) / "transforms.json"
    if not transforms.is_file():
        raise FileNotFoundError(f"{dataset}: not a processed dataset: {transforms} does not exist")
    key = "file_path" if modality == "rgb" else "thermal_file_path"
    frames = [f for f in json.loads(transforms.read_text()).get("frames", []) if key in f]
    if not frames:
        raise ValueError(f"{transforms}: no frame has a {key}, so a {modality} detector cannot be trained from it")
    labels = truth_label_files(scene)
    skip = set(exclude)
    items = []
    for frame in frames:
        stem = Path(frame["file_path"]).stem
        if stem in skip:
            continue
        image = Path(dataset) / frame[key]
        if not image.is_file():
            raise FileNotFoundError(f"{transforms}: {modality} image {image} of frame {frame['file_path']} is missing")
        items.append(LabelledImage(image, truth_labels_for(scene, stem, labels, image), f"{modality}_{stem}"))
    return items


def rendered_images(scene: Path, render_dir: Path, prefix: str = "render") -> List[LabelledImage]:
    """Rendered views (``<frame>.png``) with the truth boxes of their frames."""
    images = list_images(render_dir)
    if not images:
        raise FileNotFoundError(f"{render_dir}: empty render folder (no .png/.jpg images)")
    labels = truth_label_files(scene)
    return [LabelledImage(p, truth_labels_for(scene, p.stem, labels, p), f"{prefix}_{p.stem}") for p in images]


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
