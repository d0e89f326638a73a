"""Fruit of neighbouring segments joined across their borders, so that a fruit two segments both counted is kept once.

Every segment counts the fruit it saw, in the capture's world frame (:mod:`agrinerf_ns.row.segments`). Where two
segments share frames, a fruit near those frames (its nearest camera among the shared frames, give or take the
join distance) may be in both counts. Such candidates of two segments are matched one-to-one within ``distance`` by
the count's own matching (:func:`~agrinerf_ns.count.fruit_score.match_fruit`, Hungarian on the distances), so two
distinct fruit one segment kept apart stay apart. Where more than two segments share frames, the matched pairs are
joined into groups nearest first, a group never holding two fruit of one segment. Each group is kept once, the copy
of the segment that saw it best: the most views, then the nearest its segment's middle (a fruit at a segment's end is
seen from one side only). Fruit outside every overlap pass through.

The default distance, 0.30 m, is measured (``benchmarks/row_join_distance.py``, results/row/README.md): every true
fruit of a synthetic row (tuning seed 0) placed twice with the placement error measured on the dark counts' tuning
seeds (results/fruit-count-dark/tuning/placement.md, largest standard deviation per axis: 6.4 to 6.8 cm across the
view) and joined by this rule. Closer distances leave many copies apart (double counts).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Dict, List, Sequence, Tuple

import numpy as np
from jaxtyping import Float, Int

from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.count.fruit_score import match_fruit
from agrinerf_ns.row.segments import Segment

JOIN_DISTANCE = 0.30
"""Metres (dataset units): see the module."""


@dataclass(frozen=True)
class RowFruit:
    """A fruit of one segment's count, with where along the trajectory it is."""

    fruit: Fruit
    segment: int
    """Index of the segment that counted it."""
    frame: int
    """Its nearest camera's frame, in trajectory order of the whole capture."""


@dataclass
class JoinResult:
    """The row's fruit, each once, and what the join did."""

    fruit: List[RowFruit]
    copies: List[int]
    """Per kept fruit, how many segments counted it (1: no other segment did)."""
    pairs: Dict[Tuple[int, int], int] = field(default_factory=dict)
    """Per pair of overlapping segments, the fruit joined between them."""


def nearest_frames(points: Float[np.ndarray, "n 3"], cameras: Float[np.ndarray, "c 3"]) -> Int[np.ndarray, " n"]:
    """Each point's nearest camera (index into ``cameras``, the trajectory order)."""
    from scipy.spatial import cKDTree

    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0, np.int64)
    return cKDTree(np.asarray(cameras, np.float64).reshape(-1, 3)).query(points)[1].astype(np.int64)


def row_fruit(per_segment: Sequence[Sequence[Fruit]], cameras: Float[np.ndarray, "c 3"]) -> List[RowFruit]:
    """Every segment's fruit (``per_segment[i]``: segment i's) with its nearest camera's frame."""
    out: List[RowFruit] = []
    for index, fruit in enumerate(per_segment):
        frames = nearest_frames(np.array([f.centre for f in fruit]).reshape(-1, 3), cameras)
        out += [RowFruit(f, index, int(k)) for f, k in zip(fruit, frames, strict=True)]
    return out


def _margin_frames(cameras: np.ndarray, distance: float) -> int:
    steps = np.linalg.norm(np.diff(cameras, axis=0), axis=1)
    step = float(np.median(steps)) if len(steps) else 0.0
    return int(math.ceil(distance / step)) if step > 0 else 0


def join_fruit(
    per_segment: Sequence[Sequence[Fruit]],
    segments: Sequence[Segment],
    cameras: Float[np.ndarray, "c 3"],
    distance: float = JOIN_DISTANCE,
) -> JoinResult:
    """The fruit of all ``segments`` (``per_segment[i]``: segment i's count; ``cameras``: the whole capture's camera
    centres in trajectory order, dataset frame) joined across their overlaps (see the module)."""
    if len(per_segment) != len(segments):
        raise ValueError(f"{len(per_segment)} segment counts for {len(segments)} segments")
    if not distance > 0:
        raise ValueError(f"the join distance must be positive, got {distance}")
    cameras = np.asarray(cameras, np.float64).reshape(-1, 3)
    items = row_fruit(per_segment, cameras)
    margin = _margin_frames(cameras, distance)
    centres = np.array([r.fruit.centre for r in items], np.float64).reshape(-1, 3)
    candidates: List[Tuple[float, int, int]] = []
    for a, first in enumerate(segments):
        for second in segments[a + 1 :]:
            lo, hi = max(first.start, second.start) - margin, min(first.stop, second.stop) + margin
            if min(first.stop, second.stop) <= max(first.start, second.start):
                continue  # no shared frames
            left = [i for i, r in enumerate(items) if r.segment == first.index and lo <= r.frame < hi]
            right = [j for j, r in enumerate(items) if r.segment == second.index and lo <= r.frame < hi]
            rows, cols = match_fruit(centres[left], centres[right], distance)  # the count's one-to-one matching
            for a_row, b_col in zip(rows, cols, strict=True):
                i, j = left[int(a_row)], right[int(b_col)]
                candidates.append((float(np.linalg.norm(centres[i] - centres[j])), i, j))
    group = list(range(len(items)))
    members: Dict[int, List[int]] = {i: [i] for i in range(len(items))}

    def root(i: int) -> int:
        while group[i] != i:
            group[i] = group[group[i]]
            i = group[i]
        return i

    pairs: Dict[Tuple[int, int], int] = {}
    for _, i, j in sorted(candidates):
        a, b = root(i), root(j)
        if a == b:
            continue
        if {items[k].segment for k in members[a]} & {items[k].segment for k in members[b]}:
            continue  # one segment's two fruit are two fruit
        group[b] = a
        members[a] += members.pop(b)
        key = (items[i].segment, items[j].segment)
        pairs[key] = pairs.get(key, 0) + 1
    by_index = {s.index: s for s in segments}
    kept, copies = [], []
    for head in sorted(members, key=lambda h: min(items[k].frame for k in members[h])):
        best = min(members[head], key=lambda k: (-items[k].fruit.views,
                                                 abs(items[k].frame - by_index[items[k].segment].middle),
                                                 items[k].segment))  # fmt: skip
        kept.append(items[best])
        copies.append(len(members[head]))
    return JoinResult(kept, copies, pairs)
