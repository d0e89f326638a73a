"""``agrinerf-bench``'s runs as jobs: each scene synthesised and processed once, then each (scene, method, random
stream) trained and evaluated, in this process or as Ray tasks (``agrinerf-bench --ray``).

The driver alone appends to ``results.csv`` (one writer), each finished run exactly once; runs with results are not
planned again, and a run that was trained but not evaluated is evaluated without retraining (its ``train_run.json``).
A run's job removes a Nerfstudio run folder left without a ``train_run.json`` (an attempt killed mid-training) before
training again. Failed runs are listed with their errors and logs in ``OUT/failures.md``.
"""

from __future__ import annotations

import dataclasses
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Set, Tuple

from rich.console import Console

from agrinerf_ns.lab import results
from agrinerf_ns.lab.layout import BenchLayout, experiment_folder, train_record
from agrinerf_ns.lab.methods import METHODS, BenchMethod
from agrinerf_ns.lab.profiles import BenchProfile
from agrinerf_ns.lab.runs import run_method
from agrinerf_ns.lab.scenes import prepare_scene
from agrinerf_ns.orchestrate.jobs import (
    Executor,
    Job,
    JobsReport,
    Resources,
    driver_lock,
    failures_markdown,
    run_jobs,
    write_failures,
)

GPU_PROFILES = ("full",)
"""Profiles meant for a GPU: each of their runs asks for one."""
FAILURES_MD = "failures.md"


@dataclass(frozen=True)
class GridRun:
    """One training run of the grid."""

    scene: str
    method: str
    """A bench method key (:data:`agrinerf_ns.lab.methods.METHODS`)."""
    seed: int = 0
    """Random stream (``ns-train --machine.seed``; 0: Nerfstudio's default, the key unchanged)."""

    @property
    def key(self) -> str:
        """Its ``method`` in ``results.csv`` (:func:`agrinerf_ns.lab.results.seed_key`)."""
        return results.seed_key(self.method, self.seed)


def seeded_method(method: BenchMethod, seed: int) -> BenchMethod:
    """``method`` trained with random stream ``seed`` (0: unchanged)."""
    if not seed:
        return method
    return dataclasses.replace(
        method, label=f"{method.label} s{seed}", train_args=(*method.train_args, "--machine.seed", str(seed))
    )


def plan(
    scenes: Sequence[str], methods: Sequence[str], seeds: Sequence[int], done: Set[Tuple[str, str]]
) -> List[GridRun]:
    """The grid's runs (scenes, then methods, then streams) without those already in ``done`` ((scene, key) pairs)."""
    runs = [GridRun(scene, method, seed) for scene in scenes for method in methods for seed in seeds]
    return [run for run in runs if (run.scene, run.key) not in done]


def run_resources(profile_name: str, cpus: Optional[int], gpus: Optional[float]) -> Resources:
    """What each training run holds: ``cpus`` cores (threads), and ``gpus`` (None: one for a GPU profile)."""
    return Resources(cpus=cpus, gpus=(1.0 if profile_name in GPU_PROFILES else 0.0) if gpus is None else gpus)


def prepare(scene: str, profile: BenchProfile, scene_seed: int, scenes_root: Path) -> Tuple[Path, Path]:
    """Job: synthesise and process one scene (cached); its (raw capture, dataset)."""
    raw, data = prepare_scene(scene, profile, scene_seed, scenes_root)
    return raw, data


def train_and_evaluate(
    run: GridRun, profile: BenchProfile, runs_root: Path, prepared: Tuple[Path, Path]
) -> List[Dict[str, object]]:
    """Job: train one run and evaluate its checkpoints; its result rows."""
    from agrinerf_ns.machine import device_name

    raw, data = prepared
    method = seeded_method(METHODS[run.method], run.seed)
    if not train_record(runs_root, run.scene, run.key).exists():
        shutil.rmtree(experiment_folder(runs_root, run.scene, run.key) / method.ns_method, ignore_errors=True)
    return run_method(run.scene, run.key, method, raw, data, profile, runs_root, device_name())


def grid_jobs(
    runs: Sequence[GridRun], profile: BenchProfile, layout: BenchLayout, scene_seed: int, resources: Resources,
    retries: int,
) -> List[Job]:  # fmt: skip
    """A preparation job per scene (CPU only), then a job per run after its scene's."""
    jobs = []
    for scene in dict.fromkeys(run.scene for run in runs):
        folder = layout.scene(scene).raw.parent
        jobs.append(Job(f"scene:{scene}", prepare, (scene, profile, scene_seed, layout.scenes), folder,
                        Resources(cpus=resources.cpus), retries=retries))  # fmt: skip
    for run in runs:
        folder = experiment_folder(layout.runs, run.scene, run.key)
        log = folder / f"{METHODS[run.method].ns_method}.train.log"
        jobs.append(Job(f"{run.scene}/{run.key}", train_and_evaluate, (run, profile, layout.runs), folder, resources,
                        after=(f"scene:{run.scene}",), log=log, retries=retries))  # fmt: skip
    return jobs


def run_grid(
    runs: Sequence[GridRun],
    profile: BenchProfile,
    layout: BenchLayout,
    csv_path: Path,
    scene_seed: int,
    executor: Executor,
    resources: Resources = Resources(),
    retries: int = 1,
    console: Optional[Console] = None,
) -> JobsReport:
    """Run ``runs`` on ``executor``, appending each run's rows to ``csv_path`` as it finishes (on the driver, once per
    run); writes ``OUT/failures.md`` when runs failed (removes a stale one when none did). Holds ``OUT``'s driver lock
    throughout (:func:`~agrinerf_ns.orchestrate.jobs.driver_lock`: a second driver on ``OUT`` stops at once); runs
    that already have rows in ``csv_path`` are not appended again."""
    with driver_lock(layout.out):
        written = results.done_runs(results.read_rows(csv_path))

        def on_result(job: Job, rows: Any) -> None:
            if job.fn is not train_and_evaluate:
                return
            run: GridRun = job.args[0]
            if (run.scene, run.key) not in written:
                results.append_rows(csv_path, rows)
                written.add((run.scene, run.key))

        report = run_jobs(grid_jobs(runs, profile, layout, scene_seed, resources, retries), executor, on_result,
                          "benchmark runs", console)  # fmt: skip
        write_failures(layout.out / FAILURES_MD, failures_markdown(report, "Benchmark runs that failed"))
    return report


class RunsFailed(RuntimeError):
    """Some jobs failed after their retries (listed in the report's ``failures.md``)."""

    def __init__(self, report: JobsReport, listing: Path) -> None:
        self.report = report
        keys = [*report.failed, *report.skipped]
        super().__init__(f"{len(keys)} run(s) failed or were not run: {', '.join(keys)} (errors and logs: {listing})")
