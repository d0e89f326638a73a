"""The detection benchmark: render held-out views, train detectors on truth, detect, score, write the tables.

Per scene: every method's held-out (eval split) views are rendered (or taken from a folder); an RGB detector is trained
on the clean RGB truth views and a thermal detector on the dataset's thermal frames plus some cross-spectral renders
of training views (as the paper does), both without the held-out frames; each method's renders go through the
detector of its modality and are scored against the true boxes.
"""

from __future__ import annotations

import hashlib
import json
import math
import platform
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Dict, List, Literal, Optional, Set, Tuple

from agrinerf_ns.bench.methods import ABLATIONS
from agrinerf_ns.detect.boxes import MIN_BOX_PIXELS, SceneTruth, list_images, yolo_to_xyxy
from agrinerf_ns.detect.detector import DetectorConfig, predict_folder, train_detector, trained_weights
from agrinerf_ns.detect.figure import PanelBoxes, detection_figure
from agrinerf_ns.detect.render import LoadedRun, MissingOutputError, Output, load_run, render_pipeline_views
from agrinerf_ns.detect.scoring import DetectionMetrics, ImageBoxes, score_detections
from agrinerf_ns.detect.tables import ResultRow, write_tables
from agrinerf_ns.detect.yolo_data import (
    LabelledImage,
    dataset_images,
    rendered_images,
    rgb_truth_images,
    subsample,
    write_yolo_dataset,
)
from agrinerf_ns.machine import device_name, software_versions
from agrinerf_ns.modalities import TABLE_IV_ABLATIONS

DetectorInput = Literal["rgb", "thermal"]
"""Which trained detector scores a view: the RGB one or the thermal one (a detector input, not a reconstruction
modality of :mod:`agrinerf_ns.modalities`)."""


@dataclass
class MethodSpec:
    """One reconstruction to evaluate."""

    label: str
    """Row label, e.g. "Nerfacto (RGB)", "Ours (Cross-Spectral)"."""
    output: Output = "rgb"
    """Rendered output: "rgb", or "thermal" for the cross-spectral rendering."""
    config: Optional[Path] = None
    """Nerfstudio run config (outputs/.../config.yml) to render from."""
    renders: Optional[Path] = None
    """Or: a folder of already rendered held-out views named <frame>.png."""
    detector: Optional[DetectorInput] = None
    """Detector to use; default "thermal" for output "thermal", else "rgb" (Nerfacto (Thermal): output rgb, detector
    thermal)."""

    def detector_modality(self) -> DetectorInput:
        return self.detector or ("thermal" if self.output == "thermal" else "rgb")


@dataclass
class SceneSpec:
    """One scene: its raw capture (with truth/), its processed dataset, and the methods trained on it."""

    name: str
    lighting: str
    raw: Path
    dataset: Optional[Path] = None
    """Processed dataset; needed for the thermal detector (its thermal frames are aligned to the RGB camera)."""
    methods: List[MethodSpec] = field(default_factory=list)


