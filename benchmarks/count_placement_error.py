"""Where counted fruit lie against their true fruit, along the rig's view and across it (#60).

``python benchmarks/count_placement_error.py --counts LABEL=COUNT_DIR... --out FILE.md`` reads each
``agrinerf-count`` folder's ``fruits.csv`` (written with ``--truth``: each fruit's centre in the capture's frame) and
the capture's ``truth/fruits.json`` (found from the folder's ``count.json``), pairs every counted fruit with its
nearest true fruit within ``--within`` metres, and writes per folder: the pairs, the median distance, and the mean and
standard deviation of the offset along the capture's axes (the synthetic rig drives along x and looks along y, so y
is the depth from the cameras). A scatter much wider along y than across it is depth error of the placement.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import List

import numpy as np
import tyro
from jaxtyping import Float

from agrinerf_ns.count.fruit_score import read_truth_fruit
from agrinerf_ns.count.write import CAPTURE_COLUMNS


@dataclass
class PlacementArgs:
    counts: List[str] = field(default_factory=list)
    """LABEL=FOLDER: agrinerf-count output folders written with --truth."""
    out: Path = Path("placement.md")
    """The table to write."""
    within: float = 0.15
    """A counted fruit is paired with its nearest true fruit when that lies within this distance (m)."""


def capture_centres(folder: Path) -> Float[np.ndarray, "n 3"]:
    """The counted fruit's centres in the capture's frame (``fruits.csv``'s capture columns)."""
    columns = CAPTURE_COLUMNS[:3]
    with open(folder / "fruits.csv", newline="") as handle:
        rows = list(csv.DictReader(handle))
    if rows and columns[0] not in rows[0]:
        raise ValueError(f"{folder / 'fruits.csv'}: no capture-frame columns (count it with --truth)")
    return np.array([[float(r[k]) for k in columns] for r in rows]).reshape(-1, 3)


def true_centres(folder: Path) -> Float[np.ndarray, "m 3"]:
    """The centres of the true fruit of the capture the count was scored against."""
    return read_truth_fruit(Path(json.loads((folder / "count.json").read_text())["truth"])).centres


def offsets(counted: np.ndarray, truth: np.ndarray, within: float) -> np.ndarray:
    """Counted minus nearest true centre, for the counted fruit with a true one within ``within``."""
    if len(counted) == 0 or len(truth) == 0:
        return np.zeros((0, 3))
    gaps = np.linalg.norm(counted[:, None] - truth[None], axis=-1)
    near = gaps.min(axis=1) <= within
    return (counted - truth[gaps.argmin(axis=1)])[near]


def main(args: PlacementArgs) -> None:
    lines = [
        f"| count | counted | paired within {args.within:g} m | median distance (m) | mean offset x / y / z (m) "
        "| sd x / y / z (m) |",
        "|---|---|---|---|---|---|",
    ]
    for item in args.counts:
        label, _, folder = item.partition("=")
        counted = capture_centres(Path(folder))
        off = offsets(counted, true_centres(Path(folder)), args.within)
        if len(off) == 0:
            lines.append(f"| {label} | {len(counted)} | 0 | - | - | - |")
            continue
        mean, sd = off.mean(axis=0), off.std(axis=0)
        lines.append(
            f"| {label} | {len(counted)} | {len(off)} | {np.median(np.linalg.norm(off, axis=1)):.3f} | "
            + " / ".join(f"{v:+.3f}" for v in mean) + " | " + " / ".join(f"{v:.3f}" for v in sd) + " |"
        )  # fmt: skip
    args.out.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(tyro.cli(PlacementArgs))
