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

MinBoxPixels = Annotated[
    int,
    tyro.conf.arg(
        help="A fruit counts when at least this many of its pixels are visible (truth/boxes_coco.json areas); smaller "
        "ones are ignored in scoring and left out of detector training labels. 0: every box counts."
    ),
]
RaysPerChunk = Annotated[
    Optional[int],
    tyro.conf.arg(
        help="Rays rendered at once (eval_num_rays_per_chunk). Default: 1024 on a CPU (faster and far less memory than "
        "the configs' GPU-sized chunks there; docs/detect.md), the run config's on a GPU. The image does not depend on "
        "it."
    ),
]


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
    detector: Annotated[DetectorConfig, tyro.conf.arg(name="detector")] = field(default_factory=DetectorConfig)
    conf_threshold: float = 0.25
    """Score threshold for precision, recall, F1 and the picture."""
    cross_spectral_fraction: float = 0.25
    """Cross-spectral renders of training views added to the thermal detector's set (fraction of its size)."""
    rgb_source: Literal["clean", "captured"] = "clean"
    """RGB detector training images: the clean truth views, or the captured (dataset) frames as the paper labels."""
    thermal_init: Literal["rgb", "scratch"] = "rgb"
    """Start the thermal detector from the scene's RGB detector (trained here from scratch) or from random weights."""
    thermal_init_lr0: float = 0.002
    """Learning rate of the thermal detector started from the RGB one (the RGB one uses --detector.lr0)."""
    min_box_pixels: MinBoxPixels = MIN_BOX_PIXELS
    max_render_views: Optional[int] = None
    """Render at most this many held-out views per method, evenly spaced (default: all)."""
    rays_per_chunk: RaysPerChunk = None
    detectors_from: Optional[Path] = None
    """An earlier evaluate --out folder whose detectors of the same scenes to use instead of training new ones (e.g.
    Table IV scored with Table III's detectors); refused if they trained on a held-out view."""
    reuse: bool = True
    """Reuse renders and detector weights already in OUT/work."""

    def main(self) -> None:
        from rich.console import Console

        from agrinerf_ns.detect.evaluate import EvalSettings, evaluate_plan, load_plan, plan_from_bench

        if (self.plan is None) == (self.bench is None):
            raise ValueError("give exactly one of --plan PLAN.json or --bench AGRINERF_BENCH_OUT")
        if self.plan is not None:
            scenes = load_plan(self.plan)
        else:
            scenes = plan_from_bench(self.bench, self.table)  # type: ignore[arg-type]

        settings = EvalSettings(
            detector=self.detector,
            conf_threshold=self.conf_threshold,
            cross_spectral_fraction=self.cross_spectral_fraction,
            max_render_views=self.max_render_views,
            rays_per_chunk=self.rays_per_chunk,
            reuse=self.reuse,
            rgb_source=self.rgb_source,
            thermal_init=self.thermal_init,
            thermal_init_lr0=self.thermal_init_lr0,
            min_box_pixels=self.min_box_pixels,
            detectors_from=self.detectors_from,
        )
        command = "agrinerf-detect " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        written = evaluate_plan(scenes, self.out, settings, self.table, command)
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
        from agrinerf_ns.detect.render import render_views

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
        from agrinerf_ns.detect.evaluate import EvalSettings, MethodSpec, SceneSpec, train_scene_detector

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
        from agrinerf_ns.detect.evaluate import EvalSettings, score_render_folder

        settings = EvalSettings(conf_threshold=self.conf_threshold, min_box_pixels=self.min_box_pixels)
        metrics, _ = score_render_folder(self.raw, self.renders, self.weights, settings, imgsz=self.imgsz)
        text = json.dumps(metrics.as_dict(), indent=2)
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
        from agrinerf_ns.detect.evaluate import merge_evaluations

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
    from agrinerf_ns.detect.render import MissingOutputError

    command = tyro.extras.subcommand_cli_from_dict(COMMANDS, args=args, description=__doc__)
    try:
        command.main()
    except (MissingTruthError, MissingOutputError, FileNotFoundError, ValueError, ImportError) as err:
        print(f"agrinerf-detect: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
