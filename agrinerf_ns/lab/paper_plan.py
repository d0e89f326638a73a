"""The plans of ``agrinerf-detect evaluate``: the scenes and methods to score, read from a plan file
(:func:`load_plan`) or an ``agrinerf-bench`` output folder (:func:`plan_from_bench`), as
:class:`~agrinerf_ns.detect.eval_plan.SceneSpec` lists.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List, Optional, Tuple

from agrinerf_ns.detect.eval_plan import DetectorInput, MethodSpec, SceneSpec
from agrinerf_ns.detect.render_views import Output
from agrinerf_ns.lab.layout import BenchLayout, split_scene
from agrinerf_ns.lab.methods import ABLATIONS, METHODS
from agrinerf_ns.modalities import TABLE_IV_ABLATIONS


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
    """The plan for an ``agrinerf-bench`` output folder (:mod:`agrinerf_ns.lab.layout`): every scene's finished runs
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
