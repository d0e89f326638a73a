"""The count's files: ``fruits.csv``, ``fruits.ply`` (one vertex per fruit, plain binary PLY), ``fruit_map.png`` (the
fruit over a top view of the row) and the score as Markdown."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import numpy as np
from jaxtyping import Float

from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.count.fruit_score import CountScore, Similarity, TruthFruit

CSV_COLUMNS = (
    "id", "x", "y", "z", "x_ns", "y_ns", "z_ns", "diameter", "views", "detections", "temperature_c", "score",
)  # fmt: skip
"""x, y, z and diameter: the dataset's frame and units (``transforms.json``; the capture's odometry world when its
poses were ``given``); x_ns, y_ns, z_ns: Nerfstudio's frame (the dataparser's transform and scale applied)."""
CAPTURE_COLUMNS = ("x_capture", "y_capture", "z_capture", "truth_id")


def write_csv(
    path: Path,
    fruit: Sequence[Fruit],
    ns_centres: Float[np.ndarray, "n 3"],
    capture: Optional[Float[np.ndarray, "n 3"]] = None,
    truth_ids: Optional[Sequence[int]] = None,
) -> None:
    """One row per fruit; with ``capture`` also the centre in the capture's frame and the matched true fruit id (-1:
    none)."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(CSV_COLUMNS + (CAPTURE_COLUMNS if capture is not None else ()))
        for i, f in enumerate(fruit):
            row: List[object] = [i, *_fmt(f.centre), *_fmt(ns_centres[i]), f"{f.diameter:.4f}", f.views, f.detections]
            row += ["" if f.temperature is None else f"{f.temperature:.2f}", f"{f.score:.3f}"]
            if capture is not None:
                row += [*_fmt(capture[i]), -1 if truth_ids is None else truth_ids[i]]
            writer.writerow(row)


def read_csv(path: Path) -> List[Fruit]:
    """The fruit of a ``fruits.csv`` written by :func:`write_csv` (dataset frame); raises ValueError naming the file
    when a column is missing or a value is not a number."""
    fruit = []
    with open(path, newline="") as handle:
        for line, row in enumerate(csv.DictReader(handle), start=2):
            try:
                temperature = row["temperature_c"]
                fruit.append(Fruit(np.array([float(row[k]) for k in "xyz"]), float(row["diameter"]), int(row["views"]),
                                   int(row["detections"]), float(temperature) if temperature else None,
                                   float(row["score"])))  # fmt: skip
            except (KeyError, TypeError, ValueError) as err:
                raise ValueError(f"{path}:{line}: not a fruits.csv row ({err!r})") from err
    return fruit


def _fmt(values: np.ndarray) -> List[str]:
    return [f"{float(v):.4f}" for v in values]


def write_ply(path: Path, fruit: Sequence[Fruit]) -> None:
    """Binary little-endian PLY, a vertex per fruit (dataset frame): x y z, red green blue (by temperature where
    known, else red), diameter, views, temperature (NaN when unknown)."""
    temps = np.array([np.nan if f.temperature is None else f.temperature for f in fruit], dtype=np.float64)
    colours = _temperature_colours(temps)
    header = "\n".join([
        "ply", "format binary_little_endian 1.0", f"element vertex {len(fruit)}",
        "property float x", "property float y", "property float z",
        "property uchar red", "property uchar green", "property uchar blue",
        "property float diameter", "property int views", "property float temperature", "end_header",
    ]) + "\n"  # fmt: skip
    record = np.dtype([
        ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1"),
        ("diameter", "<f4"), ("views", "<i4"), ("temperature", "<f4"),
    ])  # fmt: skip
    data = np.zeros(len(fruit), dtype=record)
    for i, f in enumerate(fruit):
        data[i] = (*f.centre, *colours[i], f.diameter, f.views, temps[i])
    with open(path, "wb") as handle:
        handle.write(header.encode("ascii"))
        handle.write(data.tobytes())


def _temperature_colours(temps: np.ndarray) -> np.ndarray:
    from matplotlib import colormaps

    out = np.tile(np.array([220, 30, 30], np.uint8), (len(temps), 1))
    known = np.isfinite(temps)
    if known.any():
        lo, hi = float(temps[known].min()), float(temps[known].max())
        unit = (temps[known] - lo) / max(hi - lo, 1e-6)
        out[known] = (colormaps["turbo"](unit)[:, :3] * 255).round().astype(np.uint8)
    return out


