"""Fruit in a sampled field: the seen, dense voxels that stand out from the surfaces around them in the source output
(warmer or cooler than the leaves; fruit-coloured in RGB), grouped into connected components, kept when fruit-sized.

*Standing out*: a voxel's feature minus the mean over the seen, dense voxels within ``background_size`` (a box
filter over the grid, normalised by the voxels it covers), in units of the robust spread (1.4826 MAD) of that
difference over all of them; a voxel beyond ``threshold`` is a fruit voxel. With ``polarity both`` warm and cool
voxels are grouped apart (a seed's fruit are all warmer or all cooler than its leaves, the ground and bark can be
either). Source ``fruit``: the fruit head's probability reaches ``fruit_probability``. RGB: the fruit-colour score
of :func:`agrinerf_ns.fruit.colour_score.fruit_colour` (red to yellow saturation after
scaling the voxels' 99th brightness percentile to 1), warm polarity only.

*Fruit-sized*: a 26-connected component of fruit voxels is a fruit when its diameter (``2 sqrt(5 l1)``, with l1 the
largest variance of its voxel centres: a solid ball's diameter from its variance) lies in ``min_diameter`` ..
``max_diameter``, its two largest spreads differ by at most ``max_elongation`` (a leaf rim against warm ground is a
strip) and at least ``min_views`` training views show it with ``min_pixels`` pixels of their images (the truth's
rule for a fruit visible from the capture).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import List, Optional, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.count.source_table import source_row
from agrinerf_ns.count.volume import SampledField, mask_of, views_showing_pixels
from agrinerf_ns.fruit.contrast import Polarity
from agrinerf_ns.robust import robust_spread

DIAMETER_PER_SD = 2.0 * np.sqrt(5.0)
"""A solid ball's diameter over the standard deviation of its points along any axis."""


@dataclass(frozen=True)
class ComponentConfig:
    """How fruit voxels are found and grouped."""

    threshold: float = 2.5
    """Fruit voxels stand out from their surroundings by at least this many robust spreads."""
    polarity: Polarity = "both"
    """Fruit warmer (``warm``), cooler (``cool``) or either (``both``) than their surroundings; RGB is always warm."""
    background_size: float = 0.3
    """Side (dataset units) of the box whose seen, dense voxels give a voxel's surroundings."""
    min_diameter: float = 0.03
    """Smallest fruit diameter kept (dataset units)."""
    max_diameter: float = 0.16
    """Largest fruit diameter kept (dataset units)."""
    max_elongation: float = 3.0
    """Largest ratio of a fruit's two largest spreads."""
    min_voxels: int = 3
    """Smallest component kept (voxels)."""
    min_views: int = 2
    """Training views that must show a fruit with at least ``min_pixels`` of their pixels (without views: the most
    views that see any of its voxels)."""
    fruit_probability: float = 0.5
    """Source ``fruit``: a voxel is a fruit voxel where the fruit head's probability reaches this (instead of standing
    out from its surroundings)."""
    split_diameter: Optional[float] = None
    """Touching fruit: a component too large or too elongated for one fruit is split by k-means into as many parts
    as fruit of this diameter (dataset units) would cover its two largest spreads, and each part is judged alone;
    None: such components are dropped."""
    min_pixels: float = 3.0
    """Pixels of a training image (at the dataset's resolution) a fruit must cover to count as shown in it (as a true
    fruit is visible with 3 pixels of a training view's truth mask)."""


def standing_out(sampled: SampledField, config: ComponentConfig) -> Float[np.ndarray, " n"]:
    """Each seen, dense voxel's feature minus its surroundings' mean, in robust spreads (see the module)."""
    from scipy.ndimage import uniform_filter

    feature = _feature(sampled)
    grid = sampled.grid
    mask = mask_of(grid, sampled.flat).astype(np.float32)
    values = np.zeros(int(np.prod(grid.shape)), np.float32)
    values[sampled.flat] = feature
    size = max(3, int(round(config.background_size * sampled.frame.scale / grid.step)) | 1)
    total = uniform_filter(values.reshape(grid.shape), size=size, mode="constant")
    count = uniform_filter(mask, size=size, mode="constant")
    background = (total / np.maximum(count, 1e-6)).reshape(-1)[sampled.flat]
    difference = feature - background
    spread = robust_spread(difference) if len(difference) else 1.0
    return difference / max(spread, 1e-6)


def _feature(sampled: SampledField) -> Float[np.ndarray, " n"]:
    """One value per voxel, as the source's row makes it (the output itself, or the fruit-colour score of RGB)."""
    return source_row(sampled.source).value(sampled.feature)


