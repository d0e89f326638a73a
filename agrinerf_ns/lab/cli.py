"""``agrinerf-bench``: train each method on the same scenes and machine, evaluate, and write the trade-off.

Every method is trained with ``ns-train`` (the real trainer) once per scene, saving checkpoints along the way; each
checkpoint is one point of a quality-against-wall-time curve. Results are appended to ``results.csv`` after every
run (resumable: finished runs are skipped), then ``results.md`` (table + summary) and ``tradeoff.png`` are written.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import tyro
from rich.console import Console

from agrinerf_ns.lab import bench_grid, margins, results
from agrinerf_ns.lab.layout import BenchLayout
from agrinerf_ns.lab.methods import METHODS, SAMPLE_BUDGETS, unknown_reason
from agrinerf_ns.lab.profiles import PROFILES, BenchProfile
from agrinerf_ns.machine import machine_note
from agrinerf_ns.orchestrate.executors import executor_for
from agrinerf_ns.orchestrate.jobs import FolderInUse

CONSOLE = Console()


@dataclass
class BenchConfig:
    """Speed/accuracy benchmark of AgriNeRF against Nerfacto (RGB), Nerfacto (Thermal) and TensoRF."""

    out: Path = Path("outputs/bench")
    """Folder for scenes, runs, results.csv, results.md and tradeoff.png."""
    profile: str = "quick"
    """quick (CPU), full (GPU, paper settings: 30k steps), detect (CPU: the dark garden at 320x240 for
    ``agrinerf-detect evaluate --bench``), count (CPU, realistic sizes: agrinerf-lite's fruit counted on the row the
    rig drove beside the truth-mask oracle, the seeds-by-lightings table in OUT/counts.md), count-small (the earlier
    count profile, 200x150: every path and source counted, OUT/count.csv and count.md) or tiny (tests)."""
    methods: Optional[Tuple[str, ...]] = None
    """Methods to run (agrinerf-lite, agrinerf, nerfacto, nerfacto-thermal, tensorf; sample-budget variants such as
    agrinerf-paper-samples, trained for about the preset's wall time, only when named; BASE%FIELD=VALUE: BASE with a
    model config field set, e.g. agrinerf-lite%thermal_rays_per_batch=128, JSON values); None: the profile's (count:
    agrinerf-lite), else every method but the sample-budget variants."""
    scenes: Optional[Tuple[str, ...]] = None
    """``<orchard|garden>-<bright|shadowed|dusk|dark>`` scenes; None: the profile's."""
    steps: Tuple[str, ...] = ()
    """METHOD=N: train METHOD for N steps instead of the profile's budget, e.g. ``nerfacto=390 tensorf=390`` to set
    the baselines at the paper preset's steps (equal steps) as well as at their own (about equal wall time)."""
    evaluations: Optional[int] = None
    """Checkpoints evaluated per run (None: the profile's); more give a slow baseline's curve points at the presets'
    wall times."""
    seed: int = 0
    """Seed of the synthetic scenes."""
    seeds: Tuple[int, ...] = ()
    """Several scene seeds instead of --seed, each its own benchmark folder OUT/seed-<S> (seeds 0-2 tune, 100 and up
    report: docs/bench_profiles.md); with the count profile, OUT/counts.md tabulates every seed's row counts."""
    count: Optional[bool] = None
    """Count the fruit of every finished run (OUT/count.csv, count.md); None: the profile's (count: yes). False trains
    only, e.g. runs that only the detection tables read (``agrinerf-count`` counts one run later)."""
    target_psnr: Optional[float] = None
    """PSNR whose time-to-reach is reported; None: the lowest final PSNR among the RGB methods (all reach it)."""
    results_csv: Optional[Path] = None
    """Where results are appended; None: OUT/results.csv."""
    report_only: bool = False
    """Train nothing: rewrite results.md and tradeoff.png from the rows already in the CSV."""
    run_seeds: Tuple[int, ...] = (0,)
    """Random streams each method is trained with (``ns-train --machine.seed``; 0: Nerfstudio's default). A run of
    stream s > 0 is keyed ``<method>@s<s>`` in results.csv."""
    ray: Optional[str] = None
    """Run the grid as Ray tasks (the ``[ray]`` extra): ``local`` starts Ray on this machine, ``auto`` joins the
    cluster this machine belongs to, or a cluster address. OUT must be on a filesystem every node sees."""
    cpus_per_run: Optional[int] = None
    """CPU cores (and threads) each run holds; None: one per run with --ray, threads unchanged without."""
    gpus_per_run: Optional[float] = None
    """GPUs each run holds with --ray; None: one for the GPU profile (full), none otherwise."""
    retries: int = 1
    """Further attempts of a run that fails or whose worker dies, before it is reported in OUT/failures.md."""
    ray_cpus: Optional[int] = None
    """With --ray local: the CPUs Ray may use (None: all of this machine's)."""


