"""The detector's commands: downstream fruit detection on rendered views.

Subcommands: ``render`` (held-out views of one run), ``train`` (a detector on a scene's truth), ``score`` (a folder
of renders against the true boxes) and ``fruit`` (a fruit head's rendered channel as the detections, no detector).
The ``agrinerf-detect`` console script (:mod:`agrinerf_ns.lab.paper_cli`) adds the paper tables' ``evaluate`` and
``table``. Needs the optional ``[detect]`` extra (Ultralytics, AGPL-3.0) for
everything but ``render`` and ``fruit``.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Literal, Optional

import tyro
from typing_extensions import Annotated

from agrinerf_ns.detect.boxes import MIN_BOX_PIXELS
from agrinerf_ns.detect.detector import DetectorConfig
from agrinerf_ns.detect.settings import EvalSettings, MinBoxPixels, RaysPerChunk


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
class FruitCommand:
    """Table III from a fruit head, no detector needed: the rendered fruit channel's regions in the held-out views of
    one or more runs, scored against the scenes' true boxes (mAP50, mAP50-95, P/R/F1 with bootstrap intervals over
    the pooled images; prints JSON)."""

    runs: List[str]
    """RENDERS=RAW pairs: an ``agrinerf-count`` render folder (OUT/renders of a run with a fruit head) and its raw
    synthetic capture (truth/boxes_yolo)."""
    split: Literal["eval", "train"] = "eval"
    min_box_pixels: MinBoxPixels = MIN_BOX_PIXELS
    out: Optional[Path] = None
    """Also write the metrics JSON here."""

    def main(self) -> None:
        from agrinerf_ns.detect.fruit_channel import score_fruit_channel

        pairs = []
        for pair in self.runs:
            renders, sep, raw = pair.partition("=")
            if not sep or not renders or not raw:
                raise ValueError(f"--runs {pair!r}: expected RENDERS=RAW (a count render folder and its raw capture)")
            pairs.append((Path(renders), Path(raw)))
        import datetime
        import os

        from agrinerf_ns.machine import machine_note

        record = {"command": "agrinerf-detect fruit " + " ".join(sys.argv[2:]), "machine": machine_note(),
                  "threads": os.environ.get("OMP_NUM_THREADS", "unset"),
                  "date": datetime.date.today().isoformat()}  # fmt: skip
        scored = score_fruit_channel(pairs, self.split, self.min_box_pixels)
        text = json.dumps({**scored.as_dict(), "record": record}, indent=2)
        print(text)
        if self.out is not None:
            self.out.write_text(text + "\n")


COMMANDS: Dict[str, type] = {
    "render": RenderCommand,
    "train": TrainCommand,
    "score": ScoreCommand,
    "fruit": FruitCommand,
}
"""The detector's own subcommands; the ``agrinerf-detect`` console script adds the paper tables' ``evaluate`` and
``table`` (:mod:`agrinerf_ns.lab.paper_cli`)."""


def entrypoint(
    args: Optional[List[str]] = None, commands: Optional[Dict[str, type]] = None, description: Optional[str] = None
) -> None:
    """Run one of ``commands`` (default :data:`COMMANDS`): errors in the input are reported in one line, exit
    status 2."""
    from agrinerf_ns.detect.boxes import MissingTruthError
    from agrinerf_ns.detect.render_views import MissingOutputError

    command = tyro.extras.subcommand_cli_from_dict(
        COMMANDS if commands is None else commands, args=args, description=description or __doc__
    )
    try:
        command.main()
    except (MissingTruthError, MissingOutputError, FileNotFoundError, ValueError, ImportError) as err:
        print(f"agrinerf-detect: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
