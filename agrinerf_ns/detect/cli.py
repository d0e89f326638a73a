"""``agrinerf-detect``: downstream fruit detection on rendered views (paper Tables III and IV).

Subcommands: ``evaluate`` (the whole benchmark from a plan file), ``render`` (held-out views of one run), ``train``
(a detector on a scene's truth) and ``score`` (a folder of renders against the true boxes). Needs the optional
``[detect]`` extra (Ultralytics, AGPL-3.0) for everything but ``render``.
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Literal, Optional

import tyro
from typing_extensions import Annotated

from agrinerf_ns.detect.boxes import MIN_BOX_PIXELS
from agrinerf_ns.detect.detector import DetectorConfig
from agrinerf_ns.detect.settings import EvalSettings, MinBoxPixels, RaysPerChunk


@dataclass
class EvaluateCommand:
    """Render, train detectors, detect and score every method of every scene in a plan; write the tables + picture.

    Plan (JSON): {"scenes": [{"name": "orchard", "lighting": "dark", "raw": RAW, "dataset": DATASET,
    "methods": [{"label": "Nerfacto (RGB)", "config": ".../config.yml", "output": "rgb"},
    {"label": "Nerfacto (Thermal)", "config": ..., "output": "rgb", "detector": "thermal"},
    {"label": "Ours (Cross-Spectral)", "config": ..., "output": "thermal"}]}]}. A method may give "renders" (a folder of
    <frame>.png held-out views) instead of "config".
    """

    out: Path
    """Output folder: table_<iii|iv>.md/.csv, metrics.json, detections.png, work/ (renders, YOLO sets, detectors)."""
    plan: Optional[Path] = None
    """Plan JSON (see above)."""
    bench: Optional[Path] = None
    """Or: an agrinerf-bench output folder (all its finished runs; agrinerf gives an RGB and a cross-spectral row)."""
    table: Literal["III", "IV"] = "III"
    """Table III (methods x lighting) or IV (modality ablations of one scene)."""
    settings: Annotated[EvalSettings, tyro.conf.arg(name="")] = field(default_factory=EvalSettings)
    """Evaluation settings (agrinerf_ns.detect.settings.EvalSettings)."""

    def main(self) -> None:
        from rich.console import Console

        from agrinerf_ns.detect.eval_plan import load_plan, plan_from_bench
        from agrinerf_ns.detect.paper_eval import evaluate_plan

        if (self.plan is None) == (self.bench is None):
            raise ValueError("give exactly one of --plan PLAN.json or --bench AGRINERF_BENCH_OUT")
        if self.plan is not None:
            scenes = load_plan(self.plan)
        else:
            scenes = plan_from_bench(self.bench, self.table)  # type: ignore[arg-type]
        command = "agrinerf-detect " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        written = evaluate_plan(scenes, self.out, self.settings, self.table, command)
        console = Console()
        console.print(written["markdown"].read_text())
        for kind, path in written.items():
            console.print(f"[green]wrote[/green] {kind}: {path}")


@dataclass
class RenderCommand:
    """Render the held-out (eval split) views of a trained Nerfstudio run to OUT/<frame>.png."""

    config: Path
    """outputs/<experiment>/<method>/<timestamp>/config.yml"""
    out: Path
    output: Literal["rgb", "thermal"] = "rgb"
    """"thermal" is AgriNeRF's cross-spectral rendering."""
    split: Literal["eval", "train"] = "eval"
    max_views: Optional[int] = None
    rays_per_chunk: RaysPerChunk = None

    def main(self) -> None:
        from agrinerf_ns.detect.render_views import render_views

        written = render_views(self.config, self.output, self.out, self.split, self.max_views, self.rays_per_chunk)
        print(f"wrote {len(written)} views to {self.out}")


