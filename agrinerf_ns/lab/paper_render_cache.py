"""A method's rendered views in an evaluation's work folder: rendered once, reused while run and output are the same."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Dict

from agrinerf_ns.detect.boxes import list_images
from agrinerf_ns.detect.eval_plan import MethodSpec
from agrinerf_ns.detect.render_views import Split, render_pipeline_views
from agrinerf_ns.detect.settings import EvalSettings
from agrinerf_ns.run_loading import LoadedRun, load_run


def slug(text: str) -> str:
    """A folder name for a label: "Ours (Cross-Spectral)" -> "ours__cross_spectral"."""
    return "".join(ch if ch.isalnum() else "_" for ch in text).strip("_").lower()


def cached_render(
    method: MethodSpec,
    out: Path,
    split: Split,
    settings: EvalSettings,
    runs: Dict[Path, LoadedRun],
    share: float = 1.0,
) -> Path:
    """Render (or reuse) a method's views of ``split`` into ``out``; ``runs`` caches loaded runs by config path.

    Held-out views: all (or ``settings.max_render_views``). Training views (cross-spectral renders for the thermal
    detector): only as many as it takes, ``cross_spectral_fraction`` of the training frames times ``share`` (this
    method's share of the cross-spectral methods), evenly spaced. Views already in ``out`` are reused when its
    ``renders.json`` names the same output and run config (and ``settings.reuse``).
    """
    if settings.reuse and (out / "renders.json").is_file() and list_images(out):
        manifest = json.loads((out / "renders.json").read_text())
        if (manifest.get("output"), manifest.get("config")) == (method.output, str(method.config)):
            return out
    assert method.config is not None
    if method.config not in runs:
        runs[method.config] = load_run(method.config, settings.rays_per_chunk)
    if split == "eval":
        max_views = settings.max_render_views
    else:
        frames = len(runs[method.config].pipeline.datamanager.train_dataset)
        max_views = math.ceil(settings.cross_spectral_fraction * frames * share)
    render_pipeline_views(runs[method.config], method.output, out, split, max_views)
    return out
