"""Where the view path loses fruit, split between the renders' colours and their geometry: each render folder is
counted three times, on the capture's own frames with the true depth (the ceiling), on the run's colours with the
true depth (`agrinerf_ns.lab.count_oracle.with_true_depth`) and on the run's colours with its rendered depth, each placed
by depth and by rays, with the diagnosis of each (2D recall and precision, lift error). Prints a Markdown table.

    python benchmarks/count_depth_split.py --renders COUNT/renders --raw RAW [--renders ... --raw ...] \
        [--source rgb] [--out FILE.md]

``--renders``: `agrinerf-count` output folders' renders/ (one per run); ``--raw``: each one's synthetic capture.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import List, Optional, Tuple

import numpy as np
import tyro

from agrinerf_ns.count.cluster import ClusterConfig
from agrinerf_ns.count.detectors import DetectorConfig
from agrinerf_ns.count.pipeline import CountConfig
from agrinerf_ns.count.render import load_renders
from agrinerf_ns.count.sources import CountSource
from agrinerf_ns.lab.count_diagnose import diagnose
from agrinerf_ns.lab.count_oracle import oracle_renders, with_true_depth

CASES = ("capture frames, true depth", "run's colours, true depth", "run's colours, rendered depth")


@dataclass
class Args:
    renders: Tuple[Path, ...]
    """Render folders of trained runs (agrinerf-count OUT/renders)."""
    raw: Tuple[Path, ...]
    """The synthetic capture of each, in the same order."""
    source: CountSource = "rgb"
    """What fruit are detected in."""
    out: Optional[Path] = None


def main(args: Args) -> str:
    if len(args.renders) != len(args.raw):
        raise SystemExit("give one --raw per --renders")
    lines = [
        f"Detections on `{args.source}`; F1 and count error at 0.05 m, placed by depth / by rays; 2D recall and "
        "precision of the detections against the true fruit masks; lift error: median distance of a hit's "
        "depth-lifted centre from its fruit's.",
        "",
        "| run | views and depth | F1 by depth | F1 by rays | count error by depth | 2D recall | 2D precision | "
        "lift error (m) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    f1: List[List[float]] = [[] for _ in range(2 * len(CASES))]
    for folder, raw in zip(args.renders, args.raw, strict=True):
        run = load_renders(folder)
        assert run.dataset is not None, f"{folder}: the renders do not name their dataset"
        sets = (oracle_renders(raw, run.dataset, "true"), with_true_depth(run, raw), run)
        for case, renders in enumerate(sets):
            config = CountConfig(detect=DetectorConfig(source=args.source))
            by_depth = diagnose(renders, raw, config)
            by_rays = diagnose(renders, raw, replace(config, cluster=ClusterConfig(triangulate=True)))
            f1[2 * case].append(by_depth["score"]["f1"])
            f1[2 * case + 1].append(by_rays["score"]["f1"])
            lift = by_depth["lift_error_m"]["median"]
            lines.append(
                f"| {folder.parent.name} | {CASES[case]} | {by_depth['score']['f1']:.2f} | "
                f"{by_rays['score']['f1']:.2f} | {by_depth['score']['count_error']:+.0%} | "
                f"{by_depth['2d']['recall']:.2f} | {by_depth['2d']['precision']:.2f} | "
                f"{'-' if lift is None else f'{lift:.3f}'} |"
            )
    lines += ["", "| mean over the runs | F1 by depth | F1 by rays |", "|---|---|---|"]
    for case, name in enumerate(CASES):
        lines.append(f"| {name} | {np.mean(f1[2 * case]):.2f} | {np.mean(f1[2 * case + 1]):.2f} |")
    text = "\n".join(lines) + "\n"
    if args.out is not None:
        args.out.write_text(text)
    return text


if __name__ == "__main__":
    print(main(tyro.cli(Args)))
