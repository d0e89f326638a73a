"""Whether a change leaves training as it was: the loss terms of every step of paired runs, before and after.

Record each method's weighted loss terms for ``--steps`` steps (same seed, same batches, the training callbacks on:
box fits and upsampling), once per tree, then compare the two records:

    git worktree add /tmp/before BASE
    OMP_NUM_THREADS=1 PYTHONPATH=/tmp/before python benchmarks/paired_equality.py record --data DS --out before.json
    OMP_NUM_THREADS=1 python benchmarks/paired_equality.py record --data DS --out after.json
    python benchmarks/paired_equality.py compare before.json after.json --out OUT/paired_equality.md

``compare`` writes, per method and term, the largest absolute and relative difference over the steps and the number
of steps equal to the last digit. The default methods run every timed render: the blur model and the windowed event
loss (``agrinerf``), EvDeblurNeRF's event pairs with learnt thresholds and its rigid kernel and EDI prior
(``evdeblurnerf-lite``), and the thermal camera's rays.
"""

from __future__ import annotations

import json
import math
import random
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Tuple, Union

import numpy as np
import tyro

DEFAULT_METHODS = ("agrinerf", "evdeblurnerf-lite")
SMALL = {"init_resolution": 24, "final_resolution": 40, "upsampling_iters": (6,), "box_fit_iters": (4,),
         "box_fit_rays": 1024, "occupancy_update_iters": (8,)}  # fmt: skip
"""Grids and schedules shrunk so that a few steps pass a box fit, an upsampling and an occupancy update."""


@dataclass
class Record:
    data: Path
    """A processed dataset (agrinerf-process) with events, exposures and thermal frames."""
    out: Path
    """JSON file of the loss terms per method and step."""
    methods: Tuple[str, ...] = DEFAULT_METHODS
    steps: int = 12
    rays_per_batch: int = 256


@dataclass
class Compare:
    before: Path
    after: Path
    out: Path = field(default_factory=lambda: Path("paired_equality.md"))


def record(args: Record) -> None:
    import torch

    from agrinerf_ns.lab.stepper import MethodStepper

    runs: Dict[str, List[Dict[str, float]]] = {}
    for key in args.methods:
        for seeded in (random.seed, np.random.seed, torch.manual_seed):  # as ns-train seeds (the image order too)
            seeded(0)
        overrides = {**SMALL, "event_threshold_learnt": True} if key.startswith("evdeblurnerf") else dict(SMALL)
        stepper = MethodStepper(key, args.data, args.rays_per_batch, model_overrides=overrides, callbacks=True)
        steps = []
        for step in range(args.steps):
            terms = stepper.loss_dict(step)
            steps.append({k: float(v) for k, v in sorted(terms.items())})
            stepper.apply(terms, step)
        runs[key] = steps
        print(key, "last step:", steps[-1])
    args.out.write_text(json.dumps(runs, indent=1))


def compare(args: Compare) -> None:
    before, after = json.loads(args.before.read_text()), json.loads(args.after.read_text())
    lines = [
        "| method | term | steps | equal to the last digit | max abs diff | max rel diff |",
        "|---|---|---|---|---|---|",
    ]
    for method in sorted(set(before) & set(after)):
        terms = sorted({k for step in before[method] for k in step} | {k for step in after[method] for k in step})
        for term in terms:
            pairs = [(b.get(term, math.nan), a.get(term, math.nan)) for b, a in zip(before[method], after[method], strict=True)]  # fmt: skip
            equal = sum(1 for b, a in pairs if b == a)
            abs_diff = max(abs(b - a) for b, a in pairs)
            rel_diff = max(abs(b - a) / max(abs(b), 1e-30) for b, a in pairs)
            lines.append(f"| {method} | {term} | {len(pairs)} | {equal} | {abs_diff:.3g} | {rel_diff:.3g} |")
    text = "\n".join(lines) + "\n"
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(text)
    print(text)


def entrypoint() -> None:
    args: Union[Record, Compare] = tyro.extras.subcommand_cli_from_dict(
        {"record": Record, "compare": Compare}, prog="paired_equality.py"
    )
    record(args) if isinstance(args, Record) else compare(args)


if __name__ == "__main__":
    entrypoint()
