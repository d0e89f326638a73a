"""Fruit counted from the trained field itself, in 3D: the field sampled on a grid over the scene's occupied box
(:mod:`agrinerf_ns.count.volume`), fruit voxels grouped into fruit (:mod:`agrinerf_ns.count.components`), scored and
written as the view path writes its count (fruits.csv, fruits.ply, fruit_map.png, count.json, score.md)."""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any, Dict, Optional, Tuple

import numpy as np
import tyro

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.count.components import ComponentConfig, find_fruit
from agrinerf_ns.count.fruit_score import read_truth_fruit
from agrinerf_ns.count.pipeline import CONSOLE, CountConfig, CountResult, raw_training_frames, score_result, write_count
from agrinerf_ns.count.render import CountInputError, WorldFrame, relative_path
from agrinerf_ns.count.row_range import fruit_in_range
from agrinerf_ns.count.sources import SourceChoice, field_outputs, resolve_source
from agrinerf_ns.count.volume import SampledField, VolumeConfig, render_depth_views, sample_field

if TYPE_CHECKING:
    from agrinerf_ns.run_loading import LoadedRun


@dataclass(frozen=True)
class FieldCountConfig:
    """How fruit are found in the field."""

    source: SourceChoice = "auto"
    """The output fruit are told apart by: fruit (the fruit head), temperature, thermal_camera, thermal
    (cross-spectral), rgb; auto: the first of the last four the run has (RGB only when it has no thermal output, and
    the count says so; :mod:`agrinerf_ns.count.sources`)."""
    volume: Annotated[VolumeConfig, tyro.conf.arg(name="")] = field(default_factory=VolumeConfig)
    components: Annotated[ComponentConfig, tyro.conf.arg(name="")] = field(default_factory=ComponentConfig)
    seen_margin: float = 0.05
    """A voxel is seen by a view when it lies at most this far (dataset units) behind the view's rendered depth."""


def count_model(
    model: Any,
    cameras: Any,
    frame: WorldFrame,
    config: FieldCountConfig,
    box: Optional[np.ndarray] = None,
) -> Tuple[CountResult, SampledField, Dict[str, Any]]:
    """Count the fruit of ``model`` (an AgriNeRF model: ``model.field`` and its heads), seen from ``cameras`` (its
    training cameras; None: every dense voxel counts as seen); ``box``: the Nerfstudio-frame box to sample (None:
    the occupied box of the rendered views)."""
    source, note = resolve_source(config.source, "field", field_outputs(model))
    start = time.perf_counter()
    views = render_depth_views(model, cameras, config.volume) if cameras is not None else []
    rendered = time.perf_counter()
    sampled = sample_field(model, views, frame, source, config.volume, config.seen_margin * frame.scale,
                           config.components.max_diameter * frame.scale, box, note)  # fmt: skip
    sampled_at = time.perf_counter()
    fruit, stats = find_fruit(sampled, config.components)
    info = {
        "path": "field",
        "source": source,
        "source_note": note,
        "views_rendered": len(views),
        "grid_shape": list(sampled.grid.shape),
        "voxel_size": sampled.grid.step / frame.scale,
        "box_ns": (sampled.grid.origin - sampled.grid.step / 2).tolist()
        + (sampled.grid.origin + (np.array(sampled.grid.shape) - 0.5) * sampled.grid.step).tolist(),
        "dense_voxels": sampled.dense,
        "seen_voxels": int(len(sampled.flat)),
        **stats,
        "seconds": {"render_views": rendered - start, "sample_field": sampled_at - rendered,
                    "components": time.perf_counter() - sampled_at},
    }  # fmt: skip
    if not sampled.dense:  # a field without geometry (e.g. trained on thermal frames alone) counts nothing, and says so
        info["warning"] = (
            f"no voxel of the field reaches the density threshold {config.volume.density_threshold:g}: the field has "
            "no surface to count fruit on (a run trained without RGB frames may have none at this budget)"
        )
    return CountResult(fruit, [], [], 0.0), sampled, info


def run_field_count(
    run: Path,
    out: Path,
    config: FieldCountConfig = FieldCountConfig(),
    truth: Optional[Path] = None,
    overwrite: bool = False,
    score: CountConfig = CountConfig(),
    loaded: Optional["LoadedRun"] = None,
) -> Tuple[CountResult, Dict[str, Any]]:
    """Count the fruit of the trained run at ``run`` (folder or config.yml) in 3D and write ``out`` atomically; with
    ``truth`` (a synthetic capture) also score it (``score``: match distance, alignment, visibility); ``loaded``: the
    run already loaded (``agrinerf_ns.run_loading.load_run``)."""
    from agrinerf_ns.run_loading import load_run, trained_run_config

    config_path = trained_run_config(run)
    out = Path(out)
    if out.exists() and any(out.iterdir()) and not overwrite:
        raise FileExistsError(f"{out}: output folder exists and is not empty (pass --overwrite to replace it)")
    if truth is not None:
        read_truth_fruit(truth)  # fail before loading
    frame = WorldFrame.read(config_path.parent / "dataparser_transforms.json")
    loaded = loaded if loaded is not None else load_run(config_path)
    model = loaded.pipeline.model
    model.eval()
    datamanager = loaded.pipeline.datamanager
    cameras = datamanager.train_dataset.cameras
    result, sampled, info = count_model(model, cameras, frame, config)
    if info["source"] == "rgb":
        CONSOLE.print(f"[yellow]Counting from RGB: {info['source_note']}", soft_wrap=True)
    if "warning" in info:
        CONSOLE.print(f"[yellow]{config_path}: {info['warning']}", soft_wrap=True)
    cameras_ds = frame.to_dataset(cameras.camera_to_worlds[:, :3, 3].cpu().numpy().astype(np.float64))
    result.fruit = fruit_in_range(result.fruit, cameras_ds, score.max_range)
    dataset = loaded.dataset_dir
    if truth is not None:
        if dataset is None:
            raise CountInputError(f"{config_path}: the run does not name its dataset folder, needed to score it")
        names = [relative_path(Path(p), dataset) for p in datamanager.train_dataset.image_filenames]
        score_result(result, dataset, raw_training_frames(dataset, names), Path(truth), score, cameras_ds)
    info |= {"run": str(config_path), "method": loaded.method, "step": loaded.step, "settings": asdict(config),
             "max_range": score.max_range}  # fmt: skip
    with atomic_output_dir(out, overwrite) as tmp:
        surface = frame.to_dataset(sampled.points()[:: max(1, len(sampled.flat) // 200_000)])
        title = f"{len(result.fruit)} fruit counted in the field on '{info['source']}', {loaded.method}"
        write_count(tmp, result, frame, surface, cameras_ds, title, info, score, truth, f"field on {info['source']}")
    s = result.score
    CONSOLE.print(
        f"[bold green]{len(result.fruit)} fruit[/bold green] in the field ({info['source']}) -> {out}"
        + (f"; F1 {s.f1:.2f}, count error {s.count_error:+.1%} against {s.visible} visible" if s else ""),
        soft_wrap=True,
    )
    return result, info