def summary(rows: Sequence[results.Row], target_psnr: Optional[float], table: Sequence[Dict[str, object]]) -> str:
    """Differences against the baselines at equal wall time and equal steps (``table``: `margins.margins` of the
    rows), and the time to a stated PSNR, per scene."""
    key = results.quality_key(rows)
    lines = [
        f"Quality figure: `{key}` ({'vs clean truth, exposure-aligned' if key == 'psnr_clean' else 'vs held-out frames'})."
    ]
    for scene in sorted({r["scene"] for r in rows}):
        scene_rows = [r for r in rows if r["scene"] == scene]
        methods = sorted(
            {r["method"] for r in scene_rows if METHODS[results.seed_base(r["method"])].supervision == "rgb"}
        )
        if not methods:
            continue
        lines.append(f"\n**{scene}**")
        lines += margins.summary_lines([row for row in table if row["scene"] == scene])
        final_quality = {m: max(results.as_float(r, key) for r in scene_rows if r["method"] == m) for m in methods}
        target = target_psnr if target_psnr is not None else min(final_quality.values())
        lines.append(
            f"- time to reach {target:.2f} dB: "
            + ", ".join(
                f"{METHODS[m].label} {_seconds(results.time_to_quality(scene_rows, m, scene, target, key))}"
                for m in methods
            )
        )
    return "\n".join(lines) + "\n"


def _seconds(value: float) -> str:
    return f"{value:.0f} s" if math.isfinite(value) else "not reached"


def write_reports(rows: Sequence[results.Row], out: Path, target_psnr: Optional[float], command: str) -> None:
    """results.md (command, machine, summary, table) and tradeoff.png."""
    layout = BenchLayout(out)
    table = margins.margins(rows, results.quality_key(rows))
    text = (f"# agrinerf-bench results\n\nCommand: `{command}`\n\n{machine_note(sorted({r['device'] for r in rows}))}\n\n"
            f"![quality against wall time](tradeoff.png)\n\n## Summary\n{summary(rows, target_psnr, table)}\n"
            f"## All checkpoints\ns/step: steady state, wall time between a run's first and last checkpoint over the "
            f"steps between them. Peak RSS: the `ns-train` process tree, sampled every 0.2 s.\n\n"
            f"{results.markdown_table(rows)}")  # fmt: skip
    layout.results_md.write_text(text)
    margins.write_margins(table, layout.out / "margins.csv")
    results.plot(rows, layout.tradeoff_png)


def step_budgets(pairs: Sequence[str]) -> Dict[str, int]:
    """``METHOD=N`` pairs to step budgets; ValueError naming the pair that is not one."""
    budgets = {}
    for pair in pairs:
        method, _, value = pair.partition("=")
        if unknown_reason(method) is not None or not value.isdigit() or int(value) < 1:
            raise ValueError(f"--steps {pair!r}: expected METHOD=N, METHOD one of {', '.join(METHODS)} (or a variant "
                             "BASE%FIELD=VALUE) and N a positive whole number of steps")  # fmt: skip
        budgets[method] = int(value)
    return budgets


