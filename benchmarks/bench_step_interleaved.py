"""Seconds per training step of several runs, one step of each in turn, each run in a process of its own.

    python benchmarks/bench_step_interleaved.py --data outputs/bench/scenes/garden-bright/data \
        --out outputs/step-speed --runs agrinerf@7000 before:agrinerf@7000 agrinerf tensorf \
        --trees before=/tmp/agrinerf-before [--steps 20] [--warmup 3]

A run is ``[TREE:]METHOD[@STEP][%FIELD=VALUE...]``: an ``agrinerf-bench`` method key, timed at the grids and with the terms of
training step STEP (default 0, the grids a preset starts with; e.g. ``agrinerf@7000``: the paper preset at its final
300^3 grids, blur model and event loss on as from step 1200), from the checkout TREE (a name given in ``--trees``;
default this one, as installed; a TREE is imported through a layout of links under OUT/trees), so that a change can be timed against the code before it in one run, with model config fields set
(``%event_supervision="off"``: no event loss; VALUE is JSON). Every run's pipeline
(Nerfstudio's own, built from its registered method config, the same rays per batch) lives in a worker process
(``benchmarks/step_worker.py``); the driver asks one worker at a time for one step, rotating the order every round,
so the runs share the machine's state step by step and the paired ratio of each round is close to what a quiet
machine would give. A step is what Nerfstudio's trainer runs per iteration: next batch, forward, loss, backward,
optimizer step (no callbacks). The fields are as initialised, not trained. Writes ``OUT/step_speed.csv`` (every step)
and ``OUT/step_speed.md`` (medians, quartiles, median paired ratio to the first run).
"""

from __future__ import annotations

import csv
import hashlib
import json
import os
import statistics
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, NamedTuple, Optional, Tuple

import tyro

from agrinerf_ns.lab.methods import METHODS, field_values
from agrinerf_ns.machine import device_name
from agrinerf_ns.run_order import rotated
from agrinerf_ns.source_tree import link_installed_layout

WORKER = Path(__file__).with_name("step_worker.py")


@dataclass
class Args:
    data: Path
    """A processed dataset (``transforms.json``), e.g. an ``agrinerf-bench`` scene's ``data`` folder."""
    out: Path = Path("outputs/step-speed")
    """Where ``step_speed.csv`` and ``step_speed.md`` go."""
    runs: Tuple[str, ...] = ("agrinerf", "tensorf")
    """``[TREE:]METHOD[@STEP][%FIELD=VALUE...]`` (see the module docstring); ratios are to the first."""
    trees: Tuple[str, ...] = ()
    """``NAME=PATH`` checkouts the runs may name (e.g. ``before=/tmp/snapshot``)."""
    steps: int = 20
    """Timed rounds (one step of every run per round)."""
    warmup: int = 3
    """Untimed rounds first (TensoRF's first steps are much slower)."""
    rays_per_batch: int = 1024
    """Rays per batch, the same for every run."""
    seed: int = 0


class Run(NamedTuple):
    label: str
    method: str
    at_step: int
    tree: Optional[Path]
    overrides: Dict[str, object]


def parse_runs(runs: Tuple[str, ...], trees: Tuple[str, ...]) -> List[Run]:
    """The runs of ``--runs``; raises SystemExit naming an unknown method or tree."""
    named = dict(t.split("=", 1) for t in trees)
    parsed = []
    for text in runs:
        head, *fields = text.split("%")
        tree, _, rest = head.rpartition(":")
        method, _, step = rest.partition("@")
        try:  # the fields are checked by the run's own checkout, which may have others than this one
            overrides = field_values(text, fields)
        except KeyError as err:
            raise SystemExit(f"run {err.args[0]}") from None
        if method not in METHODS:
            raise SystemExit(f"run {text!r}: unknown method {method!r}; choose from {sorted(METHODS)}")
        if tree and tree not in named:
            raise SystemExit(f"run {text!r}: tree {tree!r} is not in --trees {list(named)}")
        parsed.append(Run(text, method, int(step or 0), Path(named[tree]).resolve() if tree else None, overrides))
    return parsed


