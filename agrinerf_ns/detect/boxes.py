"""Box files of a synthetic scene: YOLO label files (``truth/boxes_yolo/<frame>.txt``) and box conversions.

Frames are identified by their file stem (``000000``): the raw capture's ``rgb/000000.png``, the truth files
``truth/rgb_clean/000000.png`` and ``truth/boxes_yolo/000000.txt``, the dataset's ``images/000000.png`` and a rendered
view ``000000.png`` all name the same camera. YOLO boxes are normalised (``cx cy w h`` in [0, 1]), so they apply at
any image resolution of that camera (rendered views may be downscaled).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional

import numpy as np
from jaxtyping import Float

TRUTH_BOXES_DIR = Path("truth") / "boxes_yolo"
TRUTH_RGB_DIR = Path("truth") / "rgb_clean"
TRUTH_COCO = Path("truth") / "boxes_coco.json"
MIN_BOX_PIXELS = 30
"""Default visible-pixel count below which a true fruit is an ignore region (about a third of a whole fruit at
320x240)."""
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".tif", ".tiff", ".bmp")


class MissingTruthError(FileNotFoundError):
    """A scene, frame or file lacks the true boxes needed for detection."""


def read_yolo_labels(path: Path) -> Float[np.ndarray, "m 4"]:
    """Read a YOLO label file: one ``class cx cy w h`` line per box (normalised). Returns ``cx cy w h`` rows.

    An empty file is a frame without fruit. Raises ``ValueError`` naming the file and line for malformed content.
    """
    rows: List[List[float]] = []
    for number, line in enumerate(Path(path).read_text().splitlines(), start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 5:
            raise ValueError(f"{path}:{number}: expected 'class cx cy w h', got {line!r}")
        try:
            values = [float(v) for v in fields[1:]]
        except ValueError as err:
            raise ValueError(f"{path}:{number}: non-numeric box {line!r}") from err
        if not all(np.isfinite(values)) or values[2] < 0 or values[3] < 0:
            raise ValueError(f"{path}:{number}: invalid box {line!r} (need finite cx cy and w, h >= 0)")
        rows.append(values)
    return np.asarray(rows, dtype=np.float64).reshape(-1, 4)


def write_yolo_labels(path: Path, boxes: Float[np.ndarray, "m 4"], class_id: int = 0) -> None:
    """Write normalised ``cx cy w h`` rows as a YOLO label file (one class)."""
    lines = [f"{class_id} {cx:.6f} {cy:.6f} {w:.6f} {h:.6f}" for cx, cy, w, h in np.asarray(boxes).reshape(-1, 4)]
    Path(path).write_text("".join(line + "\n" for line in lines))


def yolo_to_xyxy(boxes: Float[np.ndarray, "m 4"], width: int, height: int) -> Float[np.ndarray, "m 4"]:
    """Normalised ``cx cy w h`` -> pixel ``x1 y1 x2 y2`` for an image of ``width`` x ``height``."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    cx, cy, w, h = boxes[:, 0] * width, boxes[:, 1] * height, boxes[:, 2] * width, boxes[:, 3] * height
    return np.stack([cx - w / 2, cy - h / 2, cx + w / 2, cy + h / 2], axis=1)


def xyxy_to_yolo(boxes: Float[np.ndarray, "m 4"], width: int, height: int) -> Float[np.ndarray, "m 4"]:
    """Pixel ``x1 y1 x2 y2`` -> normalised ``cx cy w h``."""
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    w, h = boxes[:, 2] - boxes[:, 0], boxes[:, 3] - boxes[:, 1]
    return np.stack([(boxes[:, 0] + w / 2) / width, (boxes[:, 1] + h / 2) / height, w / width, h / height], axis=1)


def truth_label_files(scene: Path) -> Dict[str, Path]:
    """Frame stem -> YOLO label file of a scene's true boxes. Raises :class:`MissingTruthError` if there are none."""
    scene = Path(scene)
    folder = scene / TRUTH_BOXES_DIR
    if not folder.is_dir():
        raise MissingTruthError(
            f"{scene}: no true fruit boxes: folder {folder} does not exist. Detection needs a synthetic scene written by "
            "agrinerf-synth (truth/boxes_yolo/<frame>.txt, see docs/formats.md), or labels in that layout."
        )
    files = {p.stem: p for p in sorted(folder.glob("*.txt"))}
    if not files:
        raise MissingTruthError(f"{scene}: no true fruit boxes: {folder} holds no <frame>.txt label files")
    return files


