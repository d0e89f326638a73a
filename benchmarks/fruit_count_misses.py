"""Where the fruit channel's count loses fruit, against a synthetic capture's truth (#49).

``python benchmarks/fruit_count_misses.py --renders RUN_RENDERS --truth-depth ORACLE_RENDERS --raw RAW --count COUNT``

- **By how well a fruit is seen:** the visible true fruit binned by their pixels in their second-best training view
  (a 3D count needs two), and how many of each bin the count ``COUNT`` (an ``agrinerf-count`` folder of those
  renders) matched.
- **Geometry at the fruit:** over the true fruit pixels of every view, the rendered depth's error against the true
  depth (``ORACLE_RENDERS``: ``python -m agrinerf_ns.lab.count_oracle``, whose depth is the truth's), split by whether
  the fruit channel found the pixel (probability >= 0.5). A missed pixel whose depth is also wrong is a fruit the
  geometry did not resolve; one whose depth is right is one the fruit head did not label.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List

import numpy as np
import tyro

from agrinerf_ns.count.render import load_renders
from agrinerf_ns.lab.count_diagnose import view_fruit_ids

BINS = ((3, 50), (50, 200), (200, 800), (800, 10**9))
"""Pixels of a fruit in its second-best training view."""


@dataclass
class MissArgs:
    renders: Path
    """A trained run's render folder (``agrinerf-count --config ... --out C``: ``C/renders``)."""
    truth_depth: Path
    """The oracle render folder of the same dataset (its depth is the true depth)."""
    raw: Path
    """The synthetic capture."""
    count: Path
    """The agrinerf-count folder (with --truth) of ``renders`` on the fruit channel."""


def main(args: MissArgs) -> Dict[str, object]:
    run, oracle = load_renders(args.renders), load_renders(args.truth_depth)
    truth_views = {v.file_path: v for v in oracle.views}
    areas: Dict[int, List[int]] = {}
    errors: Dict[str, List[np.ndarray]] = {"found": [], "missed": []}
    for view, ids in zip(run.views, view_fruit_ids(args.raw, run), strict=True):
        if view.fruit is None:
            raise SystemExit(f"{args.renders}: view {view.name} has no fruit channel (a run without a fruit head)")
        fruit = ids >= 0
        error = np.abs(view.depth / run.frame.scale - truth_views[view.file_path].depth)
        errors["found"].append(error[fruit & (view.fruit >= 0.5)])
        errors["missed"].append(error[fruit & (view.fruit < 0.5)])
        if view.split == "train":
            values, counts = np.unique(ids[fruit], return_counts=True)
            for value, count in zip(values, counts, strict=True):
                areas.setdefault(int(value), []).append(int(count))
    with (args.count / "fruits.csv").open() as handle:
        matched = {int(row["truth_id"]) for row in csv.DictReader(handle) if int(row["truth_id"]) >= 0}
    report: Dict[str, object] = {}
    second = {fruit: sorted(a, reverse=True)[1] if len(a) > 1 else 0 for fruit, a in areas.items() if max(a) >= 3}
    for low, high in BINS:
        members = [f for f, a in second.items() if low <= a < high]
        report[f"second view {low}-{high} px"] = f"{sum(f in matched for f in members)} of {len(members)} counted"
    members = [f for f, a in second.items() if a < 3]
    report["seen in one view only"] = f"{sum(f in matched for f in members)} of {len(members)} counted"
    for name, parts in errors.items():
        e = np.concatenate(parts)
        report[f"depth error at {name} fruit pixels"] = (
            f"{e.size} px, median {np.median(e):.3f} m, within 5 cm {np.mean(e < 0.05):.2f}, "
            f"within 15 cm {np.mean(e < 0.15):.2f}"
        )
    for key, value in report.items():
        print(f"{key}: {value}")
    return report


if __name__ == "__main__":
    main(tyro.cli(MissArgs))
