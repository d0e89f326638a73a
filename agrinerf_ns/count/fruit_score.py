"""Scoring a fruit map against a synthetic capture's truth (``truth/fruits.json``, ``truth/fruit_ids/``).

A true fruit is *visible from the capture* when at least ``min_pixels`` of it show in at least one training view's
fruit mask (``truth/fruit_ids/<frame>.png``). Counted fruit are matched one-to-one to the true fruit (Hungarian, on
the 3D distance) within ``match_distance``: a match to a visible fruit is a true positive, a counted fruit with no
match a false positive (a match to a fruit no training view shows is neither), a visible fruit with no match a false
negative. The count error is (counted - visible) / visible.

"Visible" takes in fruit that show a sliver of a few pixels behind the leaves once. Two stricter tiers of truth
stand beside it (:data:`TIERS`), each by the share of a fruit's disc a training view shows (its pixels over the disc
its true radius covers at the depth they show, through the RGB camera's focal length): a fruit is *countable* when at
least ``min_share`` (a quarter) of its disc shows in at least one training view, the fruit an annotator would mark,
and *well seen* when it does so in at least two, the views a 3D count needs. The ``*_countable`` and ``*_well_seen``
scores are recall, F1 and count error over those fruit; a match to any visible fruit still counts as correct for
precision, so precision is one figure for every tier. :func:`tier_scores` gives every tier at several match
distances (the anchors match more loosely than 0.05 m).

The fruit map is in the dataset's frame, the truth in the capture's: with ``align="poses"`` the dataset's cameras are
fit to the capture's true ones (``truth/poses.txt``, matched by timestamp) by a similarity (rotation from their
orientations, scale and shift from their centres), which removes the pose source's frame (SfM) and the odometry's mean
drift, not its local error.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Literal, Optional, Tuple, Union

import cv2
import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.count.render import CountInputError
from agrinerf_ns.dataset_format import TRANSFORMS

FRUITS_JSON = Path("truth") / "fruits.json"
FRUIT_IDS_DIR = Path("truth") / "fruit_ids"
TRUE_DEPTH_DIR = Path("truth") / "depth"
TRUE_POSES = Path("truth") / "poses.txt"
Align = Literal["poses", "none"]
TIERS = ("visible", "countable", "well_seen")
"""The tiers of truth a count is scored against, loosest first (see the module)."""
TIER_DISTANCES = (0.05, 0.10, 0.15)
"""Match distances (capture units, metres) every tier is reported at."""


@dataclass(frozen=True)
class TruthFruit:
    """A capture's true fruit: centres (capture frame), diameters (mean of the ellipsoid's axes), ids and
    temperatures (degrees C; NaN where the list has none)."""

    centres: Float[np.ndarray, "n 3"]
    diameters: Float[np.ndarray, " n"]
    ids: np.ndarray
    temperatures: Optional[Float[np.ndarray, " n"]] = None


@dataclass(frozen=True)
class Similarity:
    """``p_capture = scale * R p_dataset + t``."""

    scale: float
    rotation: Float[np.ndarray, "3 3"]
    translation: Float[np.ndarray, "3"]
    residual_rms: float = 0.0
    """RMS distance of the fitted camera centres (capture units)."""

    def apply(self, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 3"]:
        return self.scale * np.asarray(points, np.float64).reshape(-1, 3) @ self.rotation.T + self.translation

    def inverse(self, points: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, "n 3"]:
        return (np.asarray(points, np.float64).reshape(-1, 3) - self.translation) @ self.rotation / self.scale

    @classmethod
    def identity(cls) -> "Similarity":
        return cls(1.0, np.eye(3), np.zeros(3))


@dataclass(frozen=True)
class CountScore:
    """A fruit map's count and detection scores against the visible true fruit."""

    counted: int
    visible: int
    truth_total: int
    count_error: float
    """(counted - visible) / visible."""
    true_positives: int
    false_positives: int
    false_negatives: int
    precision: float
    recall: float
    f1: float
    match_distance: float
    mean_match_error: float
    """Mean distance of the true positives to their fruit (NaN without any)."""
    mean_temperature_error: float = float("nan")
    """Mean absolute difference of the true positives' temperatures from their true fruit's (degrees C; NaN without
    counted or true temperatures)."""
    countable: int = -1
    """The countable true fruit (-1: not computed, the capture has no true depth)."""
    recall_countable: float = float("nan")
    f1_countable: float = float("nan")
    """F1 of ``precision`` and ``recall_countable``."""
    count_error_countable: float = float("nan")
    """(counted - countable) / countable."""
    well_seen: int = -1
    """The well-seen true fruit (-1: not computed, the capture has no true depth)."""
    recall_well_seen: float = float("nan")
    f1_well_seen: float = float("nan")
    """F1 of ``precision`` and ``recall_well_seen``."""
    count_error_well_seen: float = float("nan")
    """(counted - well_seen) / well_seen."""

    def as_dict(self) -> Dict[str, Union[int, float]]:
        return asdict(self)