@dataclass
class EvalSettings:
    """Benchmark settings shared by all scenes."""

    detector: DetectorConfig = field(default_factory=DetectorConfig)
    conf_threshold: float = 0.25
    """Score threshold for precision, recall and F1 (mAPs use every detection down to 0.001)."""
    cross_spectral_fraction: float = 0.25
    """Cross-spectral training-view renders added to the thermal detector's set, as a fraction of its thermal frames."""
    max_render_views: Optional[int] = None
    """Render at most this many held-out views per method (None: all)."""
    rays_per_chunk: Optional[int] = None
    """Rays rendered at once (``eval_num_rays_per_chunk``; None: 1024 on a CPU, the run config's on a GPU). The image
    does not depend on it; time and memory do (:data:`agrinerf_ns.views.CPU_RAYS_PER_CHUNK`)."""
    reuse: bool = True
    """Reuse renders and detector weights already in the work folder."""
    rgb_source: Literal["clean", "captured"] = "clean"
    """RGB detector training images: ``truth/rgb_clean`` (noise-free, well exposed) or the dataset's captured frames
    (the paper labels "the original dataset images")."""
    thermal_init: Literal["rgb", "scratch"] = "rgb"
    """Start the thermal detector from the scene's RGB detector (trained here, from scratch, on the clean RGB truth
    without the held-out frames) or from random weights (docs/detect.md: from scratch it learnt nothing from the dark
    garden's 21 thermal frames in 120 CPU epochs)."""
    thermal_init_lr0: float = 0.002
    """AdamW learning rate of the thermal detector when it starts from the RGB detector (a fine-tune; the RGB one
    from scratch uses ``detector.lr0``)."""
    min_box_pixels: int = MIN_BOX_PIXELS
    """A fruit counts when at least this many of its pixels are visible in the truth view (``area`` in
    ``truth/boxes_coco.json``; about a third of a whole fruit in the 320x240 detect profile). Smaller ones, mostly
    fruit behind leaves, are ignored in scoring (COCO ignore regions) and left out of the detectors' training labels.
    0 counts every box (and needs no ``boxes_coco.json``)."""
    detectors_from: Optional[Path] = None
    """An earlier evaluation's output folder whose detectors (``work/<scene>_<lighting>/detector_<modality>``) score
    this one's renders instead of detectors trained here: e.g. Table IV's ablations scored with the detectors of the
    same scene's Table III. Refused when they trained on a held-out view or with another ``min_box_pixels``."""


@dataclass
class SceneResult:
    rows: List[ResultRow]
    panels: Dict[str, Dict[str, PanelBoxes]]


def load_plan(path: Path) -> List[SceneSpec]:
    """Read a plan JSON: {"scenes": [{"name", "lighting", "raw", "dataset", "methods": [{"label", "output", "config" |
    "renders", "detector"}]}]}. Relative paths are relative to the plan file."""
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as err:
        raise ValueError(f"{path}: cannot read the plan: {err}") from err
    base = path.parent

    def required(value: str) -> Path:
        return Path(value) if Path(value).is_absolute() else base / value

    def p(value: Optional[str]) -> Optional[Path]:
        return None if value is None else required(value)

    scenes = []
    for i, s in enumerate(data.get("scenes", [])):
        try:
            methods = [
                MethodSpec(
                    m["label"], m.get("output", "rgb"), p(m.get("config")), p(m.get("renders")), m.get("detector")
                )
                for m in s["methods"]
            ]
            scenes.append(SceneSpec(s["name"], s["lighting"], required(s["raw"]), p(s.get("dataset")), methods))
        except KeyError as err:
            raise ValueError(f"{path}: scene {i} lacks the key {err}") from err
    if not scenes:
        raise ValueError(f"{path}: the plan lists no scenes")
    return scenes


BENCH_METHODS: Dict[str, List[Tuple[str, Output, Optional[DetectorInput]]]] = {
    "nerfacto": [("Nerfacto (RGB)", "rgb", None)],
    "nerfacto-thermal": [("Nerfacto (Thermal)", "rgb", "thermal")],
    "tensorf": [("TensoRF (RGB)", "rgb", None)],
    "agrinerf-lite": [("Ours-lite (RGB)", "rgb", None), ("Ours-lite (Cross-Spectral)", "thermal", None)],
    "agrinerf": [("Ours (RGB)", "rgb", None), ("Ours (Cross-Spectral)", "thermal", None)],
}
"""agrinerf-bench method key -> the detection rows it gives (label, rendered output, detector)."""

BENCH_ABLATIONS: Dict[str, List[Tuple[str, Output, Optional[DetectorInput]]]] = {
    **{
        key: [(f"Ours ({name})", "thermal" if "thermal" in TABLE_IV_ABLATIONS[name] else "rgb", None)]
        for key, name in ABLATIONS.items()
    },
    "agrinerf-lite": [("Ours (All)", "thermal", None)],
}
"""Table IV from agrinerf-bench's AgriNeRF-lite ablations: the cross-spectral rendering where the ablation learns from
thermal frames, else the RGB one (RGB, RGB+Events)."""


