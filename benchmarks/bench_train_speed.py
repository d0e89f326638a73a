"""Seconds per training step and peak memory of several ``ns-train`` methods, side by side, repeated and interleaved.

    python benchmarks/bench_train_speed.py --data outputs/bench/scenes/orchard-dark/data --out outputs/speed \
        [--methods agrinerf tensorf agrinerf-lite] [--steps 90] [--repeats 3]

Each repeat trains every method once (the order rotates from one repeat to the next, so no method always runs first
or last) with the same rays per batch on the same processed dataset. Seconds per step are steady-state: the wall
time between the first and the last checkpoint over the steps between them (start-up and the first iterations left
out). Peak memory is the ``ns-train`` process tree's, sampled from ``/proc``. Writes ``OUT/speed.csv`` (one row per
run) and ``OUT/speed.md``: the median per method, and per repeat the ratio of every method to the first one, so that
machine noise common to a repeat cancels.
"""

from __future__ import annotations

import csv
import statistics
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import tyro

from agrinerf_ns.lab.methods import METHODS
from agrinerf_ns.machine import device_name
from agrinerf_ns.ns_commands import ns_train
from agrinerf_ns.run_order import rotated


@dataclass
class Args:
    data: Path
    """A processed dataset (``transforms.json``), e.g. an ``agrinerf-bench`` scene's ``data`` folder."""
    out: Path = Path("outputs/speed")
    """Where runs, ``speed.csv`` and ``speed.md`` go."""
    methods: Tuple[str, ...] = ("agrinerf", "tensorf", "agrinerf-lite")
    """``agrinerf-bench`` method keys; ratios are to the first."""
    steps: int = 90
    """Training steps per run (checkpoints at a third, two thirds and the end)."""
    repeats: int = 3
    """Runs per method."""
    rays_per_batch: int = 1024
    """Rays per batch, the same for every method."""


def main(args: Args) -> None:
    unknown = [m for m in args.methods if m not in METHODS]
    if unknown:
        raise SystemExit(f"unknown methods {unknown}; choose from {sorted(METHODS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    device = device_name()
    rows: List[Dict[str, object]] = []
    for repeat in range(args.repeats):
        for key in rotated(args.methods, repeat):
            method = METHODS[key]
            run = ns_train(
                method.ns_method, args.data / method.data_file, args.out / "runs" / f"r{repeat}", key,
                max_steps=args.steps, rays_per_batch=args.rays_per_batch, dataparser_args=method.dataparser_args,
                steps_per_save=max(1, args.steps // 3),
            )  # fmt: skip
            rows.append({"repeat": repeat, "method": key, "label": method.label, "s_per_step": run.s_per_step,
                         "profiler_s_per_step": run.profiler_s_per_step, "peak_rss_mb": run.peak_rss_mb,
                         "wall_s": run.wall_s, "device": device})  # fmt: skip
            print(f"repeat {repeat} {key}: {run.s_per_step:.3f} s/step, {run.peak_rss_mb:.0f} MiB", flush=True)
    with open(args.out / "speed.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    (args.out / "speed.md").write_text(report(rows, args, device))
    print((args.out / "speed.md").read_text())


def report(rows: List[Dict[str, object]], args: Args, device: str) -> str:
    """Medians per method and per-repeat ratios to the first method."""
    base = args.methods[0]
    lines = [
        "# Training speed and memory, side by side",
        "",
        f"Command: `python benchmarks/bench_train_speed.py --data {args.data} --out {args.out} --methods "
        f"{' '.join(args.methods)} --steps {args.steps} --repeats {args.repeats}`",
        f"Machine: {device}. {args.rays_per_batch} rays per batch; steady-state s/step (between the first and last "
        "checkpoint); peak RSS of the `ns-train` process tree.",
        "",
        f"| method | median s/step | runs (s/step) | median ratio to {METHODS[base].label} | median peak RSS MiB |",
        "|---|---|---|---|---|",
    ]
    for key in args.methods:
        mine = [r for r in rows if r["method"] == key]
        ratios = []
        for r in mine:
            ref = [b for b in rows if b["method"] == base and b["repeat"] == r["repeat"]]
            if ref:
                ratios.append(float(r["s_per_step"]) / float(ref[0]["s_per_step"]))  # type: ignore[arg-type]
        speeds = [float(r["s_per_step"]) for r in mine]  # type: ignore[arg-type]
        lines.append(
            f"| {METHODS[key].label} | {statistics.median(speeds):.3f} | "
            f"{', '.join(f'{s:.3f}' for s in speeds)} | {statistics.median(ratios):.2f} | "
            f"{statistics.median(float(r['peak_rss_mb']) for r in mine):.0f} |"  # type: ignore[arg-type]
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(tyro.cli(Args))