def read_truth_fruit(raw: Path) -> TruthFruit:
    """The true fruit of a synthetic capture; raises :class:`CountInputError` naming the file when there are none."""
    path = Path(raw) / FRUITS_JSON
    if not path.is_file():
        raise CountInputError(
            f"{path}: missing; scoring needs a synthetic capture written by agrinerf-synth (truth/fruits.json)"
        )
    try:
        fruits = json.loads(path.read_text())
        centres = np.asarray([f["center"] for f in fruits], np.float64).reshape(-1, 3)
        diameters = np.asarray([2.0 * np.mean(f["radii"]) for f in fruits], np.float64)
        ids = np.asarray([int(f["id"]) for f in fruits], np.int64)
        temperatures = np.asarray([float(f.get("temperature_c", np.nan)) for f in fruits], np.float64)
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CountInputError(f"{path}: not a fruit list (id, center, radii per fruit) ({err!r})") from err
    if len(ids) == 0:
        raise CountInputError(f"{path}: the scene has no true fruit to score against")
    return TruthFruit(centres, diameters, ids, temperatures)


def visible_fruit(raw: Path, frames: Iterable[str], truth: TruthFruit, min_pixels: int = 3) -> Bool[np.ndarray, " n"]:
    """Which true fruit show with at least ``min_pixels`` pixels in at least one of the ``frames`` (file stems of
    the raw capture's RGB frames), from ``truth/fruit_ids/<frame>.png`` (k + 1 = fruit k)."""
    folder = Path(raw) / FRUIT_IDS_DIR
    seen = np.zeros(len(truth.ids), dtype=bool)
    index = {int(fid): i for i, fid in enumerate(truth.ids)}
    frames = list(frames)
    if not frames:
        raise CountInputError(f"{folder}: no training frames to decide which fruit are visible")
    for stem in frames:
        path = folder / f"{stem}.png"
        ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        if ids is None:
            raise CountInputError(f"{path}: missing or unreadable fruit mask (truth of frame {stem})")
        values, counts = np.unique(ids[ids > 0].astype(np.int64) - 1, return_counts=True)
        for value, count in zip(values, counts, strict=True):
            if count >= min_pixels and int(value) in index:
                seen[index[int(value)]] = True
    return seen


def match_fruit(
    predicted: Float[np.ndarray, "m 3"], truth: Float[np.ndarray, "n 3"], distance: float
) -> Tuple[np.ndarray, np.ndarray]:
    """One-to-one matches (Hungarian on the distances) no farther apart than ``distance``: (predicted indices,
    truth indices)."""
    from scipy.optimize import linear_sum_assignment

    predicted = np.asarray(predicted, np.float64).reshape(-1, 3)
    truth = np.asarray(truth, np.float64).reshape(-1, 3)
    if len(predicted) == 0 or len(truth) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    dist = np.linalg.norm(predicted[:, None, :] - truth[None, :, :], axis=-1)
    cost = np.where(dist <= distance, dist, 1e6)
    rows, cols = linear_sum_assignment(cost)
    keep = dist[rows, cols] <= distance
    return rows[keep].astype(np.int64), cols[keep].astype(np.int64)


def disc_shares(raw: Path, stem: str, truth: TruthFruit, focal: float) -> Dict[int, float]:
    """Per true fruit (index into ``truth``) shown in the raw RGB frame ``stem``: its pixels in ``truth/fruit_ids``
    over pi (f r / z)^2, the disc its true radius would cover at ``z``, the median true depth (``truth/depth``) over
    those pixels (``focal``: the RGB camera's focal length in pixels)."""
    raw = Path(raw)
    ids_path, depth_path = raw / FRUIT_IDS_DIR / f"{stem}.png", raw / TRUE_DEPTH_DIR / f"{stem}.npy"
    ids = cv2.imread(str(ids_path), cv2.IMREAD_UNCHANGED)
    if ids is None:
        raise CountInputError(f"{ids_path}: missing or unreadable fruit mask (truth of frame {stem})")
    if not depth_path.is_file():
        raise CountInputError(f"{depth_path}: missing; the well-seen fruit need the capture's true depth")
    depth = np.load(depth_path)
    labels = ids.astype(np.int64) - 1
    index = {int(fid): i for i, fid in enumerate(truth.ids)}
    shares: Dict[int, float] = {}
    values, counts = np.unique(labels[labels >= 0], return_counts=True)
    for value, count in zip(values, counts, strict=True):
        k = index.get(int(value))
        if k is not None:
            z = float(np.median(depth[labels == value]))
            shares[k] = float(count) / (np.pi * (focal * 0.5 * truth.diameters[k] / max(z, 1e-6)) ** 2)
    return shares


