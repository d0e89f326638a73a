"""Counting in ``agrinerf-bench --profile count``: every finished run of the benchmark folder counted on every source
it has, by the field path (3D) and the view path (detect and lift; placed by depth and by rays), beside the oracle's
ceiling per scene (the capture's own frames, true depth and true temperature); rows appended to ``OUT/count.csv``,
``OUT/count.md`` rewritten, each count's files under ``OUT/count/<scene>/<method>/<path>-<source>/``. Stock models
(no AgriNeRF heads) are counted by the view path alone; runs trained on the thermal camera's views (Nerfacto
(Thermal)) are not counted."""

from __future__ import annotations

import time
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Any, Dict, List, Optional, Sequence, Set, Tuple

import numpy as np

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.count.cluster import ClusterConfig
from agrinerf_ns.count.fruit_score import read_frames
from agrinerf_ns.count.pipeline import (
    CONSOLE,
    CountConfig,
    CountResult,
    count_fruit,
    detect_and_lift,
    fused_result,
    raw_training_frames,
    score_against_truth,
    score_result,
    surface_points,
)
from agrinerf_ns.count.render import WorldFrame, relative_path
from agrinerf_ns.count.sources import VIEW_ORDER, CountSource
from agrinerf_ns.lab.count_tables import append_rows, markdown, read_rows
from agrinerf_ns.lab.layout import BenchLayout, split_scene
from agrinerf_ns.lab.methods import METHODS
from agrinerf_ns.lab.results import seed_base
from agrinerf_ns.run_loading import dataset_folder

if TYPE_CHECKING:
    from agrinerf_ns.count.field_count import FieldCountConfig
    from agrinerf_ns.run_loading import LoadedRun

VIEW_SOURCES: Tuple[CountSource, ...] = VIEW_ORDER
VIEW_PLACEMENTS: Dict[str, bool] = {"views": False, "views-rays": True}
"""The view path's rows: fruit placed by the rendered depth (`views`, `agrinerf-count --path views`) and by their
detections' rays (`views-rays`, `--triangulate`: what `--path auto` takes on RGB where the RGB frames are lit), from
the same renders and detections."""
ORACLE_METHOD = "oracle"


def count_bench(layout: BenchLayout, scenes: Sequence[str], methods: Dict[str, str], seed: int, header: str) -> None:
    """Count every finished run of ``methods`` (bench key -> ns-train method) in ``scenes`` not yet in count.csv;
    rewrite count.md."""
    csv_path = Path(layout.out) / "count.csv"
    done: Set[Tuple[str, str]] = {(r["scene"], r["method"]) for r in read_rows(csv_path)}
    for scene in scenes:
        raw, data = layout.scene(scene)
        if (scene, ORACLE_METHOD) not in done and (raw / "truth" / "depth").is_dir():
            append_rows(csv_path, _oracle_rows(scene, seed, raw, data, layout))
        for key, config in layout.finished_runs(scene, methods).items():
            if (scene, key) in done:
                continue
            method = METHODS[seed_base(key)]
            if not method.views_rgb_camera:
                CONSOLE.print(f"not counted: {scene} {key} is trained on the thermal camera's views "
                              f"({method.data_file}); the count reads the RGB camera's")  # fmt: skip
                continue
            CONSOLE.print(f"counting fruit: {scene} {key}")
            append_rows(csv_path, count_run_rows(scene, key, seed, config, raw, Path(layout.out) / "count"))
    (Path(layout.out) / "count.md").write_text(markdown(read_rows(csv_path), header))
    CONSOLE.print(f"counts: {csv_path}, {Path(layout.out) / 'count.md'}")


def _row(scene: str, method: str, seed: int, step: int, path: str, source: str, result: CountResult, seconds: float):
    lighting = split_scene(scene)[1]
    s = result.score
    assert s is not None
    return {"scene": scene, "lighting": lighting, "seed": seed, "method": method, "step": step, "path": path,
            "source": source, "counted": s.counted, "visible": s.visible, "count_error": s.count_error,
            "precision": s.precision, "recall": s.recall, "f1": s.f1, "mean_match_error": s.mean_match_error,
            "mean_temperature_error": s.mean_temperature_error, "seconds": seconds}  # fmt: skip