def main(config: BenchConfig) -> List[results.Row]:
    if config.seeds:
        return _main_seeds(config)
    if config.profile not in PROFILES:
        raise ValueError(f"unknown profile {config.profile!r}: choose one of {', '.join(PROFILES)}")
    unknown = {m: why for m in config.methods or () if (why := unknown_reason(m)) is not None}
    if unknown:
        raise ValueError(
            f"unknown methods {list(unknown)} ({'; '.join(unknown.values())}): choose from {', '.join(METHODS)}, or "
            "a variant BASE%FIELD=VALUE that sets a model config field (e.g. agrinerf-lite%thermal_rays_per_batch=128)"
        )
    profile = PROFILES[config.profile]
    methods = config.methods or profile.methods or tuple(m for m in METHODS if m not in SAMPLE_BUDGETS)
    if config.steps:
        profile = replace(profile, steps={**profile.steps, **step_budgets(config.steps)})
    if config.evaluations is not None:
        profile = replace(profile, evaluations=max(1, config.evaluations))
    scenes = config.scenes or profile.scenes
    count = profile.count if config.count is None else config.count
    if count and profile.count_rule == "row":  # every scene's row range known before anything is trained
        from agrinerf_ns.lab.count_row_bench import row_range

        for scene in scenes:
            row_range(profile, scene)
    layout = BenchLayout(config.out)
    csv_path = config.results_csv or layout.results_csv
    done = results.done_runs(results.read_rows(csv_path))
    todo = [] if config.report_only else bench_grid.plan(scenes, methods, config.run_seeds, done)
    report = None
    if todo:
        cpus = config.cpus_per_run if config.cpus_per_run is not None or config.ray is None else 1
        resources = bench_grid.run_resources(config.profile, cpus, config.gpus_per_run)
        with executor_for(config.ray, **({"num_cpus": config.ray_cpus} if config.ray else {})) as executor:
            report = bench_grid.run_grid(todo, profile, layout, csv_path, config.seed, executor, resources,
                                         config.retries, CONSOLE)  # fmt: skip
    keys = {results.seed_key(m, s) for m in methods for s in config.run_seeds}
    rows = [r for r in results.read_rows(csv_path) if r["scene"] in scenes and r["method"] in keys]
    if rows:  # none when every run failed: failures.md says why (RunsFailed below)
        write_reports(rows, config.out, config.target_psnr, "agrinerf-bench " + " ".join(sys.argv[1:]))
        CONSOLE.print(f"results: {csv_path}, {layout.results_md}, {layout.tradeoff_png}")
    if count:  # fruit counted in every finished run
        _count(config, profile, layout, scenes, {results.seed_key(m, s): METHODS[m].ns_method for m in methods
                                                 for s in config.run_seeds})  # fmt: skip
    if report is not None and (report.failed or report.skipped):
        raise bench_grid.RunsFailed(report, config.out / bench_grid.FAILURES_MD)
    return rows


def _count(
    config: BenchConfig, profile: BenchProfile, layout: BenchLayout, scenes: Sequence[str], methods: Dict[str, str]
) -> None:
    """The profile's counting of every finished run (bench key -> ns-train method in ``methods``): every path and
    source (OUT/count.csv, count.md) or the row and its table (OUT/count-row/, OUT/counts.md)."""
    from agrinerf_ns.lab.count_bench import count_bench, run_note

    note = run_note("agrinerf-bench " + " ".join(sys.argv[1:]))
    if profile.count_rule == "paths":
        count_bench(layout, scenes, methods, config.seed, note)
        return
    from agrinerf_ns.lab.count_row_bench import count_row_bench, write_bench_tables

    count_row_bench(layout, scenes, methods, profile)
    if not config.seeds:  # with --seeds, the table of every seed is written once all have run
        write_bench_tables(layout.out, note)


def _main_seeds(config: BenchConfig) -> List[results.Row]:
    """``--seeds``: the benchmark of each scene seed in OUT/seed-<S>, then (count profile) the table of them all."""
    from agrinerf_ns.lab.count_row_bench import seed_out

    rows: List[results.Row] = []
    failed: List[bench_grid.RunsFailed] = []
    for seed in config.seeds:
        try:
            rows += main(replace(config, seed=seed, seeds=(), out=seed_out(config.out, seed)))
        except bench_grid.RunsFailed as err:  # the other seeds still run; the failure is raised at the end
            failed.append(err)
    profile = PROFILES[config.profile]
    if (profile.count if config.count is None else config.count) and profile.count_rule == "row":
        from agrinerf_ns.lab.count_bench import run_note
        from agrinerf_ns.lab.count_row_bench import write_bench_tables

        write_bench_tables(config.out, run_note("agrinerf-bench " + " ".join(sys.argv[1:])))
        CONSOLE.print(f"the seeds-by-lightings table: {config.out / 'counts.md'}")
    if failed:
        raise failed[0]
    return rows


def entrypoint() -> None:
    """Console script ``agrinerf-bench``."""
    try:
        main(tyro.cli(BenchConfig))
    except (bench_grid.RunsFailed, FolderInUse) as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)
        sys.exit(1)


if __name__ == "__main__":
    entrypoint()
