"""``agrinerf-demo``: the whole product on a built-in scene, as a user runs it.

Synthesise an orchard capture at dusk, process it into a tri-modal dataset with fruit masks from the built-in maker
(``--fruit-mask-maker auto``: fruit colour on lit frames, thermal blobs on dark ones), train ``agrinerf-lite`` and its
fruit head with ``ns-train``, score the held-out views as ``agrinerf-bench`` does
(:func:`agrinerf_ns.checkpoint_eval.evaluate_checkpoint`: against the captured frames, against the clean truth after
exposure alignment, and the thermal outputs against the rescaled thermal frames), count the fruit with
``agrinerf-count`` and score the count against the capture's true fruit, draw a labelled contact sheet of those views
beside the fruit map (``demo.png``), and print the commands that count a user's own run, open this one in Nerfstudio's
viewer and render a video of it.
"""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import time
from contextlib import contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Dict, Iterator, List, Mapping, Optional, Sequence

import numpy as np
import tyro
from rich.console import Console
from rich.table import Table

from agrinerf_ns.contact_sheet import Box, ColourScale, Column, brighten, display_gain
from agrinerf_ns.dataset_format import TRANSFORMS
from agrinerf_ns.demo_fruit import FruitCount, count_caption, count_fruit, side_by_side

if TYPE_CHECKING:
    from agrinerf_ns.ns_commands import TrainRun

CONSOLE = Console()

THERMAL_SCALE = ColourScale("rescaled thermal, 8-bit DN (Fieldscale-style: relative, not degrees C)", 0.0, 255.0)
"""The colour scale of the thermal frames and of the model's thermal outputs (which are fit to them, x255)."""


@dataclass
class DemoConfig:
    """Run synth -> process -> ns-train agrinerf-lite -> evaluation -> contact sheet on a built-in scene."""

    out: Path = Path("outputs/demo")
    """Everything is written here (raw capture, dataset, run, metrics, contact sheet)."""
    scene: str = "orchard"
    """orchard or garden."""
    lighting: str = "dusk"
    """bright, shadowed, dusk or dark. Dusk by default: poor light in which the fruit head counts (docs/count.md);
    in the dark the RGB twin is shown at a display exposure (rgb_display) and the fruit are counted from the thermal
    bodies (--path bodies: docs/count.md)."""
    views: int = 24
    """Frames along the row."""
    width: int = 96
    """RGB width (height is 3/4 of it)."""
    steps: int = 600
    """Training steps of agrinerf-lite (a few minutes on a 2-core CPU)."""
    seed: int = 0
    """Scene seed."""
    sheet_views: int = 3
    """Held-out views on the contact sheet (evenly spaced over the eval split)."""
    video_steps: int = 4
    """Frames between consecutive training cameras in the printed ``ns-render interpolate`` command."""
    fruit_mask_maker: str = "auto"
    """The built-in maker of the fruit masks that train the fruit head (agrinerf-process --fruit-mask-maker): auto takes
    the thermal blobs on dark frames and the fruit colour on lit ones."""


@dataclass
class Metric:
    """One number of the demo, with what it compares."""

    key: str
    """Key in :func:`agrinerf_ns.checkpoint_eval.evaluate_checkpoint`'s result."""
    name: str
    compares: str
    unit: str
    value: Optional[float]
    """None when unavailable (then ``note`` says why)."""
    note: str = ""


_AGREEMENT = "cross-spectral `thermal` output vs rescaled thermal frames: agreement, not accuracy"
METRIC_LABELS = (
    ("psnr_clean", "PSNR", "RGB render vs clean truth, exposure-aligned (as agrinerf-bench)", "dB"),
    ("ssim_clean", "SSIM", "RGB render vs clean truth, exposure-aligned (as agrinerf-bench)", ""),
    ("psnr", "PSNR", "RGB render vs captured held-out frames (as ns-eval; dark and noisy)", "dB"),
    ("ssim", "SSIM", "RGB render vs captured held-out frames (as ns-eval)", ""),
    ("lpips", "LPIPS", "RGB render vs captured held-out frames (as ns-eval)", ""),
    ("thermal_camera_psnr", "PSNR", "thermal-camera output vs rescaled thermal frames", "dB"),
    ("thermal_camera_ssim", "SSIM", "thermal-camera output vs rescaled thermal frames", ""),
    ("thermal_psnr", "PSNR", _AGREEMENT, "dB"),
    ("thermal_ssim", "SSIM", _AGREEMENT, ""),
)
"""(key, name, what it compares, unit), in the order shown. Rows whose key the evaluation lacks are left out."""