def disc_views(raw: Path, frames: Iterable[str], truth: TruthFruit, min_share: float = 0.25) -> np.ndarray:
    """Per true fruit, the number of ``frames`` (raw RGB frame stems) that show at least ``min_share`` of its disc
    (:func:`disc_shares`): 1 or more is countable, 2 or more well seen."""
    from agrinerf_ns.process.readers import read_calibration

    camera = read_calibration(Path(raw) / "calib.yaml").rgb
    focal = 0.5 * float(camera.K[0, 0] + camera.K[1, 1])
    frames = list(frames)
    if not frames:
        raise CountInputError(f"{Path(raw) / FRUIT_IDS_DIR}: no training frames to decide how well fruit are seen")
    views = np.zeros(len(truth.ids), dtype=np.int64)
    for stem in frames:
        for k, share in disc_shares(raw, stem, truth, focal).items():
            views[k] += int(share >= min_share)
    return views


def well_seen_fruit(
    raw: Path, frames: Iterable[str], truth: TruthFruit, min_share: float = 0.25, min_views: int = 2
) -> Bool[np.ndarray, " n"]:
    """Which true fruit show at least ``min_share`` of their disc (:func:`disc_shares`) in at least ``min_views`` of
    the ``frames`` (raw RGB frame stems): with ``min_views=1`` the countable fruit."""
    return disc_views(raw, frames, truth, min_share) >= min_views


def score_fruit(
    predicted: Float[np.ndarray, "m 3"],
    truth: TruthFruit,
    visible: Optional[Bool[np.ndarray, " n"]] = None,
    match_distance: float = 0.05,
    temperatures: Optional[Float[np.ndarray, " m"]] = None,
    well_seen: Optional[Bool[np.ndarray, " n"]] = None,
    countable: Optional[Bool[np.ndarray, " n"]] = None,
) -> CountScore:
    """Count error and precision / recall / F1 of ``predicted`` centres (capture frame) against the visible true
    fruit (all of them when ``visible`` is None); with the counted fruit's ``temperatures`` (degrees C, NaN where
    unknown) also their mean error on the true positives; with ``countable`` and ``well_seen`` also the scores over
    those fruit."""
    visible = np.ones(len(truth.ids), dtype=bool) if visible is None else np.asarray(visible, bool)
    rows, cols = match_fruit(predicted, truth.centres, match_distance)
    counted = len(np.asarray(predicted).reshape(-1, 3))
    tp_mask = visible[cols]
    tp = int(tp_mask.sum())
    fp = counted - len(rows)
    n_visible = int(visible.sum())
    fn = n_visible - tp
    precision = tp / (tp + fp) if tp + fp else 0.0
    recall = tp / n_visible if n_visible else 0.0
    f1 = 2 * precision * recall / (precision + recall) if precision + recall else 0.0
    errors = np.linalg.norm(np.asarray(predicted).reshape(-1, 3)[rows[tp_mask]] - truth.centres[cols[tp_mask]], axis=1)
    strict: Dict[str, Union[int, float]] = {}
    for name, tier in (("countable", countable), ("well_seen", well_seen)):
        if tier is not None:
            strict |= _tier_fields(name, np.asarray(tier, bool), cols, counted, precision)
    return CountScore(
        counted=counted,
        visible=n_visible,
        truth_total=len(truth.ids),
        count_error=(counted - n_visible) / n_visible if n_visible else float("nan"),
        true_positives=tp,
        false_positives=fp,
        false_negatives=fn,
        precision=precision,
        recall=recall,
        f1=f1,
        match_distance=match_distance,
        mean_match_error=float(errors.mean()) if errors.size else float("nan"),
        mean_temperature_error=_temperature_error(temperatures, truth, rows[tp_mask], cols[tp_mask]),
        **strict,  # type: ignore[arg-type]
    )


def _tier_fields(
    name: str, tier: Bool[np.ndarray, " n"], cols: np.ndarray, counted: int, precision: float
) -> Dict[str, Union[int, float]]:
    """A stricter tier's count, recall, F1 (with the count's one ``precision``) and count error (``cols``: the true
    fruit matched)."""
    n = int(tier.sum())
    recall = int(tier[cols].sum()) / n if n else 0.0
    return {
        name: n,
        f"recall_{name}": recall,
        f"f1_{name}": 2 * precision * recall / (precision + recall) if precision + recall else 0.0,
        f"count_error_{name}": (counted - n) / n if n else float("nan"),
    }


