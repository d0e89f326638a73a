"""The row join's distance against the measured placement error: splits and wrong joins on the true fruit of a row.

    python benchmarks/row_join_distance.py --out OUT

Every true fruit of the front row of a synthetic scene (tuning seed 0, orchard and garden, ``make_scene`` of
``agrinerf-synth``) is placed twice, once per segment, each copy off its true centre by an independent Gaussian error
per axis with the standard deviation measured on the dark counts' tuning seeds (the largest per axis of the scene's
rows in ``results/fruit-count-dark/tuning/placement.md``, read from that file), and both segments see every fruit (the
worst case: the whole row in the overlap). The two copies are joined by the row's own rule
(:func:`agrinerf_ns.row.join.join_fruit`) at each distance. A true fruit is *split* when its copies stay apart (a
double count), and *lost* when neither copy is kept: both were joined to copies of other fruit (an undercount). Writes
``OUT/join_distance.csv`` (scene, distance, draws, fruit, the placement error used, split and lost rates: mean and
95th percentile over the draws) and prints the table.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import tyro

from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.row.join import join_fruit
from agrinerf_ns.row.segments import Segment
from agrinerf_ns.synth import SynthConfig
from agrinerf_ns.synth.capture import make_scene

PLACEMENT = Path(__file__).resolve().parents[1] / "results" / "fruit-count-dark" / "tuning" / "placement.md"


@dataclass
class Args:
    out: Path
    """Output folder."""
    distances: Tuple[float, ...] = (0.05, 0.10, 0.15, 0.20, 0.25, 0.30, 0.40)
    """Join distances tried (metres)."""
    draws: int = 50
    """Random placements per scene and distance."""
    views: int = 48
    """Frames of the synthetic row (its length: the front-row fruit along it)."""
    seed: int = 0


def placement_sd(path: Path = PLACEMENT) -> Dict[str, np.ndarray]:
    """Per scene, the largest standard deviation per axis (x, y, z) of its rows in the placement table."""
    sd: Dict[str, np.ndarray] = {}
    for line in path.read_text().splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) < 6 or not re.match(r"[a-z]+_dark_\d+", cells[0]):
            continue
        scene = cells[0].split("_")[0]
        values = np.array([float(v) for v in cells[5].split("/")])
        sd[scene] = np.maximum(sd.get(scene, values), values)
    return sd


def front_row(scene: str, views: int) -> np.ndarray:
    """Centres of the true fruit of the row the rig drives (y within a metre of it) along its path."""
    config = SynthConfig.tiny(scene=scene, views=views)
    built, rig = make_scene(config)
    length = config.speed * (views - 1) / config.fps
    centres = np.array([f["center"] for f in built.fruits], np.float64)
    keep = (np.abs(centres[:, 1]) < 1.0) & (centres[:, 0] >= rig.start_x) & (centres[:, 0] <= rig.start_x + length)
    return centres[keep]


def one_draw(truth: np.ndarray, sd: np.ndarray, distance: float, rng: np.random.Generator) -> Tuple[float, float]:
    """(split rate, lost rate) of one placement of every fruit by two segments that both see the whole row."""
    n = len(truth)
    copies = [truth + rng.normal(0.0, sd, truth.shape) for _ in range(2)]
    per_segment = [[Fruit(c, 0.08, 5, 5, None, 1.0) for c in placed] for placed in copies]
    x = np.linspace(truth[:, 0].min() - 1.0, truth[:, 0].max() + 1.0, 100)
    cameras = np.stack([x, np.full_like(x, -2.8), np.full_like(x, 1.4)], axis=1)
    segments = [Segment(0, 0, 100), Segment(1, 0, 100)]
    joined = join_fruit(per_segment, segments, cameras, distance)
    origin = {(s, id(f)): k for s in range(2) for k, f in enumerate(per_segment[s])}
    kept_of: Dict[int, List[int]] = {}
    for item in joined.fruit:
        kept_of.setdefault(origin[(item.segment, id(item.fruit))], []).append(item.segment)
    split = sum(1 for k in range(n) if len(kept_of.get(k, [])) == 2)
    lost = sum(1 for k in range(n) if k not in kept_of)
    return split / n, lost / n


def main(args: Args) -> List[Dict[str, object]]:
    sd = placement_sd()
    rng = np.random.default_rng(args.seed)
    rows: List[Dict[str, object]] = []
    for scene in ("orchard", "garden"):
        truth = front_row(scene, args.views)
        for distance in args.distances:
            draws = np.array([one_draw(truth, sd[scene], distance, rng) for _ in range(args.draws)])
            rows.append({"scene": scene, "distance_m": distance, "draws": args.draws, "fruit": len(truth),
                         "sd_x": sd[scene][0], "sd_y": sd[scene][1], "sd_z": sd[scene][2],
                         "split_mean": draws[:, 0].mean(), "split_p95": np.percentile(draws[:, 0], 95),
                         "lost_mean": draws[:, 1].mean(),
                         "lost_p95": np.percentile(draws[:, 1], 95)})  # fmt: skip
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "join_distance.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        for row in rows:
            writer.writerow({k: f"{v:.4f}" if isinstance(v, float) else v for k, v in row.items()})
    print("| scene | distance (m) | fruit | split: mean / p95 | lost: mean / p95 |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['scene']} | {r['distance_m']:.2f} | {r['fruit']} | {100 * r['split_mean']:.1f}% / "
              f"{100 * r['split_p95']:.1f}% | {100 * r['lost_mean']:.1f}% / {100 * r['lost_p95']:.1f}% |")  # fmt: skip
    return rows


if __name__ == "__main__":
    main(tyro.cli(Args))
