"""One benchmark run: a method trained on a scene with ``ns-train`` and its checkpoints evaluated, resumed from its
``train_run.json`` when it was trained before. ``agrinerf-bench`` and its grid jobs
(:mod:`agrinerf_ns.lab.bench_grid`) both run it."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Tuple

from agrinerf_ns.lab.layout import experiment_folder, train_record
from agrinerf_ns.lab.methods import BenchMethod
from agrinerf_ns.lab.profiles import BenchProfile
from agrinerf_ns.ns_commands import TrainRun, ns_train


def run_method(
    scene: str,
    method_key: str,
    method: BenchMethod,
    raw: Path,
    data: Path,
    profile: BenchProfile,
    runs: Path,
    device: str,
) -> List[Dict[str, object]]:
    """Train one method on one scene and evaluate its checkpoints; returns the result rows.

    ``runs``: the output folder's ``runs/`` (:mod:`agrinerf_ns.lab.layout`)."""
    from agrinerf_ns.checkpoint_eval import TruthImages, evaluate_checkpoint

    # an ablation or a sample budget: its method's budget (scaled to about equal wall time)
    steps = profile.steps.get(method_key, round(profile.steps[method.ns_method] * method.step_scale))
    save_every = max(1, steps // profile.evaluations)
    record = train_record(runs, scene, method_key)
    experiment = experiment_folder(runs, scene, method_key)
    run = TrainRun.load(record) if record.exists() else None
    if run is None or not run.checkpoints():
        run = ns_train(method.ns_method, data / method.data_file, experiment.parent, experiment.name, max_steps=steps,
                       rays_per_batch=profile.rays_per_batch,
                       extra_args=(*method.train_args, *_extra_args(profile, method_key, method)),
                       dataparser_args=method.dataparser_args, steps_per_save=save_every)  # fmt: skip
        run.save(record)  # an interrupted evaluation resumes without retraining
    truth = TruthImages(raw) if (raw / "truth" / "rgb_clean").is_dir() else None
    rows = []
    for step, checkpoint in run.checkpoints():
        metrics = evaluate_checkpoint(run.config, step, method.supervision, truth, max_views=profile.eval_views)
        rows.append({
            "scene": scene, "method": method_key, "label": method.label, "step": step + 1,
            "wall_s": checkpoint.stat().st_mtime - run.started_at, "s_per_step": run.s_per_step,
            "peak_rss_mb": run.peak_rss_mb, "device": device, **metrics,
        })  # fmt: skip
    return rows


def _extra_args(profile: BenchProfile, method_key: str, method: BenchMethod) -> Tuple[str, ...]:
    """The profile's extra ``ns-train`` options for a bench key, else for its ``ns-train`` method."""
    return profile.extra_args.get(method_key, profile.extra_args.get(method.ns_method, ()))