def draw_map(
    path: Path,
    fruit: Sequence[Fruit],
    surface: Float[np.ndarray, "m 3"],
    title: str,
    truth: Optional[TruthFruit] = None,
    visible: Optional[np.ndarray] = None,
    to_capture: Optional[Similarity] = None,
    cameras: Optional[Float[np.ndarray, "k 3"]] = None,
) -> None:
    """Top view (x right, y up) of the rendered surface's mean height (grey, lighter is higher) with the counted fruit (discs at their diameter,
    coloured by temperature where known) and, when given, the true fruit (rings: visible ones green, the others
    grey); everything in the capture's frame when ``to_capture`` is given, else the dataset's."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PatchCollection
    from matplotlib.patches import Circle

    to_frame = to_capture.apply if to_capture is not None else (lambda p: np.asarray(p, np.float64).reshape(-1, 3))
    scale = to_capture.scale if to_capture is not None else 1.0
    centres = to_frame(np.stack([f.centre for f in fruit])) if fruit else np.zeros((0, 3))
    ground = to_frame(surface) if len(surface) else np.zeros((0, 3))
    extent_points = [centres[:, :2]]
    if truth is not None:
        extent_points.append(truth.centres[visible if visible is not None else slice(None), :2])
    if cameras is not None and len(cameras):
        extent_points.append(to_frame(cameras)[:, :2])
    pts = np.concatenate([p for p in extent_points if len(p)] or [np.zeros((1, 2))])
    lo, hi = pts.min(0) - 0.5, pts.max(0) + 0.5
    width = float(hi[0] - lo[0])
    height = float(hi[1] - lo[1])
    fig_w = 12.0
    fig, ax = plt.subplots(figsize=(fig_w, max(3.0, min(9.0, fig_w * height / max(width, 1e-6)) + 1.2)))
    if len(ground):
        inside = (ground[:, 0] >= lo[0]) & (ground[:, 0] <= hi[0]) & (ground[:, 1] >= lo[1]) & (ground[:, 1] <= hi[1])
        g = ground[inside]
        bins = (max(10, int(width / 0.03)), max(10, int(height / 0.03)))
        top, xe, ye = np.histogram2d(g[:, 0], g[:, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]],
                                     weights=g[:, 2])  # fmt: skip
        counts, _, _ = np.histogram2d(g[:, 0], g[:, 1], bins=bins, range=[[lo[0], hi[0]], [lo[1], hi[1]]])
        mean_z = np.where(counts > 0, top / np.maximum(counts, 1), np.nan)
        ax.imshow(mean_z.T, origin="lower", extent=(lo[0], hi[0], lo[1], hi[1]), cmap="gray",
                  interpolation="nearest", alpha=0.8)  # fmt: skip
    if truth is not None:
        vis = np.ones(len(truth.ids), bool) if visible is None else visible
        for keep, colour, label in (
            (~vis, "0.6", "true fruit, not visible"),
            (vis, "limegreen", "true fruit, visible"),
        ):
            rings = [
                Circle(tuple(c[:2]), d / 2) for c, d in zip(truth.centres[keep], truth.diameters[keep], strict=True)
            ]
            ax.add_collection(PatchCollection(rings, facecolor="none", edgecolor=colour, linewidth=1.0, label=label))
    temps = np.array([np.nan if f.temperature is None else f.temperature for f in fruit])
    discs = [Circle(tuple(c[:2]), max(f.diameter * scale, 0.01) / 2) for c, f in zip(centres, fruit, strict=True)]
    collection = PatchCollection(discs, edgecolor="black", linewidth=0.4, alpha=0.9, label="counted fruit")
    if fruit and np.isfinite(temps).all():
        collection.set_array(temps)
        collection.set_cmap("turbo")
        fig.colorbar(collection, ax=ax, label="mean rendered temperature (C)", fraction=0.025, pad=0.01)
    else:
        collection.set_facecolor("red")
    ax.add_collection(collection)
    if cameras is not None and len(cameras):
        cams = to_frame(cameras)
        ax.plot(cams[:, 0], cams[:, 1], ".", color="tab:blue", markersize=3, label="cameras")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal")
    ax.set_xlabel("x (capture frame)" if to_capture is not None else "x (dataset frame)")
    ax.set_ylabel("y")
    ax.set_title(title, fontsize=10)
    ax.legend(loc="upper right", fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def score_markdown(
    score: CountScore, settings: Dict[str, object], tiers: Optional[Dict[str, Dict[str, Dict[str, float]]]] = None
) -> str:
    """The score as a small Markdown table with the settings it was computed at; with ``tiers``
    (``fruit_score.tier_scores``) first a table of every tier of truth at every match distance."""

    def fmt(value: object) -> str:
        if isinstance(value, float):
            return "nan" if math.isnan(value) else f"{value:.3f}"
        return str(value)

    rows = [f"| {key} | {fmt(value)} |" for key, value in score.as_dict().items()]
    notes = [f"- {key}: {value}" for key, value in settings.items()]
    return "\n".join([*tier_markdown(tiers or {}), "| measure | value |", "|---|---|", *rows, "", *notes]) + "\n"


def tier_markdown(tiers: Dict[str, Dict[str, Dict[str, float]]]) -> List[str]:
    """Lines of a Markdown table: per tier of truth its fruit, F1 (precision / recall) at each match distance and the
    count error (empty without tiers)."""
    if not tiers:
        return []
    distances = list(next(iter(tiers.values())))
    lines = ["| truth | fruit | " + " | ".join(f"F1 (P / R) at {d} m" for d in distances) + " | count error |",
             "|---|---|" + "---|" * len(distances) + "---|"]  # fmt: skip
    for tier, by_distance in tiers.items():
        cells = [f"{s['f1']:.2f} ({s['precision']:.2f} / {s['recall']:.2f})" for s in by_distance.values()]
        first = next(iter(by_distance.values()))
        error = "nan" if math.isnan(first["count_error"]) else f"{first['count_error']:+.0%}"
        lines.append(f"| {tier.replace('_', ' ')} | {int(first['truth'])} | " + " | ".join(cells) + f" | {error} |")
    return [*lines, ""]