def _oracle_rows(scene: str, seed: int, raw: Path, data: Path, layout: BenchLayout) -> List[Dict[str, Any]]:
    """The ceiling: the capture's frames with the true depth and the true temperature at RGB resolution."""
    from agrinerf_ns.count.detectors import DetectorConfig
    from agrinerf_ns.lab.count_oracle import oracle_renders

    start = time.perf_counter()
    renders = oracle_renders(raw, data, "true")
    config = CountConfig(detect=DetectorConfig(source="thermal"))
    result = count_fruit(renders, config)
    score_against_truth(renders, result, raw, config)
    rows = [_row(scene, ORACLE_METHOD, seed, 0, "oracle", "true_temperature", result, time.perf_counter() - start)]
    start = time.perf_counter()
    rows.append(_row(scene, ORACLE_METHOD, seed, 0, "oracle", "field_true_temperature",
                     oracle_field_count(raw, data, config), time.perf_counter() - start))  # fmt: skip
    return rows


def oracle_field_count(raw: Path, data: Path, config: CountConfig) -> CountResult:
    """The field path on the capture's true field (:mod:`agrinerf_ns.lab.count_oracle_field`) at the default settings."""
    from agrinerf_ns.count.components import find_fruit
    from agrinerf_ns.count.field_count import FieldCountConfig
    from agrinerf_ns.lab.count_oracle_field import oracle_field

    settings = FieldCountConfig()
    sampled = oracle_field(raw, data, settings.volume, settings.seen_margin, settings.components.max_diameter)
    result = CountResult(find_fruit(sampled, settings.components)[0], [], [], 0.0)
    frames = [f["file_path"] for f in read_frames(data)]
    score_result(result, data, raw_training_frames(data, frames), raw, config)
    return result


def count_run_rows(
    scene: str,
    method: str,
    seed: int,
    config: Path,
    raw: Path,
    out: Path,
    field_config: Optional["FieldCountConfig"] = None,
) -> List[Dict[str, Any]]:
    """Count one run by the field path on each source it has and by the view path on temperature, thermal and RGB
    (those it renders); score each against ``raw``'s truth and keep its files under ``out/<scene>/<method>/``.
    ``field_config``: the field path's `FieldCountConfig` (None: its defaults)."""
    from agrinerf_ns.count.field_count import FieldCountConfig
    from agrinerf_ns.count.sources import field_outputs
    from agrinerf_ns.run_loading import load_run, trained_run_config

    config = trained_run_config(config)
    frame = WorldFrame.read(config.parent / "dataparser_transforms.json")
    loaded = load_run(config)
    model = loaded.pipeline.model
    model.eval()
    datamanager = loaded.pipeline.datamanager
    dataset = dataset_folder(Path(datamanager.config.data))
    names = [relative_path(Path(p), dataset) for p in datamanager.train_dataset.image_filenames]
    train = raw_training_frames(dataset, names)
    rows: List[Dict[str, Any]] = []
    folder = out / scene / method
    sources: List[str] = list(field_outputs(model).available())
    if sources:
        field_config = FieldCountConfig() if field_config is None else field_config
        rows += _field_rows(scene, method, seed, loaded.step, model, sources, datamanager.train_dataset.cameras,
                            frame, field_config, dataset, train, raw, folder)  # fmt: skip
    else:  # a stock model (nerfacto, tensorf): no AgriNeRF heads to sample
        CONSOLE.print(f"{scene} {method}: the model has no field heads the field path reads; view path only")
    rows += _view_rows(scene, method, seed, loaded, raw, folder)
    return rows


