"""Wall time of one benchmark grid run one after another and as local Ray tasks, in one invocation, and whether each
run's PSNR is the same.

    python benchmarks/bench_ray_grid.py --out outputs/ray-grid [--profile tiny] [--methods agrinerf-lite] \
        [--seeds 0 1 2 3] [--steps 60] [--cpus-per-run 1] [--ray-cpus 2] [--table results/ray-grid/README.md]

The grid's scenes are prepared once beforehand (not timed). Then the same runs (each method with each random stream,
``--cpus-per-run`` cores and as many threads each) are trained and evaluated twice: one after another in this process
(``agrinerf-bench`` without ``--ray``), then as tasks of a local Ray of ``--ray-cpus`` CPUs (``--ray local``; its
start and stop counted). The table gives both wall times, their ratio, the load average around each, and whether
every checkpoint's PSNR is the same to the last digit (the floats compared exactly).
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import tyro

from agrinerf_ns.lab import bench_grid
from agrinerf_ns.lab.layout import BenchLayout
from agrinerf_ns.lab.profiles import PROFILES
from agrinerf_ns.machine import machine_note
from agrinerf_ns.orchestrate.executors import executor_for
from agrinerf_ns.orchestrate.jobs import JobsReport, Resources

QUALITY = ("psnr", "psnr_clean", "thermal_psnr")


@dataclass
class Args:
    out: Path = Path("outputs/ray-grid")
    """Scenes, both grids' runs and results, ray-grid.md."""
    profile: str = "tiny"
    """Scene size and step budgets (``agrinerf_ns.lab.profiles``)."""
    methods: Tuple[str, ...] = ("agrinerf-lite",)
    seeds: Tuple[int, ...] = (0, 1, 2, 3)
    """Random streams of each method: the grid is methods x seeds x the profile's scenes."""
    steps: Optional[int] = None
    """Training steps of every method (None: the profile's)."""
    cpus_per_run: int = 1
    ray_cpus: int = 2
    """CPUs of the local Ray (runs side by side: ray_cpus / cpus_per_run)."""
    table: Optional[Path] = None
    """Also write the table here (e.g. results/ray-grid/README.md)."""


def _timed(layout: BenchLayout, grid: List[bench_grid.GridRun], profile, args: Args, ray: bool) -> Tuple[float, JobsReport, Tuple[float, float]]:  # fmt: skip
    load_before = os.getloadavg()[0]
    start = time.perf_counter()
    options = dict(num_cpus=args.ray_cpus, object_store_mb=100, temp_dir=Path(tempfile.mkdtemp(prefix="ray-"))) if ray else {}  # fmt: skip
    with executor_for("local" if ray else None, **options) as executor:
        report = bench_grid.run_grid(grid, profile, layout, layout.results_csv, 0, executor,
                                     Resources(cpus=args.cpus_per_run), retries=0)  # fmt: skip
    wall = time.perf_counter() - start
    if report.failed or report.skipped:
        raise SystemExit(f"runs failed ({'Ray' if ray else 'sequential'}): see {layout.out / bench_grid.FAILURES_MD}")
    return wall, report, (load_before, os.getloadavg()[0])


def _quality(report: JobsReport) -> Dict[Tuple[str, str, object], Tuple[float, ...]]:
    """(run, step) -> the PSNR figures of that checkpoint, as computed (full floats)."""
    out = {}
    for key, rows in report.done.items():
        if key.startswith("scene:"):
            continue
        for row in rows:
            out[(key, str(row["step"]), row["method"])] = tuple(float(row.get(q, math.nan)) for q in QUALITY)
    return out


def _same(a: Tuple[float, ...], b: Tuple[float, ...]) -> bool:
    return all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b, strict=True))


def main(args: Args) -> str:
    profile = PROFILES[args.profile]
    if args.steps is not None:
        profile = dataclasses.replace(profile, steps={k: args.steps for k in profile.steps})
    grid = bench_grid.plan(profile.scenes, args.methods, args.seeds, set())
    scenes = args.out / "scenes"
    for scene in profile.scenes:
        bench_grid.prepare(scene, profile, 0, scenes)
    layouts = {}
    for name in ("sequential", "ray"):
        layout = BenchLayout(args.out / name)
        layout.out.mkdir(parents=True, exist_ok=True)
        if not layout.scenes.exists():
            layout.scenes.symlink_to(scenes.resolve())
        if layout.results_csv.exists() or layout.runs.exists():
            raise SystemExit(f"{layout.out}: holds runs of an earlier invocation; remove it (both grids train anew)")
        layouts[name] = layout
    seq_wall, seq_report, seq_load = _timed(layouts["sequential"], grid, profile, args, ray=False)
    ray_wall, ray_report, ray_load = _timed(layouts["ray"], grid, profile, args, ray=True)
    seq_q, ray_q = _quality(seq_report), _quality(ray_report)
    same = sum(1 for k in seq_q if k in ray_q and _same(seq_q[k], ray_q[k]))
    diff = max((abs(a - b) for k in seq_q if k in ray_q for a, b in zip(seq_q[k], ray_q[k], strict=True)
                if math.isfinite(a) and math.isfinite(b)), default=math.nan)  # fmt: skip
    cpu = next((line.split(":", 1)[1].strip() for line in Path("/proc/cpuinfo").read_text().splitlines()
                if line.startswith("model name")), platform.processor())  # fmt: skip
    steps = sorted({profile.steps[m] for m in args.methods})
    text = (
        "# A benchmark grid one run after another and as local Ray tasks\n\n"
        f"Command: `python benchmarks/bench_ray_grid.py {' '.join(sys.argv[1:])}`\n\n"
        f"{machine_note()}. CPU: {cpu}, `nproc` {os.cpu_count()}. Each run: {args.cpus_per_run} CPU and "
        f"OMP_NUM_THREADS={args.cpus_per_run}; the local Ray has {args.ray_cpus} CPUs, so "
        f"{args.ray_cpus // args.cpus_per_run} runs side by side. Grid: {len(grid)} runs ({', '.join(args.methods)} x "
        f"random streams {', '.join(map(str, args.seeds))} on {', '.join(profile.scenes)}; profile `{args.profile}`, "
        f"{'/'.join(map(str, steps))} steps, {profile.evaluations} checkpoints evaluated per run). Scenes prepared "
        "once beforehand; both wall times include each run's ns-train start-up and evaluation, the Ray one also "
        "Ray's start and stop. Load: 1-minute load average before and after each grid (other work shares the "
        "machine).\n\n"
        "| grid | wall (s) | ratio to sequential | load before / after |\n|---|---|---|---|\n"
        f"| sequential | {seq_wall:.1f} | 1.00 | {seq_load[0]:.2f} / {seq_load[1]:.2f} |\n"
        f"| local Ray | {ray_wall:.1f} | {ray_wall / seq_wall:.2f} | {ray_load[0]:.2f} / {ray_load[1]:.2f} |\n\n"
        f"PSNR ({', '.join(QUALITY)}) of every evaluated checkpoint: {same} of {len(seq_q)} identical to the last "
        f"digit between the two grids (largest difference {diff:.3g} dB).\n"
    )
    (args.out / "ray-grid.md").write_text(text)
    if args.table is not None:
        args.table.parent.mkdir(parents=True, exist_ok=True)
        args.table.write_text(text)
    print(text)
    return text


if __name__ == "__main__":
    main(tyro.cli(Args))
