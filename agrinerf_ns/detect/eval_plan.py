"""What an evaluation scores: scenes and their methods, from a plan file or an ``agrinerf-bench`` output folder.

A plan lists scenes (raw capture with ``truth/``, processed dataset) and, per scene, the methods to score: a trained
run (``config``) or a folder of rendered held-out views (``renders``), the output rendered, and the detector used.
:func:`check_scene` refuses a scene that cannot be scored before anything is rendered or trained.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Literal, Optional, Tuple

from agrinerf_ns.bench.layout import BenchLayout, split_scene
from agrinerf_ns.bench.methods import ABLATIONS, METHODS
from agrinerf_ns.detect.boxes import SceneTruth, list_images
from agrinerf_ns.detect.render_views import MissingOutputError, Output
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


BenchRows = Dict[str, List[Tuple[str, Output, Optional[DetectorInput]]]]

BENCH_METHODS: BenchRows = {
    "nerfacto": [("Nerfacto (RGB)", "rgb", None)],
    "nerfacto-thermal": [("Nerfacto (Thermal)", "rgb", "thermal")],
    "tensorf": [("TensoRF (RGB)", "rgb", None)],
    "agrinerf-lite": [("Ours-lite (RGB)", "rgb", None), ("Ours-lite (Cross-Spectral)", "thermal", None)],
    "agrinerf": [("Ours (RGB)", "rgb", None), ("Ours (Cross-Spectral)", "thermal", None)],
}
"""agrinerf-bench method key -> the detection rows it gives (label, rendered output, detector)."""

BENCH_ABLATIONS: BenchRows = {
    **{
        key: [(f"Ours ({name})", "thermal" if "thermal" in TABLE_IV_ABLATIONS[name] else "rgb", None)]
        for key, name in ABLATIONS.items()
    },
    "agrinerf-lite": [("Ours (All)", "thermal", None)],
}
"""Table IV from agrinerf-bench's AgriNeRF-lite ablations: the cross-spectral rendering where the ablation learns from
thermal frames, else the RGB one (RGB, RGB+Events)."""


def plan_from_bench(bench_out: Path, table: str = "III") -> List[SceneSpec]:
    """The plan for an ``agrinerf-bench`` output folder (:mod:`agrinerf_ns.bench.layout`): every scene's finished runs
    (with a checkpoint) of a known method. Table "IV": the scenes with modality ablations (``lite-ablation-*`` runs),
    one row per ablation."""
    known = BENCH_ABLATIONS if table == "IV" else BENCH_METHODS
    layout = BenchLayout(Path(bench_out))
    scenes = []
    for scene in layout.run_scenes():
        if table == "IV" and not layout.has_runs(scene, list(ABLATIONS)):
            continue
        configs = layout.finished_runs(scene, {key: METHODS[key].ns_method for key in known})
        methods = [
            MethodSpec(label, output, config=config, detector=detector)
            for key, config in configs.items()
            for label, output, detector in known[key]
        ]
        if methods:
            name, lighting = split_scene(scene)
            raw, data = layout.scene(scene)
            scenes.append(SceneSpec(name, lighting, raw, data if data.is_dir() else None, methods))
    if not scenes:
        raise FileNotFoundError(f"{layout.runs}: no finished run of {', '.join(known)}")
    return scenes


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
            check_render_folder(m.renders, m)
        if m.detector_modality() == "thermal" and scene.dataset is None:
            raise ValueError(
                f"scene {scene.name}, {m.label}: the thermal detector is trained on the dataset's thermal frames; "
                "give the scene's processed dataset (with thermal_file_path frames)"
            )


def check_render_folder(folder: Path, method: MethodSpec) -> None:
    """A folder of renders holds views, of the output the method asks for (its ``renders.json``, where present)."""
    if not Path(folder).is_dir() or not list_images(folder):
        raise FileNotFoundError(f"{folder}: empty render folder (no .png/.jpg views) for {method.label}")
    manifest = Path(folder) / "renders.json"
    if manifest.is_file():
        rendered = json.loads(manifest.read_text()).get("output")
        if rendered != method.output:
            raise MissingOutputError(
                f"{folder}: holds '{rendered}' renders ({manifest}) but {method.label} asks for '{method.output}'"
            )
