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
from pathlib import Path
from typing import List, Sequence

import numpy as np
from jaxtyping import Float

from agrinerf_ns.count.cluster import ClusterConfig, cluster_fruit, merge_distance
from agrinerf_ns.count.errors import CountInputError
from agrinerf_ns.count.fruit_score import dataset_frames, read_split
from agrinerf_ns.count.lift import LiftedDetection
from agrinerf_ns.dataset_format import FRUIT_BODIES


def read_sightings(dataset: Path) -> List[dict]:
    """The dataset's thermal fruit sightings (``fruit_bodies.json``), each checked for its fields."""
    path = Path(dataset) / FRUIT_BODIES
    if not path.is_file():
        raise CountInputError(
            f"{path}: no thermal fruit bodies in this dataset (made by `agrinerf-process --fruit-mask-maker auto` or "
            "`thermal` with --mask-maker.thermal-rule bodies on dark frames with a thermal camera)"
        )
    try:
        rows = json.loads(path.read_text())["sightings"]
        for row in rows:
            if len(row["centre"]) != 3 or not float(row["diameter"]) > 0 or not isinstance(row["frame"], str):
                raise ValueError(f"bad sighting {row}")
    except (OSError, json.JSONDecodeError, KeyError, TypeError, ValueError) as err:
        raise CountInputError(f"{path}: not a fruit bodies file ({err})") from err
    return rows


def training_images(dataset: Path) -> List[str]:
    """The dataset's training frames (``file_path``): its ``train_filenames``, else every frame."""
    listed = read_split(dataset, "train_filenames")
    return listed if listed else list(dataset_frames(dataset))


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


def camera_centres(dataset: Path, frames: Sequence[str]) -> Float[np.ndarray, "n 3"]:
    """The centres of the dataset's cameras ``frames``, in its frame."""
    by_path = dataset_frames(dataset)
    return np.array([np.asarray(by_path[name]["transform_matrix"], np.float64)[:3, 3] for name in frames])


def count_sightings(detections: Sequence[LiftedDetection], config: ClusterConfig) -> tuple:
    """The fruit of these sightings and the merge distance used."""
    return cluster_fruit(detections, config), merge_distance(detections, config)