CROSS_SPECTRAL_NOTE = "a blend of thermal, RGB luma and events by design (docs/model.md, Losses)"


def lpips_unavailable_reason() -> str:
    """Why LPIPS is NaN: the one-line reason shown instead of the number."""
    from agrinerf_ns import compat

    if compat.lpips_shim_needed():
        return (
            f"unavailable: its AlexNet weights ({compat.ALEXNET_WEIGHTS}) are not in "
            f"{compat.alexnet_weights_path().parent} and nothing is downloaded (README, Offline use)"
        )
    return "unavailable: the metric returned NaN"


def labelled_metrics(results: Mapping[str, object]) -> List[Metric]:
    """The evaluation's numbers with what each compares; LPIPS without a value carries its reason."""
    rows = []
    for key, name, compares, unit in METRIC_LABELS:
        if key not in results:
            continue
        value = float(results[key])  # type: ignore[arg-type]
        note = CROSS_SPECTRAL_NOTE if key.startswith("thermal_") and not key.startswith("thermal_camera") else ""
        if not math.isfinite(value):
            reason = lpips_unavailable_reason() if key == "lpips" else "unavailable: not finite on any held-out view"
            rows.append(Metric(key, name, compares, unit, None, reason))
        else:
            rows.append(Metric(key, name, compares, unit, value, note))
    return rows


@dataclass
class HeldOutView:
    """What the contact sheet shows of one held-out view, as numpy arrays at the RGB resolution."""

    name: str
    captured: np.ndarray
    """(H, W, 3) sRGB in [0, 1]: the captured frame."""
    truth: np.ndarray
    """(H, W, 3) sRGB in [0, 1]: the clean truth."""
    outputs: Dict[str, np.ndarray]
    """The model's outputs: ``rgb`` (H, W, 3); ``thermal``, ``thermal_camera``, ``temperature`` (H, W) when present."""
    thermal_frame: Optional[np.ndarray] = None
    """(H, W) in [0, 1], NaN outside the thermal camera's view, or None (no thermal frames)."""


OPTIONAL_OUTPUTS = (
    ("thermal_camera", "AgriNeRF thermal-camera output (fit to the thermal frames)"),
    ("thermal", "AgriNeRF cross-spectral `thermal` output (the AgriNeRF paper's)"),
)
"""Thermal outputs drawn when the model renders them, on :data:`THERMAL_SCALE`, in this order."""


def sheet_columns(views: Sequence[HeldOutView], found: Optional[Mapping[str, Sequence[Box]]] = None) -> List[Column]:
    """The contact sheet's columns for ``views``: captured RGB, the same brightened for display, the RGB render
    exposure-aligned to the clean truth, the clean truth, the thermal frame, the thermal outputs and ``temperature``
    when the model renders them. ``found`` (view name -> boxes), when given, is drawn on the render columns."""
    import torch

    from agrinerf_ns.image_metrics import exposure_align

    gain = display_gain(np.concatenate([v.captured for v in views], axis=0))
    aligned = [
        exposure_align(torch.from_numpy(v.outputs["rgb"]).float(), torch.from_numpy(v.truth).float()).numpy()
        for v in views
    ]
    boxes = [list(found.get(v.name, ())) for v in views] if found is not None else None
    columns = [
        Column("captured RGB (held-out frame, as recorded)", [v.captured for v in views]),
        Column(
            f"the same frame x{gain:.0f} in linear light, brightened for display only",
            [brighten(v.captured, gain) for v in views],
        ),
        Column("AgriNeRF RGB render, exposure-aligned to the clean truth", aligned, boxes=boxes),
        Column("clean truth (synthetic, never trained on)", [v.truth for v in views]),
    ]
    thermal_frames = [v.thermal_frame for v in views if v.thermal_frame is not None]
    if len(thermal_frames) == len(views):
        frames = [255.0 * frame for frame in thermal_frames]
        columns.append(Column("thermal frame (captured, rescaled; grey: outside its view)", frames, THERMAL_SCALE))
    for key, title in OPTIONAL_OUTPUTS:
        if all(key in v.outputs for v in views):
            columns.append(Column(title, [255.0 * v.outputs[key] for v in views], THERMAL_SCALE, boxes=boxes))
    if all("temperature" in v.outputs for v in views):
        values = np.concatenate([v.outputs["temperature"].ravel() for v in views])
        low, high = np.nanpercentile(values, [1, 99]) if np.isfinite(values).any() else (0.0, 1.0)
        scale = ColourScale("temperature, degrees C", float(low), float(max(high, low + 1e-3)), "magma")
        columns.append(Column("AgriNeRF temperature (degrees C)", [v.outputs["temperature"] for v in views], scale))
    return columns


