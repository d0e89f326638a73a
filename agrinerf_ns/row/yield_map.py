"""The row's yield map: fruit per metre along the driven path (``row_yield.csv``) and a top view (``row_map.png``).

A fruit's place along the row is its projection on the driven path: the path length to its nearest camera plus its
offset along the path there. Bins of ``bin_m`` metres run from the first camera to the last (the last bin may be
shorter; its fruit per metre is over its own length); a bin with no fruit is a gap.
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence, Tuple

import numpy as np
from jaxtyping import Float, Int, Num

ROW_YIELD_COLUMNS = ("bin", "start_m", "end_m", "fruit", "fruit_per_m", "gap", "truth_fruit", "truth_per_m")


def path_length(cameras: Float[np.ndarray, "c 3"]) -> Float[np.ndarray, " c"]:
    """Distance driven to each camera (metres, dataset units) from the first."""
    cameras = np.asarray(cameras, np.float64).reshape(-1, 3)
    return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(cameras, axis=0), axis=1))])


def along_row(points: Float[np.ndarray, "n 3"], cameras: Float[np.ndarray, "c 3"]) -> Float[np.ndarray, " n"]:
    """Each point's place along the driven path (metres from the first camera, within the path's length)."""
    from agrinerf_ns.row.join import nearest_frames

    points = np.asarray(points, np.float64).reshape(-1, 3)
    cameras = np.asarray(cameras, np.float64).reshape(-1, 3)
    if len(points) == 0:
        return np.zeros(0)
    s = path_length(cameras)
    k = nearest_frames(points, cameras)
    ahead = np.minimum(k + 1, len(cameras) - 1)
    behind = np.maximum(k - 1, 0)
    tangent = cameras[ahead] - cameras[behind]
    tangent /= np.maximum(np.linalg.norm(tangent, axis=1, keepdims=True), 1e-12)
    offset = np.sum((points - cameras[k]) * tangent, axis=1)
    return np.clip(s[k] + offset, 0.0, s[-1])


@dataclass(frozen=True)
class YieldBins:
    """Fruit per bin along the row."""

    edges: Float[np.ndarray, " b1"]
    counts: Int[np.ndarray, " b"]
    truth: Optional[Int[np.ndarray, " b"]] = None

    @property
    def widths(self) -> Float[np.ndarray, " b"]:
        return np.diff(self.edges)

    @property
    def per_metre(self) -> Float[np.ndarray, " b"]:
        return self.counts / np.maximum(self.widths, 1e-12)


def yield_bins(
    positions: Float[np.ndarray, " n"],
    length: float,
    bin_m: float,
    truth_positions: Optional[Float[np.ndarray, " t"]] = None,
) -> YieldBins:
    """Counts of ``positions`` (metres along the row) in bins of ``bin_m`` over ``[0, length]``; with
    ``truth_positions`` the true fruit's too."""
    if not bin_m > 0:
        raise ValueError(f"--bin-m must be positive, got {bin_m}")
    n = max(1, math.ceil(length / bin_m - 1e-9))
    edges = np.minimum(np.arange(n + 1) * bin_m, length) if length > 0 else np.array([0.0, bin_m])
    edges[-1] = max(length, edges[-2] + 1e-9) if length > 0 else bin_m

    def count(p: np.ndarray) -> np.ndarray:
        index = np.clip(np.searchsorted(edges, np.asarray(p, np.float64), side="right") - 1, 0, n - 1)
        return np.bincount(index, minlength=n).astype(np.int64)

    truth = None if truth_positions is None else count(truth_positions)
    return YieldBins(edges.astype(np.float64), count(positions), truth)


