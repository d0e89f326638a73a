"""The detection benchmark's orchestration: per scene render, train detectors, detect, score; then write the tables.

Per scene: every method's held-out (eval split) views are rendered (or taken from a folder; :mod:`.render_cache`); an
RGB detector is trained on the clean RGB truth views and a thermal detector on the dataset's thermal frames plus some
cross-spectral renders of training views, as the paper does, both without the held-out frames (:mod:`.training`);
each method's renders go through the detector of its modality and are scored against the true boxes
(:mod:`.score_folder`). What is evaluated comes from :mod:`.eval_plan`, how from :class:`.settings.EvalSettings`.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Optional

from agrinerf_ns.detect.boxes import list_images
from agrinerf_ns.detect.eval_plan import SceneSpec, check_scene
from agrinerf_ns.detect.figure import PanelBoxes, detection_figure
from agrinerf_ns.detect.score_folder import score_render_folder
from agrinerf_ns.detect.settings import EvalSettings
from agrinerf_ns.detect.training import train_scene_detectors, trained_scene_detectors
from agrinerf_ns.lab.paper_render_cache import cached_render, slug
from agrinerf_ns.lab.paper_tables import ResultRow, machine_note, write_tables
from agrinerf_ns.run_loading import LoadedRun


@dataclass
class SceneResult:
    rows: List[ResultRow]
    panels: Dict[str, Dict[str, PanelBoxes]]


def evaluate_scene(
    scene: SceneSpec, work: Path, settings: EvalSettings, runs: Optional[Dict[Path, LoadedRun]] = None
) -> SceneResult:
    """Check the scene (:func:`~agrinerf_ns.detect.eval_plan.check_scene`), then render, train detectors, detect and
    score every method.

    ``runs``: runs already loaded (:func:`~agrinerf_ns.run_loading.load_run`) by config path; others are loaded
    here. Each is released once its views are rendered (one pipeline in memory at a time).
    """
    check_scene(scene, settings.min_box_pixels)
    return _evaluate_checked_scene(scene, work, settings, runs)


def _evaluate_checked_scene(
    scene: SceneSpec, work: Path, settings: EvalSettings, runs: Optional[Dict[Path, LoadedRun]]
) -> SceneResult:
    work = Path(work) / slug(f"{scene.name}_{scene.lighting}")
    renders: Dict[str, Path] = {m.label: m.renders for m in scene.methods if m.renders is not None}
    runs = {} if runs is None else runs
    reuse_detectors = settings.detectors_from is not None  # then no training views are rendered for them
    rendering = [m for m in scene.methods if m.output == "thermal" and m.config is not None and not reuse_detectors]
    cross_spectral: List[Path] = []
    for config in dict.fromkeys(m.config for m in scene.methods if m.config is not None):
        for m in (m for m in scene.methods if m.config == config):
            renders[m.label] = cached_render(m, work / "renders" / slug(m.label), "eval", settings, runs)
            if m in rendering:
                out = work / "train_renders" / slug(m.label)
                cross_spectral.append(cached_render(m, out, "train", settings, runs, 1 / len(rendering)))
        runs.pop(config, None)  # free the pipeline before loading the next one
    runs.clear()
    held_out = sorted({p.stem for folder in renders.values() for p in list_images(folder)})
    modalities = {m.detector_modality() for m in scene.methods}
    if settings.detectors_from is not None:
        earlier = Path(settings.detectors_from) / "work" / work.name
        weights = trained_scene_detectors(earlier, modalities, held_out, settings.min_box_pixels)
    else:
        weights = train_scene_detectors(scene, modalities, held_out, cross_spectral, work, settings)
    rows, panels = [], {}
    for m in scene.methods:
        scored = score_render_folder(
            scene.raw,
            renders[m.label],
            weights[m.detector_modality()],
            settings.conf_threshold,
            settings.min_box_pixels,
            settings.detector.device,
        )
        manifest = renders[m.label] / "renders.json"
        step = json.loads(manifest.read_text()).get("step") if manifest.is_file() else None
        rows.append(ResultRow(scene.name, scene.lighting, m.label, scored.metrics, step, scored.matched))
        panels[m.label] = scored.panels
    return SceneResult(rows, panels)


def evaluate_plan(
    scenes: List[SceneSpec],
    out: Path,
    settings: EvalSettings,
    table: str,
    command: str,
    figure_views: int = 3,
    runs: Optional[Dict[Path, LoadedRun]] = None,
) -> Dict[str, Path]:
    """Check every scene, evaluate each, then write ``out/table_<kind>.md|csv`` (with bootstrap intervals),
    ``out/metrics.json`` (with each row's matched detections, for ``agrinerf-detect table``) and
    ``out/detections.png``.

    ``runs``: already loaded runs by config path (optional; see :func:`evaluate_scene`).
    """
    for scene in scenes:
        check_scene(scene, settings.min_box_pixels)  # every scene before any is rendered
    out = Path(out)
    results = [_evaluate_checked_scene(scene, out / "work", settings, runs) for scene in scenes]
    rows = [row for r in results for row in r.rows]
    steps = ", ".join(f"{r.scene}/{r.method}: {r.step + 1}" for r in rows if r.step is not None)
    footer = machine_note(command) + (f"  \nTraining steps of the rendered checkpoints: {steps}." if steps else "")
    md, csv_path = write_tables(rows, out, table, f"table_{table.lower()}", footer=footer)
    figure = detection_figure(
        results[0].panels, out / "detections.png", settings.conf_threshold, max_views=figure_views
    )
    metrics_json = out / "metrics.json"
    metrics_json.write_text(
        json.dumps(
            {
                "command": command,
                "settings": asdict(settings),
                "results": [
                    {
                        "scene": r.scene,
                        "lighting": r.lighting,
                        "method": r.method,
                        "step": r.step,
                        **r.metrics.as_dict(),
                        "images": None if r.matched is None else r.matched.to_json(),
                    }
                    for r in rows
                ],
            },
            indent=1,
            default=str,
        )
    )
    return {"markdown": md, "csv": csv_path, "figure": figure, "metrics": metrics_json}