def plan_from_bench(bench_out: Path, table: str = "III") -> List[SceneSpec]:
    """The plan for an ``agrinerf-bench`` output folder: OUT/scenes/<scene>-<lighting>/{raw,data} and
    OUT/runs/<scene>-<lighting>/<method key>/<ns method>/run/config.yml: every run of a known method with a
    checkpoint. Table "IV": the scenes with modality ablations (``lite-ablation-*`` runs), one row per ablation."""
    known = BENCH_ABLATIONS if table == "IV" else BENCH_METHODS
    bench_out = Path(bench_out)
    runs_root = bench_out / "runs"
    if not runs_root.is_dir():
        raise FileNotFoundError(f"{bench_out}: not an agrinerf-bench output folder ({runs_root} does not exist)")
    scenes = []
    for scene_dir in sorted(p for p in runs_root.iterdir() if p.is_dir()):
        name, _, lighting = scene_dir.name.partition("-")
        if table == "IV" and not any((scene_dir / key).is_dir() for key in ABLATIONS):
            continue
        methods = []
        for key, rows in known.items():
            configs = [c for c in sorted((scene_dir / key).glob("*/run/config.yml")) if _has_checkpoint(c)]
            if configs:
                methods += [MethodSpec(label, output, config=configs[0], detector=det) for label, output, det in rows]
        if methods:
            data = bench_out / "scenes" / scene_dir.name / "data"
            raw = bench_out / "scenes" / scene_dir.name / "raw"
            scenes.append(SceneSpec(name, lighting or "-", raw, data if data.is_dir() else None, methods))
    if not scenes:
        raise FileNotFoundError(f"{runs_root}: no finished run of {', '.join(known)}")
    return scenes


def _has_checkpoint(config: Path) -> bool:
    return any((config.parent / "nerfstudio_models").glob("step-*.ckpt"))


def check_scene(scene: SceneSpec, min_box_pixels: int = 0) -> None:
    """Fail early, naming the problem, before anything is trained or rendered."""
    SceneTruth(scene.raw, min_box_pixels)  # raises MissingTruthError for a scene without truth boxes
    if not scene.methods:
        raise ValueError(f"scene {scene.name}: no methods to evaluate")
    for m in scene.methods:
        if m.output not in ("rgb", "thermal"):
            raise ValueError(f"scene {scene.name}, {m.label}: output must be 'rgb' or 'thermal', got {m.output!r}")
        if (m.config is None) == (m.renders is None):
            raise ValueError(f"scene {scene.name}, {m.label}: give exactly one of config (a run) or renders (a folder)")
        if m.renders is not None:
            _check_render_folder(m.renders, m)
        if m.detector_modality() == "thermal" and scene.dataset is None:
            raise ValueError(
                f"scene {scene.name}, {m.label}: the thermal detector is trained on the dataset's thermal frames; "
                "give the scene's processed dataset (with thermal_file_path frames)"
            )


def _check_render_folder(folder: Path, method: MethodSpec) -> None:
    if not Path(folder).is_dir() or not list_images(folder):
        raise FileNotFoundError(f"{folder}: empty render folder (no .png/.jpg views) for {method.label}")
    manifest = Path(folder) / "renders.json"
    if manifest.is_file():
        rendered = json.loads(manifest.read_text()).get("output")
        if rendered != method.output:
            raise MissingOutputError(
                f"{folder}: holds '{rendered}' renders ({manifest}) but {method.label} asks for '{method.output}'"
            )


def _slug(text: str) -> str:
    return "".join(ch if ch.isalnum() else "_" for ch in text).strip("_").lower()