def render_held_out(config_path: Path, raw: Path, max_views: int) -> List[HeldOutView]:
    """Render ``max_views`` evenly spaced eval views of a trained run with every output its model has, beside the
    captured frames and the clean truth."""
    from agrinerf_ns.checkpoint_eval import TruthImages
    from agrinerf_ns.run_loading import load_run, render_camera
    from agrinerf_ns.views import evenly_spaced

    run = load_run(config_path)
    dataset = run.pipeline.datamanager.eval_dataset
    names = [Path(p).name for p in dataset._dataparser_outputs.image_filenames]
    truth = TruthImages(raw)
    views = []
    for index in evenly_spaced(len(names), max_views):
        outputs = {k: v.detach().cpu().float().numpy() for k, v in render_camera(run, dataset, index).items()}
        outputs = {k: (v[..., 0] if v.shape[-1] == 1 else v) for k, v in outputs.items()}
        data = dataset[index]
        thermal = None
        if "thermal" in data:
            thermal = data["thermal"][..., 0].numpy().astype(np.float32)
            if "thermal_mask" in data:
                thermal = np.where(data["thermal_mask"][..., 0].numpy() > 0.5, thermal, np.nan)
        captured = data["image"][..., :3].numpy().astype(np.float32)
        views.append(HeldOutView(names[index], captured, truth.get(names[index]).numpy(), outputs, thermal))
    del run
    return views


def _command_path(name: str) -> str:
    """How to type ``name`` (an ``ns-*`` script of this environment): bare when PATH finds this one, else its path."""
    local = Path(sys.executable).parent / name
    if not local.exists():
        return name
    found = shutil.which(name)
    if found is not None and Path(found).resolve() == local.resolve():
        return name
    try:
        return os.path.relpath(local)
    except ValueError:
        return str(local)


def follow_up_commands(config_path: Path, out: Path, video_steps: int) -> Dict[str, str]:
    """The commands that open the run in Nerfstudio's viewer and render a video flying along the training path."""
    return {
        "viewer": f"{_command_path('ns-viewer')} --load-config {config_path}",
        "video": (
            f"{_command_path('ns-render')} interpolate --load-config {config_path} --pose-source train "
            f"--interpolation-steps {video_steps} --rendered-output-names rgb_display thermal "
            f"--output-path {out / 'video.mp4'}"
        ),
    }


@dataclass
class DemoResult:
    """What the demo made (also written to ``summary.json``)."""

    config: str
    contact_sheet: str
    picture: str
    """The contact sheet beside the fruit map."""
    count: FruitCount
    metrics: List[Metric]
    stage_seconds: Dict[str, Optional[float]]
    """Wall seconds per stage; None for a stage skipped because its output was already there."""
    commands: Dict[str, str]
    train: Dict[str, float] = field(default_factory=dict)


@contextmanager
def _timed(stages: Dict[str, Optional[float]], name: str) -> Iterator[None]:
    start = time.perf_counter()
    yield
    stages[name] = time.perf_counter() - start


def _fmt(metric: Metric) -> str:
    if metric.value is None:
        return metric.note
    number = f"{metric.value:.2f} {metric.unit}".strip() if metric.unit else f"{metric.value:.3f}"
    return f"{number} ({metric.note})" if metric.note else number


