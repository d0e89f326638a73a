"""Fruit counted from the thermal camera's bodies (``agrinerf-count --path bodies``), without a field's depth.

The data stage's ``bodies`` rule (:mod:`agrinerf_ns.fruit.thermal_bodies`) places every thermal blob it decides fruit
where the rays of the frames that saw it meet, and the dataset keeps those sightings
(:data:`agrinerf_ns.dataset_format.FRUIT_BODIES`). Each sighting is a detection already in 3D: clustered like the
views path's lifted detections (:func:`agrinerf_ns.count.cluster.cluster_fruit`), a fruit is one place that several
frames saw. In the dark, where the field's depth rendered from dark RGB frames misplaces most detections
(results/fruit-masks-dark), the sightings' places come from the poses alone.
"""

from __future__ import annotations

import json
from dataclasses import asdict, replace
from pathlib import Path
from typing import TYPE_CHECKING, Dict, List, Optional, Sequence

import numpy as np
from jaxtyping import Float

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.count.cluster import cluster_fruit, merge_distance
from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.count.fruit_score import dataset_frames, read_truth_fruit
from agrinerf_ns.count.lift import LiftedDetection
from agrinerf_ns.count.render import WorldFrame, dataset_pose_source
from agrinerf_ns.count.row_range import fruit_in_range
from agrinerf_ns.dataset_format import FRUIT_BODIES, sighting_cameras

if TYPE_CHECKING:
    from agrinerf_ns.count.pipeline import CountConfig, CountResult

BODIES_MERGE_FRACTION = 1.2
"""The bodies path's merge fraction (:attr:`~agrinerf_ns.count.cluster.ClusterConfig.merge_fraction`): a sighting is
placed by the few neighbouring frames that matched it, so one fruit's sightings scatter along its rays by more than
the views path's lifted detections (on four tuning captures, 1.2 against 0.8: the row's countable fruit 0.43 against
0.40; results/fruit-count-dark)."""
IDENTITY_FRAME = WorldFrame(np.eye(3, 4), 1.0)
"""The dataset's own frame, for a count made without a run."""


def read_sightings(dataset: Path) -> List[dict]:
    """The dataset's thermal fruit sightings (``fruit_bodies.json``), each checked for its fields."""
    path = Path(dataset) / FRUIT_BODIES
    if not path.is_file():
        raise CountInputError(
            f"{path}: no fruit bodies in this dataset (made by `agrinerf-process --fruit-mask-maker auto`, `colour` or "
            "`yolo` with poses from the lit frames' masks, and by the thermal bodies rule on dark frames)"
        )
    try:
        rows = json.loads(path.read_text())["sightings"]
        for row in rows:
            if len(row["centre"]) != 3 or not float(row["diameter"]) > 0 or not isinstance(row["frame"], str):
                raise ValueError(f"bad sighting {row}")
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CountInputError(f"{path}: not a fruit bodies file ({err})") from err
    return rows


def body_detections(sightings: Sequence[dict], frames: Sequence[str]) -> List[LiftedDetection]:
    """The sightings of ``frames`` (dataset ``file_path`` values) as lifted detections, their view the frame's index
    in ``frames``."""
    index = {name: k for k, name in enumerate(frames)}
    return [
        LiftedDetection(
            view=index[row["frame"]],
            centre=np.asarray(row["centre"], np.float64),
            diameter=float(row["diameter"]),
            score=1.0,
            temperature=None if row.get("temperature") is None else float(row["temperature"]),
            origin=np.asarray(row["origin"], np.float64) if "origin" in row else None,
            ray=np.asarray(row["ray"], np.float64) if "ray" in row else None,
        )
        for row in sightings
        if row["frame"] in index
    ]


def camera_centres(frames: Dict[str, dict]) -> Float[np.ndarray, "n 3"]:
    """The centres of a dataset's cameras (``file_path`` -> frame of its ``transforms.json``), in its frame."""
    return np.array([np.asarray(frame["transform_matrix"], np.float64)[:3, 3] for frame in frames.values()])


def run_body_count(
    dataset: Path,
    out: Path,
    config: "CountConfig",
    truth: Optional[Path] = None,
    overwrite: bool = False,
    frame: Optional[WorldFrame] = None,
) -> "CountResult":
    """Count the fruit of ``dataset``'s thermal bodies and write ``out`` atomically as the views path does
    (fruits.csv, fruits.ply, fruit_map.png, count.json; score.md against ``truth``). ``frame``: a run's Nerfstudio
    frame for fruits.csv's ``ns_*`` columns (None: the dataset's own)."""
    from agrinerf_ns.count.pipeline import CountResult, raw_training_frames, score_result, write_count

    dataset = Path(dataset)
    sightings = read_sightings(dataset)  # fail before any work
    if truth is not None:
        read_truth_fruit(truth)
    by_path = dataset_frames(dataset)
    frames = list(by_path)
    detections = body_detections(sightings, frames)
    if config.cluster.merge_fraction is None:
        config = replace(config, cluster=replace(config.cluster, merge_fraction=BODIES_MERGE_FRACTION))
    cameras = camera_centres(by_path)
    fruit = fruit_in_range(cluster_fruit(detections, config.cluster), cameras, config.max_range)
    per_frame = np.bincount(np.array([d.view for d in detections], np.int64), minlength=len(frames)).tolist()
    result = CountResult(fruit, detections, per_frame, merge_distance(detections, config.cluster))
    with atomic_output_dir(Path(out), overwrite) as tmp:
        if truth is not None:
            score_result(result, dataset, raw_training_frames(dataset, frames), Path(truth), config, cameras)
        settings = {
            "path": "bodies",
            "source": str(dataset / FRUIT_BODIES),
            "method": None,
            "views": len(frames),
            "cluster": asdict(config.cluster),
            "merge_distance": result.merge_distance,
            "max_range": config.max_range,
            "poses": {"source": dataset_pose_source(dataset), "views": "the thermal frames' poses in the dataset"},
            "detections": len(detections),
            "sightings": sighting_cameras(sightings),
            "detections_per_view": per_frame,
        }
        title = f"{len(fruit)} fruit counted from the fruit bodies of {len(frames)} frames"
        write_count(tmp, result, frame or IDENTITY_FRAME, np.zeros((0, 3)), cameras, title, settings, config, truth,
                    f"fruit bodies (fruit_bodies.json: {settings['sightings']} sightings per camera)")  # fmt: skip
    return result
