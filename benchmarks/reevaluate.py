"""Evaluate the finished runs of an ``agrinerf-bench`` folder again with this checkout's metrics.

    PYTHONPATH=OTHER_CHECKOUT python benchmarks/reevaluate.py --bench OUT --out OUT/reevaluated.csv

Each run's checkpoints load with whatever ``agrinerf_ns`` the interpreter imports (so runs made by another checkout
load with its model code, through PYTHONPATH), while the metrics come from this file's checkout
(``agrinerf_ns/checkpoint_eval.py`` beside it, loaded by path): a metric added after the runs were made (e.g.
``psnr_fruit``) is then measured for them too. Writes the results rows (``agrinerf-bench``'s columns) to ``--out``.
"""

from __future__ import annotations

import csv
import importlib.util
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import tyro

from agrinerf_ns.lab import results
from agrinerf_ns.lab.layout import BenchLayout, run_config, scene_folders
from agrinerf_ns.lab.methods import METHODS
from agrinerf_ns.ns_commands import checkpoints

EVALUATE = Path(__file__).resolve().parents[1] / "agrinerf_ns" / "checkpoint_eval.py"


@dataclass
class Args:
    bench: Path
    """An ``agrinerf-bench --out`` folder."""
    out: Path
    """CSV of the re-evaluated rows."""
    last_only: bool = True
    """Only each run's last checkpoint."""
    max_views: Optional[int] = None
    """Held-out views rendered per checkpoint, evenly spaced, as the bench profile's ``eval_views`` (None: all)."""


def main(args: Args) -> None:
    spec = importlib.util.spec_from_file_location("agrinerf_reevaluate", EVALUATE)
    assert spec is not None and spec.loader is not None
    evaluate = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(evaluate)
    layout = BenchLayout(args.bench)
    rows = []
    for row in results.read_rows(layout.results_csv):
        scene, key = row["scene"], row["method"]
        method = METHODS[key]
        config = run_config(layout.runs, scene, key, method.ns_method)
        steps = checkpoints(config)
        wanted = [steps[-1]] if args.last_only and steps else steps
        if not any(step + 1 == int(row["step"]) for step, _ in wanted):  # a row of a checkpoint not asked for
            continue
        raw = scene_folders(layout.scenes, scene).raw
        truth = evaluate.TruthImages(raw) if (raw / "truth" / "rgb_clean").is_dir() else None
        step = int(row["step"]) - 1
        metrics = evaluate.evaluate_checkpoint(config, step, method.supervision, truth, max_views=args.max_views)
        rows.append({**row, **metrics})
    args.out.parent.mkdir(parents=True, exist_ok=True)
    columns = list(dict.fromkeys(k for row in rows for k in row))  # every key, first seen first (both checkouts')
    with open(args.out, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=columns)
        writer.writeheader()
        writer.writerows(rows)
    print(f"{len(rows)} rows -> {args.out}")


if __name__ == "__main__":
    main(tyro.cli(Args))
