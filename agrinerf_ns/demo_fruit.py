"""The end of ``agrinerf-demo``: the fruit of its run counted by ``agrinerf-count`` and scored against the synthetic
capture's true fruit, and the picture that puts the contact sheet beside the count's fruit map."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import List, Optional

import numpy as np


@dataclass
class FruitCount:
    """What ``agrinerf-count`` found in the demo's run, scored against the capture's true fruit."""

    counted: int
    visible: Optional[int]
    """True fruit that the training cameras saw (what the count is scored on)."""
    f1: Optional[float]
    precision: Optional[float]
    recall: Optional[float]
    match_distance_m: Optional[float]
    temperature_c: Optional[List[float]]
    """(min, median, max) of the counted fruits' mean rendered temperature; None without a temperature head."""
    path: str
    """How it counted: count.json's ``path`` (views, field) and, on the view path, the detector's ``source``."""
    folder: str
    command: str
    """The command that counts the same way (``agrinerf-count``)."""


def count_fruit(run_config: Path, raw: Path, out: Path) -> FruitCount:
    """Count the fruit of the trained run as ``agrinerf-count --config RUN --out OUT --truth RAW`` does (its CLI's
    ``main``, in this process: the run is not loaded by a second interpreter) and read its report."""
    import csv

    from agrinerf_ns.count.cli import CountArgs
    from agrinerf_ns.count.cli import main as count_main

    count_main(CountArgs(out=out, config=run_config, truth=raw, overwrite=True))
    report = json.loads((out / "count.json").read_text())
    score = report.get("score") or {}
    with open(out / "fruits.csv", newline="") as handle:
        temps = [float(row["temperature_c"]) for row in csv.DictReader(handle) if row.get("temperature_c")]
    spread = [float(v) for v in np.percentile(temps, [0, 50, 100])] if temps else None
    return FruitCount(
        counted=int(report["fruit"]),
        visible=score.get("visible"),
        f1=score.get("f1"),
        precision=score.get("precision"),
        recall=score.get("recall"),
        match_distance_m=score.get("match_distance"),
        temperature_c=spread,
        path=" ".join(str(v) for v in (report.get("path"), (report.get("detector") or {}).get("source")) if v),
        folder=str(out),
        command=f"agrinerf-count --config {run_config} --out {out} --truth {raw}",
    )


def count_caption(count: FruitCount, lighting: str) -> str:
    """One line of what the count found and how it scored."""
    parts = [f"agrinerf-count found {count.counted} fruit"]
    if count.visible is not None and count.f1 is not None:
        parts.append(
            f"against {count.visible} true fruit the cameras saw: F1 {count.f1:.2f} (precision {count.precision:.2f}, "
            f"recall {count.recall:.2f}, matched within {count.match_distance_m:g} m)"
        )
    if count.temperature_c is not None:
        low, mid, high = count.temperature_c
        parts.append(f"fruit temperatures {low:.1f} / {mid:.1f} / {high:.1f} C (min / median / max)")
    text = ", ".join(parts) + "."
    if lighting == "dark":
        text += " In the dark the count comes from the thermal fruit bodies, placed with the poses (--path bodies)."
    return text


CAPTION_PT = 22
"""Font size of the picture's caption line (the contact sheet's own text is drawn at about this size)."""


def side_by_side(left: Path, right: Path, out: Path, caption: str) -> Path:
    """``left`` (the contact sheet) and ``right`` (the fruit map) at one height in one PNG, a caption line under them;
    written atomically."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from PIL import Image

    with Image.open(left) as first, Image.open(right) as second:
        images = [np.asarray(first.convert("RGB")), np.asarray(second.convert("RGB"))]
    height = max(image.shape[0] for image in images)
    widths = [round(image.shape[1] * height / image.shape[0]) for image in images]
    band, dpi = 4 * CAPTION_PT, 100
    fig_w, fig_h = sum(widths), height + band
    fig = Figure(figsize=(fig_w / dpi, fig_h / dpi), dpi=dpi, facecolor="white")
    FigureCanvasAgg(fig)
    x = 0
    for image, width in zip(images, widths, strict=True):
        axes = fig.add_axes((x / fig_w, band / fig_h, width / fig_w, height / fig_h))
        axes.imshow(image, interpolation="lanczos")
        axes.set_axis_off()
        x += width
    fig.text(12 / fig_w, band / 2 / fig_h, caption, fontsize=CAPTION_PT, va="center")
    tmp = out.with_name(f".{out.name}.{os.getpid()}.tmp")
    fig.savefig(tmp, dpi=dpi, format="png", facecolor="white")
    os.replace(tmp, out)
    return out
