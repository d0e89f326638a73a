"""Intervals of a capture's fruit count and of its mean fruit temperature.

The count: a delete-a-group jackknife over the views. The views are dealt into ``groups`` interleaved groups (view i
into group i mod G); each group in turn is left out and the fruit fused again from the other views' detections (the
count's own :func:`~agrinerf_ns.count.pipeline.fuse`: clustering and the view-support rule), and the spread of those
G counts, scaled by the jackknife's (G - 1) / G, is the variance of the count. The interval is the count plus or minus
Student's t (G - 1 degrees of freedom) times its square root (not below 0): how much the count rests on which views happened to
detect each fruit. It says nothing of fruit no view shows, nor of a detector's systematic misses.

The temperature: the mean of the counted fruit's rendered temperatures with Student's t interval over the fruit
(:func:`mean_interval`, which also gives a row's mean score over its segments).
"""

from __future__ import annotations

import dataclasses
import math
from typing import List, Optional, Sequence, Tuple

from agrinerf_ns.count.cluster import ClusterConfig, Fruit
from agrinerf_ns.count.lift import LiftedDetection
from agrinerf_ns.count.pipeline import fuse
from agrinerf_ns.count.render import RenderSet

JACKKNIFE_GROUPS = 10


def _t(confidence: float, dof: int) -> float:
    from scipy import stats

    return float(stats.t.ppf(0.5 + confidence / 2, dof))


def jackknife_counts(
    detections: Sequence[LiftedDetection], renders: RenderSet, cluster: ClusterConfig, groups: int
) -> List[int]:
    """The fruit count with each of ``groups`` interleaved groups of views left out in turn."""
    counts = []
    for group in range(groups):
        kept = [v for i, v in enumerate(renders.views) if i % groups != group]
        subset = dataclasses.replace(renders, views=kept)
        counts.append(len(fuse([d for d in detections if d.view % groups != group], subset, cluster)))
    return counts


def count_interval(
    count: int,
    detections: Sequence[LiftedDetection],
    renders: RenderSet,
    cluster: ClusterConfig,
    groups: int = JACKKNIFE_GROUPS,
    confidence: float = 0.95,
) -> Tuple[float, float]:
    """``confidence`` interval of ``count`` (the fruit fused from all views) by the view jackknife, its lower end at
    least 0; (nan, nan) with fewer than two views."""
    g = min(groups, len(renders.views))
    if g < 2:
        return math.nan, math.nan
    counts = jackknife_counts(detections, renders, cluster, g)
    mean = sum(counts) / g
    half = _t(confidence, g - 1) * math.sqrt((g - 1) / g * sum((c - mean) ** 2 for c in counts))
    return max(0.0, count - half), count + half


def mean_interval(values: Sequence[float], confidence: float = 0.95) -> Tuple[float, float]:
    """Mean of the finite ``values`` and its Student's t interval's half-width (nan: no values; nan half-width: fewer
    than two)."""
    kept = [float(v) for v in values if v is not None and math.isfinite(v)]
    if not kept:
        return math.nan, math.nan
    mean = sum(kept) / len(kept)
    if len(kept) < 2:
        return mean, math.nan
    sd = math.sqrt(sum((v - mean) ** 2 for v in kept) / (len(kept) - 1))
    return mean, _t(confidence, len(kept) - 1) * sd / math.sqrt(len(kept))


def mean_temperature(fruit: Sequence[Fruit], confidence: float = 0.95) -> Tuple[float, float]:
    """Mean rendered temperature of the fruit that have one (degrees C) and its interval's half-width (nan when
    fewer than two have one)."""
    return mean_interval([f.temperature for f in fruit if f.temperature is not None], confidence)


def finite_or_none(value: Optional[float]) -> Optional[float]:
    """``value`` for JSON: None where it is not a finite number."""
    return value if value is not None and math.isfinite(value) else None
