"""Seconds per training step of several methods in one process, one step of each in turn.

    python benchmarks/bench_step_interleaved.py --data outputs/bench/scenes/orchard-dark/data \
        --out outputs/step-speed [--methods agrinerf tensorf] [--steps 40] [--warmup 3]

`bench_train_speed.py` times whole ``ns-train`` runs, minutes apart, so a noisy machine moves one method's figure and
not the other's. Here every method's pipeline (Nerfstudio's own, built from its registered method config, with the
same rays per batch) lives in one process and the methods take training steps in turn (the order rotates every
round), so they share the machine's state step by step; the paired ratio of each round is then close to what a quiet
machine would give. A step is what Nerfstudio's trainer runs per iteration: next batch, forward, loss, backward,
optimizer step (no callbacks: no upsampling within the run). Writes ``OUT/step_speed.csv`` (every step) and
``OUT/step_speed.md`` (medians, quartiles, median paired ratio to the first method).
"""

from __future__ import annotations

import csv
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import torch
import tyro

from agrinerf_ns.bench.methods import METHODS
from agrinerf_ns.bench.stepper import MethodStepper
from agrinerf_ns.machine import device_name
from agrinerf_ns.run_order import rotated


@dataclass
class Args:
    data: Path
    """A processed dataset (``transforms.json``), e.g. an ``agrinerf-bench`` scene's ``data`` folder."""
    out: Path = Path("outputs/step-speed")
    """Where ``step_speed.csv`` and ``step_speed.md`` go."""
    methods: Tuple[str, ...] = ("agrinerf", "tensorf")
    """``agrinerf-bench`` method keys; ratios are to the first."""
    steps: int = 40
    """Timed rounds (one step of every method per round)."""
    warmup: int = 3
    """Untimed rounds first (TensoRF's first steps are much slower)."""
    rays_per_batch: int = 1024
    """Rays per batch, the same for every method."""
    seed: int = 0


def main(args: Args) -> None:
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown methods {unknown}; choose from {sorted(METHODS)}")
    torch.manual_seed(args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    steppers = {key: MethodStepper(key, args.data, args.rays_per_batch) for key in args.methods}
    rows: List[Dict[str, object]] = []
    for round_ in range(args.warmup + args.steps):
        for key in rotated(args.methods, round_):
            seconds = steppers[key].step(round_)
            if round_ >= args.warmup:
                rows.append({"round": round_ - args.warmup, "method": key, "seconds": seconds})
    with open(args.out / "step_speed.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["round", "method", "seconds"])
        writer.writeheader()
        writer.writerows(rows)
    (args.out / "step_speed.md").write_text(report(rows, args, device_name()))
    print((args.out / "step_speed.md").read_text())


def report(rows: List[Dict[str, object]], args: Args, device: str) -> str:
    """Median and quartiles of s/step per method, and the median of the per-round ratios to the first method."""
    times: Dict[str, List[float]] = {k: [] for k in args.methods}
    for r in rows:
        times[str(r["method"])].append(float(r["seconds"]))  # type: ignore[arg-type]
    base = times[args.methods[0]]
    lines = [
        "# Training step time, methods interleaved in one process",
        "",
        f"Command: `python benchmarks/bench_step_interleaved.py --data {args.data} --out {args.out} --methods "
        f"{' '.join(args.methods)} --steps {args.steps} --warmup {args.warmup}`",
        f"Machine: {device}. {args.rays_per_batch} rays per batch; {args.steps} timed rounds after {args.warmup} "
        "untimed; in each round every method takes one step (rotating order).",
        "",
        f"| method | median s/step | quartiles | median per-round ratio to {METHODS[args.methods[0]].label} |",
        "|---|---|---|---|",
    ]
    for key in args.methods:
        mine = times[key]
        q1, _, q3 = statistics.quantiles(mine, n=4) if len(mine) > 1 else (mine[0], mine[0], mine[0])
        ratio = statistics.median(m / b for m, b in zip(mine, base, strict=True))
        lines.append(f"| {METHODS[key].label} | {statistics.median(mine):.3f} | {q1:.3f} - {q3:.3f} | {ratio:.3f} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(tyro.cli(Args))