def truth_labels_for(scene: Path, stem: str, label_files: Dict[str, Path], what: Path) -> Float[np.ndarray, "m 4"]:
    """The normalised true boxes of frame ``stem``; ``what`` (the image needing them) is named in the error."""
    if stem not in label_files:
        raise MissingTruthError(
            f"{what}: no true boxes for frame '{stem}' in {Path(scene) / TRUTH_BOXES_DIR} "
            f"(frames there: {_sample(label_files)}). Image files must keep the frame's stem."
        )
    return read_yolo_labels(label_files[stem])


class FrameTruth(NamedTuple):
    """A frame's true boxes (normalised ``cx cy w h``), split by visible size."""

    counted: Float[np.ndarray, "m 4"]
    ignored: Float[np.ndarray, "k 4"]


class SceneTruth:
    """A scene's true boxes per frame, with the visible pixel count of each box when ``min_pixels`` > 0."""

    def __init__(self, scene: Path, min_pixels: int = 0) -> None:
        if min_pixels < 0:
            raise ValueError(f"min_pixels must be >= 0, got {min_pixels}")
        self.scene = Path(scene)
        self.min_pixels = min_pixels
        self.label_files = truth_label_files(self.scene)
        self.visible: Optional[Dict[str, np.ndarray]] = visible_pixels(self.scene) if min_pixels > 0 else None

    def frame(self, stem: str, what: Path) -> FrameTruth:
        """Boxes of frame ``stem``; ``what`` (the image needing them) is named in errors."""
        boxes = truth_labels_for(self.scene, stem, self.label_files, what)
        if self.visible is None:
            return FrameTruth(boxes, boxes[:0])
        pixels = self.visible.get(stem, np.zeros(0))
        if len(pixels) != len(boxes):
            raise MissingTruthError(
                f"{what}: frame '{stem}' has {len(boxes)} boxes in {self.label_files[stem]} but {len(pixels)} in "
                f"{self.scene / TRUTH_COCO}: the two truth files disagree"
            )
        small = pixels < self.min_pixels
        return FrameTruth(boxes[~small], boxes[small])


def visible_pixels(scene: Path) -> Dict[str, np.ndarray]:
    """Frame stem -> visible pixel count of each true box, in the order of the frame's YOLO label file.

    Read from ``truth/boxes_coco.json`` (``area`` of each annotation, written by ``agrinerf-synth`` in label-file
    order). Raises :class:`MissingTruthError` when the file is missing or lacks areas.
    """
    path = Path(scene) / TRUTH_COCO
    if not path.is_file():
        raise MissingTruthError(
            f"{scene}: no visible pixel counts of the true boxes ({path} does not exist); give min_box_pixels 0 to "
            "count every box"
        )
    try:
        coco = json.loads(path.read_text())
        stems = {image["id"]: Path(image["file_name"]).stem for image in coco["images"]}
        counts: Dict[str, List[float]] = {stem: [] for stem in stems.values()}
        for ann in sorted(coco["annotations"], key=lambda a: a["id"]):
            counts[stems[ann["image_id"]]].append(float(ann["area"]))
    except (json.JSONDecodeError, KeyError, TypeError) as err:
        raise MissingTruthError(f"{path}: not a COCO box file with images and annotation areas ({err!r})") from err
    return {stem: np.asarray(values, dtype=np.float64) for stem, values in counts.items()}


def list_images(folder: Path) -> List[Path]:
    """Image files directly in ``folder``, sorted by name."""
    return sorted(p for p in Path(folder).iterdir() if p.suffix.lower() in IMAGE_SUFFIXES and p.is_file())


def _sample(files: Dict[str, Path], n: int = 3) -> str:
    names = list(files)
    return ", ".join(names[:n]) + (", ..." if len(names) > n else "")