def tier_scores(
    predicted: Float[np.ndarray, "m 3"],
    truth: TruthFruit,
    tiers: Dict[str, Bool[np.ndarray, " n"]],
    distances: Iterable[float] = TIER_DISTANCES,
) -> Dict[str, Dict[str, Dict[str, float]]]:
    """``{tier: {distance: {truth, precision, recall, f1, count_error}}}`` for each tier of ``tiers`` (which must
    hold ``visible``, the fruit precision is judged against) at each match distance."""
    out: Dict[str, Dict[str, Dict[str, float]]] = {name: {} for name in tiers}
    for distance in distances:
        score = score_fruit(predicted, truth, tiers["visible"], distance, well_seen=tiers.get("well_seen"),
                            countable=tiers.get("countable"))  # fmt: skip
        for name in tiers:
            suffix = "" if name == "visible" else f"_{name}"
            n = score.visible if name == "visible" else int(getattr(score, name))
            out[name][f"{distance:g}"] = {
                "truth": float(n),
                "precision": score.precision,
                "recall": float(getattr(score, f"recall{suffix}")),
                "f1": float(getattr(score, f"f1{suffix}")),
                "count_error": float(getattr(score, f"count_error{suffix}")),
            }
    return out


def _temperature_error(
    temperatures: Optional[np.ndarray], truth: TruthFruit, rows: np.ndarray, cols: np.ndarray
) -> float:
    if temperatures is None or truth.temperatures is None or len(rows) == 0:
        return float("nan")
    error = np.abs(np.asarray(temperatures, np.float64)[rows] - truth.temperatures[cols])
    error = error[np.isfinite(error)]
    return float(error.mean()) if error.size else float("nan")


def read_frames(dataset: Path) -> List[dict]:
    """The frames of the dataset's ``transforms.json`` (raises naming the file when unreadable)."""
    path = Path(dataset) / TRANSFORMS
    try:
        frames = json.loads(path.read_text())["frames"]
        if not isinstance(frames, list) or not all(isinstance(f, dict) and "file_path" in f for f in frames):
            raise TypeError("'frames' must be a list of objects with a file_path")
        return frames
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as err:
        raise CountInputError(f"{path}: cannot read the dataset's frames ({err!r})") from err


def read_split(dataset: Path, key: str) -> List[str]:
    """A split list of ``transforms.json`` (``train_filenames``, ...); empty when it has none."""
    path = Path(dataset) / TRANSFORMS
    try:
        return [str(name) for name in json.loads(path.read_text()).get(key, [])]
    except (OSError, json.JSONDecodeError, AttributeError, TypeError) as err:
        raise CountInputError(f"{path}: cannot read the dataset's {key} ({err!r})") from err


def dataset_frames(dataset: Path) -> Dict[str, dict]:
    """``file_path`` -> frame of the dataset's ``transforms.json``."""
    return {str(f["file_path"]): f for f in read_frames(dataset)}


def raw_stem(frame: dict, file_path: str) -> str:
    """The raw capture's RGB frame stem of a dataset frame (``raw_rgb``, else the dataset image's own stem)."""
    return Path(str(frame.get("raw_rgb", file_path))).stem


def align_to_capture(dataset: Path, raw: Path, tolerance_s: float = 1e-3) -> Similarity:
    """The similarity from the dataset's frame to the capture's, fit on the cameras (dataset frames' ``timestamp``
    matched to ``truth/poses.txt``): the rotation from the cameras' orientations (their mean relative rotation; camera
    centres alone leave the rotation about a straight path undetermined), then scale and translation from the centres
    by least squares. Raises :class:`CountInputError` naming the file that lacks the poses."""
    from agrinerf_ns.trajectory import TrajectoryError, read_tum

    try:
        times, poses = read_tum(Path(raw) / TRUE_POSES)
    except TrajectoryError as err:
        raise CountInputError(str(err)) from err
    from agrinerf_ns.process.poses import camera_similarity

    src, dst = [], []
    opengl_to_opencv = np.diag([1.0, -1.0, -1.0, 1.0])
    for frame in read_frames(dataset):
        if "timestamp" not in frame:
            continue
        k = int(np.argmin(np.abs(times - float(frame["timestamp"]))))
        if abs(times[k] - float(frame["timestamp"])) <= tolerance_s:
            c2w = np.eye(4)
            c2w[:3, :4] = np.asarray(frame["transform_matrix"], np.float64)[:3, :4]
            src.append(c2w @ opengl_to_opencv)
            dst.append(poses[k])
    if len(src) < 3:
        raise CountInputError(
            f"{Path(dataset) / TRANSFORMS}: {len(src)} frames have a timestamp matching "
            f"{Path(raw) / TRUE_POSES}; aligning the dataset to the capture needs 3 (or pass --align none)"
        )
    scale, rot, t, rms = camera_similarity(np.stack(src), np.stack(dst))
    return Similarity(scale, rot, t, rms)