def write_yield_csv(path: Path, bins: YieldBins) -> None:
    """``row_yield.csv``: one line per bin (truth columns empty without a truth)."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(ROW_YIELD_COLUMNS)
        for i, (count, per_m) in enumerate(zip(bins.counts, bins.per_metre, strict=True)):
            row = [i, f"{bins.edges[i]:.3f}", f"{bins.edges[i + 1]:.3f}", int(count), f"{per_m:.3f}", int(count == 0)]
            if bins.truth is not None:
                row += [int(bins.truth[i]), f"{bins.truth[i] / max(bins.widths[i], 1e-12):.3f}"]
            else:
                row += ["", ""]
            writer.writerow(row)


def correlation(
    a: Num[np.ndarray, " n"], b: Num[np.ndarray, " n"], confidence: float = 0.95
) -> Tuple[float, float, float]:
    """Pearson's r of ``a`` and ``b`` with its ``confidence`` interval (Fisher's z); nan where undefined (fewer than
    4 pairs for the interval, or a constant series)."""
    x, y = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(x) < 2 or x.std() == 0 or y.std() == 0:
        return math.nan, math.nan, math.nan
    r = float(np.corrcoef(x, y)[0, 1])
    if len(x) < 4:
        return r, math.nan, math.nan
    from scipy import stats

    z, half = math.atanh(max(min(r, 0.999999), -0.999999)), stats.norm.ppf(0.5 + confidence / 2) / math.sqrt(len(x) - 3)
    return r, math.tanh(z - half), math.tanh(z + half)


def draw_row_map(
    path: Path,
    centres: Float[np.ndarray, "n 3"],
    temperatures: Float[np.ndarray, " n"],
    cameras: Float[np.ndarray, "c 3"],
    bins: YieldBins,
    overlaps: Sequence[Tuple[float, float]],
    title: str,
) -> None:
    """Top view of the row (x, y of the dataset's frame): the driven path, each fruit at its place coloured by its
    temperature (red where unknown); under it the fruit per metre of each bin along the path, gaps (no fruit)
    shaded red, the segments' overlaps (start and end along the path, metres) hatched."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cameras = np.asarray(cameras, np.float64).reshape(-1, 3)
    centres = np.asarray(centres, np.float64).reshape(-1, 3)
    pts = np.concatenate([cameras[:, :2], centres[:, :2]]) if len(centres) else cameras[:, :2]
    lo, hi = pts.min(0) - 0.3, pts.max(0) + 0.3
    aspect = float((hi[1] - lo[1]) / max(hi[0] - lo[0], 1e-6))
    width = 12.0
    fig, (top, bars) = plt.subplots(2, 1, figsize=(width, min(6.0, max(2.0, width * aspect)) + 2.8),
                                    gridspec_kw={"height_ratios": [max(1.0, 4 * aspect), 1.0]})  # fmt: skip
    top.plot(cameras[:, 0], cameras[:, 1], "-", color="tab:blue", linewidth=1.2, label="driven path")
    known = np.isfinite(temperatures)
    if known.any():
        sc = top.scatter(centres[known, 0], centres[known, 1], c=temperatures[known], cmap="turbo", s=14,
                         edgecolors="black", linewidths=0.3, label="fruit")  # fmt: skip
        fig.colorbar(sc, ax=top, label="fruit temperature (C)", fraction=0.025, pad=0.01)
    if (~known).any():
        top.scatter(centres[~known, 0], centres[~known, 1], color="red", s=14, edgecolors="black", linewidths=0.3,
                    label="fruit, no temperature")  # fmt: skip
    top.set_xlim(lo[0], hi[0])
    top.set_ylim(lo[1], hi[1])
    top.set_aspect("equal" if aspect <= 0.5 else "auto")  # a short row: not a tall strip
    top.set_xlabel("x (m, capture world frame)")
    top.set_ylabel("y (m)")
    top.set_title(title, fontsize=10)
    top.legend(loc="upper right", fontsize=7)
    starts, widths = bins.edges[:-1], bins.widths
    bars.bar(starts, bins.per_metre, width=widths, align="edge", color="tab:green", edgecolor="black",
             linewidth=0.4, label="counted")  # fmt: skip
    if bins.truth is not None:
        bars.step(bins.edges, np.append(bins.truth / np.maximum(widths, 1e-12), 0.0), where="post", color="black",
                  linewidth=1.0, label="truth")  # fmt: skip
    for start, w, count in zip(starts, widths, bins.counts, strict=True):
        if count == 0:
            bars.axvspan(start, start + w, color="red", alpha=0.15, linewidth=0)
    for start, end in overlaps:
        bars.axvspan(start, end, facecolor="none", edgecolor="0.4", hatch="//", linewidth=0)
    bars.set_xlim(bins.edges[0], bins.edges[-1])
    bars.set_xlabel("along the driven path (m); red: gap (no fruit); hatched: two segments overlap")
    bars.set_ylabel("fruit per m")
    bars.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