def _render(
    method: MethodSpec,
    out: Path,
    split: str,
    settings: EvalSettings,
    runs: Dict[Path, LoadedRun],
    share: float = 1.0,
) -> Path:
    """Render (or reuse) a method's views of ``split``; ``runs`` caches loaded runs by config path.

    Held-out views: all (or ``settings.max_render_views``). Training views (cross-spectral renders for the thermal
    detector): only as many as it takes, ``cross_spectral_fraction`` of the training frames times ``share`` (this
    method's share of the cross-spectral methods), evenly spaced.
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
    render_pipeline_views(runs[method.config], method.output, out, split, max_views)  # type: ignore[arg-type]
    return out


def train_scene_detector(
    scene: SceneSpec,
    modality: DetectorInput,
    exclude: List[str],
    cross_spectral: List[Path],
    work: Path,
    settings: EvalSettings,
    init: Optional[Path] = None,
) -> Path:
    """Train (or reuse) the scene's RGB or thermal detector without the held-out frames; returns its weights.

    ``init``: weights to start from (else from scratch). Weights in the work folder are reused only when they were
    trained with the same settings on the same images from the same start (recorded in
    ``detector_<modality>/agrinerf_detect.json``).
    """
    run_dir = work / f"detector_{modality}"
    truth = SceneTruth(scene.raw, settings.min_box_pixels)
    if modality == "rgb" and settings.rgb_source == "clean":
        items: List[LabelledImage] = rgb_truth_images(truth, exclude)
    elif modality == "rgb":
        if scene.dataset is None:
            raise ValueError(f"scene {scene.name}: rgb_source 'captured' needs the scene's processed dataset")
        items = dataset_images(truth, scene.dataset, "rgb", exclude)
    else:
        assert scene.dataset is not None
        items = dataset_images(truth, scene.dataset, "thermal", exclude)
        extra: List[LabelledImage] = []
        for folder in cross_spectral:
            renders = rendered_images(truth, folder, f"xspec_{folder.name}")
            extra += [item for item in renders if item.image.stem not in set(exclude)]
        count = settings.cross_spectral_fraction * len(items) / max(1, len(extra))
        items += subsample(extra, min(1.0, count), settings.detector.seed)
    record = {
        "detector": asdict(settings.detector),
        "min_box_pixels": settings.min_box_pixels,
        "images": [str(item.image) for item in items],
        "init": None if init is None else {"path": str(init), "sha256": _sha256(init)},
    }
    record_path = run_dir / "agrinerf_detect.json"
    if settings.reuse and record_path.is_file() and json.loads(record_path.read_text()) == record:
        reused = trained_weights(run_dir)
        if reused is not None:
            return reused
    data_yaml = write_yolo_dataset(work / f"yolo_{modality}", items)
    weights = train_detector(data_yaml, run_dir, settings.detector, init)
    record_path.write_text(json.dumps(record, indent=1))
    return weights


def train_scene_detectors(
    scene: SceneSpec,
    modalities: Set[DetectorInput],
    exclude: List[str],
    cross_spectral: List[Path],
    work: Path,
    settings: EvalSettings,
) -> Dict[DetectorInput, Path]:
    """The detectors a scene's methods need; with ``thermal_init`` "rgb" the RGB one is trained first (even when no
    method uses it) and the thermal one starts from its weights."""
    weights: Dict[DetectorInput, Path] = {}
    if "rgb" in modalities or ("thermal" in modalities and settings.thermal_init == "rgb"):
        weights["rgb"] = train_scene_detector(scene, "rgb", exclude, cross_spectral, work, settings)
    if "thermal" in modalities:
        init, thermal_settings = None, settings
        if settings.thermal_init == "rgb":
            init = weights["rgb"]
            thermal_settings = replace(settings, detector=replace(settings.detector, lr0=settings.thermal_init_lr0))
        weights["thermal"] = train_scene_detector(
            scene, "thermal", exclude, cross_spectral, work, thermal_settings, init
        )
    return weights


def trained_scene_detectors(
    folder: Path, modalities: Set[DetectorInput], held_out: List[str], min_box_pixels: int
) -> Dict[DetectorInput, Path]:
    """The detectors an earlier evaluation trained for a scene (``folder`` = its ``work/<scene>_<lighting>``), checked
    against their records: none may have trained on a held-out view, and their labels must have left out the same
    small fruit the scoring ignores."""
    weights: Dict[DetectorInput, Path] = {}
    for modality in sorted(modalities):
        run_dir = Path(folder) / f"detector_{modality}"
        record_path = run_dir / "agrinerf_detect.json"
        found = trained_weights(run_dir)
        if not record_path.is_file() or found is None:
            raise FileNotFoundError(f"{run_dir}: no trained {modality} detector there (weights/best.pt and "
                                    "agrinerf_detect.json, as agrinerf-detect evaluate writes them)")  # fmt: skip
        record = json.loads(record_path.read_text())
        leaked = sorted({Path(image).stem for image in record["images"]} & set(held_out))
        if leaked:
            raise ValueError(f"{record_path}: the {modality} detector trained on held-out views {leaked}; it cannot "
                             "score them")  # fmt: skip
        if record.get("min_box_pixels") != min_box_pixels:
            raise ValueError(f"{record_path}: trained with min_box_pixels {record.get('min_box_pixels')}, this "
                             f"evaluation ignores fruit under {min_box_pixels}")  # fmt: skip
        weights[modality] = found
    return weights


def _sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def score_render_folder(
    raw: Path, renders: Path, weights: Path, settings: EvalSettings, imgsz: Optional[int] = None
) -> Tuple[DetectionMetrics, Dict[str, PanelBoxes]]:
    """Detect on every rendered view (at ``imgsz``, default the detector's training size) and score against the
    scene's true boxes (those under ``settings.min_box_pixels`` visible pixels ignored)."""
    truth = SceneTruth(raw, settings.min_box_pixels)
    detections = predict_folder(weights, renders, imgsz=imgsz, device=settings.detector.device)
    images, panels = [], {}
    for path in list_images(renders):
        boxes, scores, (width, height) = detections[path.stem]
        frame = truth.frame(path.stem, path)
        true = yolo_to_xyxy(frame.counted, width, height)
        images.append(ImageBoxes(boxes, scores, true, yolo_to_xyxy(frame.ignored, width, height)))
        panels[path.stem] = PanelBoxes(path, true, boxes, scores)
    return score_detections(images, conf_threshold=settings.conf_threshold), panels


def evaluate_scene(
    scene: SceneSpec, work: Path, settings: EvalSettings, runs: Optional[Dict[Path, LoadedRun]] = None
) -> SceneResult:
    """Render, train detectors, detect and score every method of one scene.

    ``runs``: runs already loaded (:func:`~agrinerf_ns.detect.render.load_run`) by config path; others are loaded
    here. Each is released once its views are rendered (one pipeline in memory at a time).
    """
    check_scene(scene, settings.min_box_pixels)
    work = Path(work) / _slug(f"{scene.name}_{scene.lighting}")
    renders: Dict[str, Path] = {m.label: m.renders for m in scene.methods if m.renders is not None}
    runs = {} if runs is None else runs
    reuse_detectors = settings.detectors_from is not None  # then no training views are rendered for them
    rendering = [m for m in scene.methods if m.output == "thermal" and m.config is not None and not reuse_detectors]
    cross_spectral: List[Path] = []
    for config in dict.fromkeys(m.config for m in scene.methods if m.config is not None):
        for m in (m for m in scene.methods if m.config == config):
            renders[m.label] = _render(m, work / "renders" / _slug(m.label), "eval", settings, runs)
            if m in rendering:
                out = work / "train_renders" / _slug(m.label)
                cross_spectral.append(_render(m, out, "train", settings, runs, 1 / len(rendering)))
        runs.pop(config, None)  # free the pipeline before loading the next one
    runs.clear()
    held_out = sorted({p.stem for folder in renders.values() for p in list_images(folder)})
    modalities = {m.detector_modality() for m in scene.methods}
    if reuse_detectors:
        earlier = Path(settings.detectors_from) / "work" / work.name  # type: ignore[arg-type]
        weights = trained_scene_detectors(earlier, modalities, held_out, settings.min_box_pixels)
    else:
        weights = train_scene_detectors(scene, modalities, held_out, cross_spectral, work, settings)
    rows, panels = [], {}
    for m in scene.methods:
        metrics, method_panels = score_render_folder(
            scene.raw, renders[m.label], weights[m.detector_modality()], settings
        )
        manifest = renders[m.label] / "renders.json"
        step = json.loads(manifest.read_text()).get("step") if manifest.is_file() else None
        rows.append(ResultRow(scene.name, scene.lighting, m.label, metrics, step))
        panels[m.label] = method_panels
    return SceneResult(rows, panels)


def machine_note(command: str) -> str:
    """Footer for the tables: the command and the machine."""
    try:
        import ultralytics

        yolo = ultralytics.__version__
    except ImportError:  # pragma: no cover - the detector needs it anyway
        yolo = "absent"
    return (
        f"Command: `{command}`  \nMachine: {platform.machine()}, {device_name()}; "
        f"{software_versions()}, ultralytics {yolo}. "
        "mAPs x100, COCO 101-point interpolation; precision/recall/F1 at IoU 0.5."
    )


def evaluate_plan(
    scenes: List[SceneSpec],
    out: Path,
    settings: EvalSettings,
    table: str,
    command: str,
    figure_views: int = 3,
    runs: Optional[Dict[Path, LoadedRun]] = None,
) -> Dict[str, Path]:
    """Evaluate every scene, then write ``out/table_<kind>.md|csv``, ``out/metrics.json`` and ``out/detections.png``.

    ``runs``: already loaded runs by config path (optional; see :func:`evaluate_scene`).
    """
    for scene in scenes:
        check_scene(scene, settings.min_box_pixels)
    out = Path(out)
    results = [evaluate_scene(scene, out / "work", settings, runs) for scene in scenes]
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
                    }
                    for r in rows
                ],
            },
            indent=2,
            default=str,
        )
    )
    return {"markdown": md, "csv": csv_path, "figure": figure, "metrics": metrics_json}