def _field_rows(
    scene: str,
    method: str,
    seed: int,
    step: int,
    model: Any,
    sources: List[str],
    cameras: Any,
    frame: WorldFrame,
    field_config: "FieldCountConfig",
    dataset: Path,
    train: List[str],
    raw: Path,
    folder: Path,
) -> List[Dict[str, Any]]:
    """The field path's rows, one per source in ``sources`` (those the model has; the density sampling shared)."""
    from agrinerf_ns.count.components import find_fruit
    from agrinerf_ns.count.field_count import count_model

    score = CountConfig()
    rows: List[Dict[str, Any]] = []
    start = time.perf_counter()
    result, sampled, info = count_model(model, cameras, frame, field_config)
    shared = time.perf_counter() - start - info["seconds"]["components"]
    sampled_first = sampled.source
    centres = frame.to_dataset(cameras.camera_to_worlds[:, :3, 3].cpu().numpy())
    surface = frame.to_dataset(sampled.points()[:: max(1, len(sampled.flat) // 200_000)])
    for source in sources:
        begin = time.perf_counter()
        if source != sampled.source:
            sampled = sampled.with_source(model, source)
            fruit, stats = find_fruit(sampled, field_config.components)
            result = CountResult(fruit, [], [], 0.0)
            info = info | stats | {"source": source}
        score_result(result, dataset, train, raw, score)
        # the depth renders and the density sampling are shared; each source adds its features and components
        own = info["seconds"]["components"] if source == sampled_first else time.perf_counter() - begin
        seconds = shared + own
        rows.append(_row(scene, method, seed, step, "field", source, result, seconds))
        _write(folder / f"field-{source}", result, frame, surface, centres, info, score, raw)
    return rows


def _view_rows(scene: str, method: str, seed: int, loaded: "LoadedRun", raw: Path, folder: Path):
    """The view path's rows: every view of the loaded run rendered once, each source detected once and placed both
    ways."""
    from agrinerf_ns.count.detectors import DetectorConfig
    from agrinerf_ns.count.render import render_loaded_run

    config, step = loaded.config_path, loaded.step
    rows: List[Dict[str, Any]] = []
    start = time.perf_counter()
    renders = render_loaded_run(loaded)
    rendered = time.perf_counter() - start
    view_cameras = renders.frame.to_dataset(np.stack([v.origins[0, 0] for v in renders.views]))
    view_surface = surface_points(renders)  # under every view count's fruit map
    for source in VIEW_SOURCES:
        if not renders.outputs().has(source):  # a run without that output (rgb: trained on thermal alone)
            continue
        begin = time.perf_counter()
        lifted, per_view = detect_and_lift(renders, DetectorConfig(source=source))  # once for both placements
        detected = time.perf_counter() - begin
        for path, triangulate in VIEW_PLACEMENTS.items():
            begin = time.perf_counter()
            view_config = CountConfig(
                detect=DetectorConfig(source=source), cluster=ClusterConfig(triangulate=triangulate)
            )
            result = fused_result(lifted, per_view, renders, view_config.cluster)
            score_against_truth(renders, result, raw, view_config)
            rows.append(_row(scene, method, seed, step, path, source, result,
                             rendered + detected + time.perf_counter() - begin))  # fmt: skip
            _write(folder / f"{path}-{source}", result, renders.frame, view_surface, view_cameras,
                   {"path": path, "source": source, "run": str(config), "cluster": asdict(view_config.cluster)},
                   view_config, raw)  # fmt: skip
    return rows


def _write(folder: Path, result: CountResult, frame: WorldFrame, surface, cameras, info, config, raw: Path) -> None:
    from agrinerf_ns.count.pipeline import write_count

    folder.parent.mkdir(parents=True, exist_ok=True)
    with atomic_output_dir(folder, True) as tmp:
        title = f"{len(result.fruit)} fruit, {info.get('path')} path on '{info.get('source')}'"
        write_count(tmp, result, frame, surface, cameras, title, info, config, raw, f"{info.get('path')}")


def run_note(command: str) -> str:
    """Command, machine, threads and load, for the head of count.md."""
    import os

    from agrinerf_ns.machine import machine_note

    load = ", ".join(f"{v:.1f}" for v in os.getloadavg())
    threads = os.environ.get("OMP_NUM_THREADS", "unset")
    return f"Command: `{command}`\n\n{machine_note()}; {os.cpu_count()} cores, OMP_NUM_THREADS={threads}, load {load}."