class Worker:
    """A `step_worker.py` process holding one run's pipeline."""

    def __init__(self, run: Run, args: Args) -> None:
        env = dict(os.environ)
        if run.tree is not None:  # import that checkout's package, laid out as installed (dataparsers/ inside it)
            name = hashlib.sha1(str(run.tree).encode()).hexdigest()[:12]
            layout = link_installed_layout(run.tree, args.out / "trees" / name)
            env["PYTHONPATH"] = os.pathsep.join([str(layout), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
        command = [sys.executable, str(WORKER), run.method, str(args.data), str(args.rays_per_batch),
                   str(run.at_step), str(args.seed), json.dumps(run.overrides)]  # fmt: skip
        self.process = subprocess.Popen(command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env)
        self.info = json.loads(self._read_line(run, prefix="READY "))
        self.run = run

    def _read_line(self, run: Run, prefix: str = "") -> str:
        assert self.process.stdout is not None
        while True:
            line = self.process.stdout.readline()
            if not line:
                raise RuntimeError(f"step worker of {run.label!r} exited (code {self.process.wait()})")
            if line.startswith(prefix):
                return line[len(prefix) :].strip()

    def step(self, step: int) -> float:
        assert self.process.stdin is not None
        self.process.stdin.write(f"STEP {step}\n")
        self.process.stdin.flush()
        return float(self._read_line(self.run, prefix="SECONDS "))

    def close(self) -> None:
        if self.process.stdin is not None:
            self.process.stdin.close()
        self.process.wait(timeout=60)


def main(args: Args) -> None:
    runs = parse_runs(args.runs, args.trees)
    args.out.mkdir(parents=True, exist_ok=True)
    workers: Dict[str, Worker] = {}
    try:
        for run in runs:  # one at a time: each builds its pipeline alone
            workers[run.label] = Worker(run, args)
        rows: List[Dict[str, object]] = []
        labels = tuple(r.label for r in runs)
        for round_ in range(args.warmup + args.steps):
            for label in rotated(labels, round_):
                seconds = workers[label].step(round_)
                if round_ >= args.warmup:
                    rows.append({"round": round_ - args.warmup, "run": label, "seconds": seconds})
    finally:
        for worker in workers.values():
            worker.close()
    with open(args.out / "step_speed.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["round", "run", "seconds"])
        writer.writeheader()
        writer.writerows(rows)
    info = {label: w.info for label, w in workers.items()}
    (args.out / "step_speed.md").write_text(report(rows, args, runs, info, device_name()))
    print((args.out / "step_speed.md").read_text())


def report(rows: List[Dict[str, object]], args: Args, runs: List[Run], info: Dict[str, dict], device: str) -> str:
    """Median and quartiles of s/step per run, and the median of the per-round ratios to the first run."""
    times: Dict[str, List[float]] = {r.label: [] for r in runs}
    for row in rows:
        times[str(row["run"])].append(float(row["seconds"]))  # type: ignore[arg-type]
    base = times[runs[0].label]
    threads = os.environ.get("OMP_NUM_THREADS", "all")
    lines = [
        "# Training step time, runs interleaved step by step",
        "",
        f"Command: `OMP_NUM_THREADS={threads} python benchmarks/bench_step_interleaved.py --data {args.data} --out "
        f"{args.out} --runs {' '.join(args.runs)}"
        + (f" --trees {' '.join(args.trees)}" if args.trees else "")
        + f" --steps {args.steps} --warmup {args.warmup}`",
        f"Machine: {device}; OMP_NUM_THREADS={threads}. {args.rays_per_batch} rays per batch; {args.steps} timed rounds "
        f"after {args.warmup} untimed; in each round every run takes one step (rotating order), each run in its own "
        "process. Fields as initialised (not trained).",
        "",
        f"| run | method | grids of step | resolution | parameters | median s/step | quartiles | "
        f"median per-round ratio to {runs[0].label} |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for run in runs:
        mine = times[run.label]
        q1, _, q3 = statistics.quantiles(mine, n=4) if len(mine) > 1 else (mine[0], mine[0], mine[0])
        ratio = statistics.median(m / b for m, b in zip(mine, base, strict=True))
        meta = info.get(run.label, {})
        lines.append(
            f"| {run.label} | {METHODS[run.method].label} | {run.at_step} | {meta.get('resolution', '-')} | "
            f"{meta.get('parameters', 0) / 1e6:.2f}M | {statistics.median(mine):.3f} | {q1:.3f} - {q3:.3f} | "
            f"{ratio:.3f} |"
        )
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(tyro.cli(Args))