def find_fruit(sampled: SampledField, config: ComponentConfig = ComponentConfig()) -> Tuple[List[Fruit], dict]:
    """Fruit (dataset frame and units) of a sampled field, and a summary of what was found and dropped."""
    row = source_row(sampled.source)
    if row.probability:  # e.g. the fruit head says it directly: its probability against a threshold
        probability = sampled.feature[:, 0].astype(np.float32)
        selections = [(probability >= config.fruit_probability, probability)]
    else:
        z = standing_out(sampled, config)
        polarities = ["warm"] if row.one_sided else (
            ["warm", "cool"] if config.polarity == "both" else [config.polarity])  # fmt: skip
        selections = [(z >= config.threshold if p == "warm" else z <= -config.threshold, np.abs(z)) for p in polarities]
    fruit: List[Fruit] = []
    stats = {
        "fruit_voxels": 0,
        "components": 0,
        "split": 0,
        "too_small": 0,
        "too_large": 0,
        "elongated": 0,
        "unseen": 0,
    }
    for selected, score in selections:
        stats["fruit_voxels"] += int(selected.sum())
        found, dropped = _components(sampled, selected, score, config)
        fruit.extend(found)
        for key, value in dropped.items():
            stats[key] += value
    stats["fruit"] = len(fruit)
    return sorted(fruit, key=lambda f: (-f.views, tuple(f.centre))), stats


def _split(xyz: Float[np.ndarray, "n 3"], spreads: np.ndarray, diameter: float) -> List[np.ndarray]:
    """Index arrays of the k-means parts of a component whose two largest spreads would hold k fruit of
    `diameter` (one part when k < 2)."""
    from scipy.cluster.vq import kmeans2

    sd = diameter / DIAMETER_PER_SD
    k = int(min(len(xyz) // 3, round(float(spreads[0] * spreads[1]) / sd**2)))
    if k < 2:
        return [np.arange(len(xyz))]
    _, assignment = kmeans2(xyz.astype(np.float64), k, minit="++", seed=0)
    return [np.flatnonzero(assignment == j) for j in range(k) if np.any(assignment == j)]


def _components(
    sampled: SampledField, selected: np.ndarray, score: np.ndarray, config: ComponentConfig
) -> Tuple[List[Fruit], dict]:
    from scipy.ndimage import label

    grid, frame = sampled.grid, sampled.frame
    labels, count = label(mask_of(grid, sampled.flat[selected]), structure=np.ones((3, 3, 3), bool))
    voxel_label = labels.reshape(-1)[sampled.flat]  # 0 where not selected
    order = np.argsort(voxel_label, kind="stable")
    bounds = np.searchsorted(voxel_label[order], np.arange(1, count + 2))
    points = frame.to_dataset(sampled.points())
    dropped = {"components": count, "split": 0, "too_small": 0, "too_large": 0, "elongated": 0, "unseen": 0}
    fruit: List[Fruit] = []
    queue = [(order[bounds[k] : bounds[k + 1]], True) for k in range(count)]  # (voxels, may be split)
    while queue:
        members, splittable = queue.pop()
        if len(members) < config.min_voxels:
            dropped["too_small"] += 1
            continue
        xyz = points[members]
        spreads = np.sqrt(np.maximum(np.linalg.eigvalsh(np.cov(xyz.T)), 0.0))[::-1]
        voxel = grid.step / frame.scale
        spreads = np.sqrt(spreads**2 + voxel**2 / 12.0)  # a voxel's own extent
        diameter = float(DIAMETER_PER_SD * spreads[0])
        if diameter < config.min_diameter:
            dropped["too_small"] += 1
            continue
        too_large, elongated = diameter > config.max_diameter, spreads[0] > config.max_elongation * spreads[1]
        if (too_large or elongated) and config.split_diameter and splittable:
            parts = _split(xyz, spreads, config.split_diameter)
            if len(parts) > 1:
                queue.extend((members[part], False) for part in parts)
                dropped["split"] += 1
                continue
        if too_large:
            dropped["too_large"] += 1
            continue
        if elongated:
            dropped["elongated"] += 1
            continue
        if sampled.views:
            views = views_showing_pixels(sampled.points()[members], sampled.views, sampled.seen_margin,
                                         config.min_pixels, sampled.field, _device(sampled.field))  # fmt: skip
        else:
            views = int(sampled.seen_by[members].max())
        if views < config.min_views:
            dropped["unseen"] += 1
            continue
        temperature = None
        if sampled.temperature is not None:
            temperature = float(np.mean(sampled.temperature[members]))
        fruit.append(
            Fruit(
                centre=xyz.mean(0),
                diameter=diameter,
                views=views,
                detections=int(len(members)),
                temperature=temperature,
                score=float(np.mean(score[members])),
            )
        )
    return fruit, dropped


def _device(field: object) -> object:
    """Where the field's parameters are (``cpu`` without any)."""
    parameters = getattr(field, "parameters", None)
    first = next(iter(parameters()), None) if callable(parameters) else None
    return first.device if first is not None else "cpu"