@dataclass
class TrainCommand:
    """Train a YOLOv8 detector from scratch on a scene's truth (RGB: truth/rgb_clean; thermal: dataset thermal)."""

    raw: Path
    """Raw capture with truth/boxes_yolo (agrinerf-synth output)."""
    out: Path
    modality: Literal["rgb", "thermal"] = "rgb"
    dataset: Optional[Path] = None
    """Processed dataset (needed for thermal)."""
    exclude_renders: List[Path] = field(default_factory=list)
    """Folders of held-out renders whose frames are left out of training."""
    cross_spectral: List[Path] = field(default_factory=list)
    """Folders of cross-spectral renders of training views to add to the thermal set."""
    cross_spectral_fraction: float = 0.25
    init: Optional[Path] = None
    """Detector weights to start from (e.g. the scene's RGB detector for a thermal one); None: from scratch."""
    min_box_pixels: MinBoxPixels = MIN_BOX_PIXELS
    detector: Annotated[DetectorConfig, tyro.conf.arg(name="detector")] = field(default_factory=DetectorConfig)

    def main(self) -> None:
        from agrinerf_ns.detect.boxes import list_images
        from agrinerf_ns.detect.eval_plan import MethodSpec, SceneSpec
        from agrinerf_ns.detect.training import train_scene_detector

        if self.modality == "thermal" and self.dataset is None:
            raise ValueError("--modality thermal needs --dataset (the processed dataset with thermal frames)")
        exclude = sorted({p.stem for folder in self.exclude_renders for p in list_images(folder)})
        scene = SceneSpec("scene", "", self.raw, self.dataset, [MethodSpec("detector", detector=self.modality)])
        settings = EvalSettings(
            self.detector,
            cross_spectral_fraction=self.cross_spectral_fraction,
            reuse=False,
            min_box_pixels=self.min_box_pixels,
        )
        weights = train_scene_detector(
            scene, self.modality, exclude, self.cross_spectral, self.out, settings, self.init
        )
        print(f"weights: {weights}")


@dataclass
class ScoreCommand:
    """Detect on a folder of rendered views and score against the scene's true boxes (prints JSON)."""

    raw: Path
    renders: Path
    weights: Path
    imgsz: Optional[int] = None
    """Inference size; None: the size the detector was trained at."""
    conf_threshold: float = 0.25
    min_box_pixels: MinBoxPixels = MIN_BOX_PIXELS
    out: Optional[Path] = None
    """Also write the metrics JSON here."""

    def main(self) -> None:
        from agrinerf_ns.detect.bootstrap import bootstrap_maps
        from agrinerf_ns.detect.score_folder import score_render_folder

        scored = score_render_folder(
            self.raw, self.renders, self.weights, self.conf_threshold, self.min_box_pixels, imgsz=self.imgsz
        )
        intervals = bootstrap_maps(scored.matched).intervals()
        bounds = {f"{key}_95ci": [i.low, i.high] for key, i in zip(("map50", "map50_95"), intervals, strict=True)}
        text = json.dumps({**scored.metrics.as_dict(), **bounds}, indent=2)
        print(text)
        if self.out is not None:
            self.out.write_text(text)


@dataclass
class TableCommand:
    """One table from several evaluations (e.g. one per lighting): their metrics.json files, scored alike."""

    metrics: List[Path]
    """metrics.json files written by agrinerf-detect evaluate."""
    out: Path
    """Output folder for table_<iii|iv>.md/.csv."""
    table: Literal["III", "IV"] = "III"

    def main(self) -> None:
        from agrinerf_ns.detect.merge import merge_evaluations

        command = "agrinerf-detect " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        md, csv_path = merge_evaluations(self.metrics, self.out, self.table, command)
        print(md.read_text())
        print(f"wrote {md} and {csv_path}")


COMMANDS = {
    "evaluate": EvaluateCommand,
    "render": RenderCommand,
    "train": TrainCommand,
    "score": ScoreCommand,
    "table": TableCommand,
}


def entrypoint(args: Optional[List[str]] = None) -> None:
    """Console script entry point: errors in the input are reported in one line, exit status 2."""
    from agrinerf_ns.detect.boxes import MissingTruthError
    from agrinerf_ns.detect.render_views import MissingOutputError

    command = tyro.extras.subcommand_cli_from_dict(COMMANDS, args=args, description=__doc__)
    try:
        command.main()
    except (MissingTruthError, MissingOutputError, FileNotFoundError, ValueError, ImportError) as err:
        print(f"agrinerf-detect: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