MERGE_FREE_SETTINGS = ("reuse", "detectors_from", "rays_per_chunk")
"""Settings that may differ between evaluations merged into one table (they change where results come from or how
fast, not how they are scored)."""


def merge_evaluations(metrics_files: List[Path], out: Path, table: str, command: str) -> Tuple[Path, Path]:
    """One Table III (or IV) from several evaluations' ``metrics.json`` (e.g. one per lighting, run at different
    times): refused when they were scored with different settings or give the same (scene, lighting, method) twice.
    The footer lists each evaluation's command."""
    rows: List[ResultRow] = []
    reference: Optional[Dict[str, object]] = None
    commands = []
    for path in metrics_files:
        data = json.loads(Path(path).read_text())
        settings = {k: v for k, v in data["settings"].items() if k not in MERGE_FREE_SETTINGS}
        if reference is None:
            reference = settings
        elif settings != reference:
            changed = sorted(k for k in set(settings) | set(reference) if settings.get(k) != reference.get(k))
            raise ValueError(f"{path}: scored with other settings than {metrics_files[0]} ({', '.join(changed)})")
        commands.append(f"`{data['command']}`")
        for r in data["results"]:
            fields = {k: r[k] for k in DetectionMetrics.__dataclass_fields__}
            rows.append(ResultRow(r["scene"], r["lighting"], r["method"], DetectionMetrics(**fields), r.get("step")))
    keys = [(r.scene, r.lighting, r.method) for r in rows]
    repeated = sorted({k for k in keys if keys.count(k) > 1})
    if repeated:
        raise ValueError(f"the evaluations give these rows more than once: {repeated}")
    footer = machine_note(command) + "  \nMerged from: " + "; ".join(commands) + "."
    return write_tables(rows, out, table, f"table_{table.lower()}", footer=footer)

