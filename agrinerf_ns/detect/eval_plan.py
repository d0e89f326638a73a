"""What a detection evaluation scores: scenes and their methods (read from a plan file or an ``agrinerf-bench``
output folder by :mod:`agrinerf_ns.lab.paper_plan`).

A plan lists scenes (raw capture with ``truth/``, processed dataset) and, per scene, the methods to score: a trained
run (``config``) or a folder of rendered held-out views (``renders``), the output rendered, and the detector used.
:func:`check_scene` refuses a scene that cannot be scored before anything is rendered or trained.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Literal, Optional

from agrinerf_ns.detect.boxes import SceneTruth, list_images
from agrinerf_ns.detect.render_views import MissingOutputError, Output

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