def _caption(metrics: List[Metric], steps: int, device: str) -> str:
    by_key = {m.key: m for m in metrics}
    parts = [f"agrinerf-lite, {steps} steps on the {device}."]
    for key, text in (
        ("psnr_clean", "RGB vs clean truth (exposure-aligned)"),
        ("psnr", "RGB vs captured frames"),
        ("thermal_camera_psnr", "thermal-camera output vs thermal frames"),
        ("thermal_psnr", "cross-spectral output vs thermal frames (a blend by design)"),
    ):
        if key in by_key and by_key[key].value is not None:
            parts.append(f"{text}: {by_key[key].value:.2f} dB.")
    parts.append("Mean PSNR over all held-out views.")
    return " ".join(parts)


TRAIN_PROGRESS_SAVES = 10
"""Checkpoints written during training (every tenth of the steps): the demo reports its progress from them."""


def train_with_progress(config: DemoConfig, data: Path) -> "TrainRun":
    """``ns-train agrinerf-lite`` on ``data``, its progress reported from the checkpoints it writes every tenth of the
    steps (ns-train's own output goes to its log)."""
    from concurrent.futures import ThreadPoolExecutor

    from agrinerf_ns.ns_commands import checkpoints, ns_train
    from agrinerf_ns.progress import work_progress

    every = max(1, config.steps // TRAIN_PROGRESS_SAVES)
    run_dir = config.out / "runs"
    config_path = run_dir / "demo" / "agrinerf-lite" / "run" / "config.yml"
    with ThreadPoolExecutor(1) as pool, work_progress(f"training {config.steps} steps", config.steps) as progress:
        future = pool.submit(ns_train, "agrinerf-lite", data, run_dir, "demo", config.steps, steps_per_save=every)
        while not future.done():
            time.sleep(1.0)
            saved = [step + 1 for step, _ in checkpoints(config_path)] if config_path.exists() else []
            if saved and max(saved) > progress.done:
                progress.advance(max(saved) - progress.done)
        return future.result()


def _print_summary(
    config: DemoConfig,
    results: Mapping[str, object],
    metrics: List[Metric],
    stages: Dict[str, Optional[float]],
    count: FruitCount,
    run_config: Path,
    picture: Path,
    sheet: Path,
) -> Dict[str, str]:
    """The demo's closing screen: the held-out metrics, the stages' wall times, the count and the commands for the
    user's own run (returned: viewer and video)."""
    held_out = int(results.get("eval_views", 0))  # type: ignore[call-overload]
    table = Table("metric", "compares", "value", title=f"agrinerf-lite on the {config.lighting} {config.scene}, "
                  f"mean of {held_out} held-out views", title_justify="left")  # fmt: skip
    for metric in metrics:
        table.add_row(metric.name, metric.compares, _fmt(metric))
    CONSOLE.print(table)
    times = Table("stage", "wall time", title="wall time per stage", title_justify="left")
    for name, seconds in stages.items():
        times.add_row(name, "reused (already there)" if seconds is None else f"{seconds:.1f} s")
    CONSOLE.print(times)
    commands = follow_up_commands(run_config, config.out, config.video_steps)
    CONSOLE.print(count_caption(count, config.lighting), soft_wrap=True)
    CONSOLE.print(f"contact sheet and fruit map: {picture} (the sheet alone: {sheet})", soft_wrap=True)
    CONSOLE.print(
        f"count the fruit of your own run (add --truth RAW for a synthetic capture's score):\n"
        f"  {_command_path('agrinerf-count')} --config outputs/<experiment>/agrinerf-lite/<time>/config.yml "
        f"--out count/\n(this run: {count.command})",
        soft_wrap=True,
    )
    CONSOLE.print(
        f"open this run in the viewer (then the address it prints, http://localhost:7007 by default):\n"
        f"  {commands['viewer']}",
        soft_wrap=True,
    )
    video_note = "" if shutil.which("ffmpeg") else " (needs ffmpeg on PATH: apt-get install ffmpeg)"
    CONSOLE.print(f"render a video of it{video_note}:\n  {commands['video']}", soft_wrap=True)

    return commands


def main(config: DemoConfig) -> DemoResult:
    from agrinerf_ns import compat
    from agrinerf_ns.checkpoint_eval import TruthImages, evaluate_checkpoint
    from agrinerf_ns.contact_sheet import write_contact_sheet
    from agrinerf_ns.method_configs.agrinerf_methods import default_device_type
    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.synth import SynthConfig, generate_capture

    compat.activate()  # LPIPS offline, checkpoint loading, an ffmpeg on PATH (as every ns-* command has them)
    raw, data = config.out / "raw", config.out / "orchard"
    stages: Dict[str, Optional[float]] = {"agrinerf-synth": None, "agrinerf-process": None}
    started = time.perf_counter()
    if (raw / "calib.yaml").exists():
        CONSOLE.print(f"reusing the raw capture in {raw} (delete it to synthesise again)", soft_wrap=True)
    else:
        CONSOLE.rule("1/6 agrinerf-synth")
        synth = SynthConfig(scene=config.scene, lighting=config.lighting, seed=config.seed, views=config.views,
                            width=config.width, height=config.width * 3 // 4)  # fmt: skip
        with _timed(stages, "agrinerf-synth"):
            generate_capture(synth, raw, progress=True)
    if (data / TRANSFORMS).exists():
        CONSOLE.print(f"reusing the dataset in {data} (delete it to process again)", soft_wrap=True)
    else:
        CONSOLE.rule(f"2/6 agrinerf-process (fruit masks: --fruit-mask-maker {config.fruit_mask_maker})")
        with _timed(stages, "agrinerf-process"):
            maker = config.fruit_mask_maker
            settings = ProcessConfig(poses="given", overwrite=True, fruit_mask_maker=maker)  # type: ignore[arg-type]
            process_capture(raw, data, settings)
    CONSOLE.rule(f"3/6 ns-train agrinerf-lite ({config.steps} steps, with the fruit head)")
    with _timed(stages, "ns-train agrinerf-lite"):
        run = train_with_progress(config, data)
    CONSOLE.print(f"trained in {run.wall_s:.0f} s ({run.s_per_step:.3f} s/step, peak {run.peak_rss_mb:.0f} MiB)")
    CONSOLE.rule("4/6 evaluation of the held-out views (as agrinerf-bench)")
    step = run.checkpoints()[-1][0]
    with _timed(stages, "evaluation (held-out views)"):
        results = evaluate_checkpoint(run.config, step, "rgb", TruthImages(raw))
    metrics = labelled_metrics(results)
    CONSOLE.rule("5/6 agrinerf-count, scored against the capture's true fruit")
    with _timed(stages, "agrinerf-count"):
        count = count_fruit(run.config, raw, config.out / "count")
    CONSOLE.rule("6/6 contact sheet and fruit map")
    sheet, picture = config.out / "contact_sheet.png", config.out / "demo.png"
    with _timed(stages, "contact sheet (render + draw)"):
        views = render_held_out(run.config, raw, config.sheet_views)
        write_contact_sheet(
            sheet_columns(views),
            [v.name for v in views],
            sheet,
            title=f"agrinerf-demo: the synthetic {config.lighting} {config.scene}, held-out views (not trained on)",
            caption=_caption(metrics, config.steps, default_device_type().upper()),
            row_prefix="held-out",
        )
        side_by_side(sheet, Path(count.folder) / "fruit_map.png", picture, count_caption(count, config.lighting))
    stages["total"] = time.perf_counter() - started

    commands = _print_summary(config, results, metrics, stages, count, run.config, picture, sheet)

    result = DemoResult(
        config=str(run.config),
        contact_sheet=str(sheet),
        picture=str(picture),
        count=count,
        metrics=metrics,
        stage_seconds=stages,
        commands=commands,
        train={"steps": config.steps, "s_per_step": run.s_per_step, "peak_rss_mb": run.peak_rss_mb},
    )
    (config.out / "summary.json").write_text(json.dumps(asdict(result), indent=2))
    return result


def entrypoint() -> None:
    """Console script ``agrinerf-demo``."""
    main(tyro.cli(DemoConfig))


if __name__ == "__main__":
    entrypoint()
