"""``agrinerf-demo``: the whole product on a built-in scene, as a user runs it.

Synthesise a dark orchard capture, process it into a tri-modal dataset, train ``agrinerf-lite`` with ``ns-train``,
render the held-out views (RGB and thermal) with ``ns-render``, evaluate with ``ns-eval``, and write an image strip.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import List

import numpy as np
import tyro
from PIL import Image
from rich.console import Console
from rich.table import Table

CONSOLE = Console()


@dataclass
class DemoConfig:
    """Run synth -> process -> ns-train agrinerf-lite -> ns-render -> ns-eval on a built-in scene."""

    out: Path = Path("outputs/demo")
    """Everything is written here (raw capture, dataset, run, renders, metrics, strip)."""
    scene: str = "orchard"
    """orchard or garden."""
    lighting: str = "dark"
    """bright, shadowed, dusk or dark."""
    views: int = 24
    """Frames along the row."""
    width: int = 96
    """RGB width (height is 3/4 of it)."""
    steps: int = 600
    """Training steps of agrinerf-lite (a few minutes on a 2-core CPU)."""
    seed: int = 0
    """Scene seed."""


def image_strip(render_dir: Path, out: Path, max_views: int = 4) -> Path:
    """Stack the rendered views: one row per output (rgb, thermal, ...), one column per held-out view."""
    rows: List[np.ndarray] = []
    for output in ("rgb", "thermal"):
        files = sorted(render_dir.rglob(f"{output}/*.jpg")) + sorted(render_dir.rglob(f"{output}/*.png"))
        if not files:
            continue
        tiles = [np.asarray(Image.open(f).convert("RGB")) for f in files[:max_views]]
        rows.append(np.concatenate(tiles, axis=1))
    if not rows:
        raise FileNotFoundError(f"{render_dir}: ns-render wrote no rgb or thermal images")
    width = max(r.shape[1] for r in rows)
    rows = [np.pad(r, ((0, 0), (0, width - r.shape[1]), (0, 0))) for r in rows]
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate(rows, axis=0)).save(out)
    return out


def main(config: DemoConfig) -> dict:
    from agrinerf_ns.bench.ns_commands import ns_eval, ns_render_dataset, ns_train
    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.synth import SynthConfig, generate_capture

    raw, data = config.out / "raw", config.out / "orchard"
    if not (raw / "calib.yaml").exists():
        CONSOLE.rule("1/5 agrinerf-synth")
        synth = SynthConfig(scene=config.scene, lighting=config.lighting, seed=config.seed, views=config.views,
                            width=config.width, height=config.width * 3 // 4)  # fmt: skip
        generate_capture(synth, raw)
    if not (data / "transforms.json").exists():
        CONSOLE.rule("2/5 agrinerf-process")
        process_capture(raw, data, ProcessConfig(poses="given", overwrite=True))
    CONSOLE.rule(f"3/5 ns-train agrinerf-lite ({config.steps} steps)")
    run = ns_train("agrinerf-lite", data, config.out / "runs", "demo", max_steps=config.steps)
    CONSOLE.print(f"trained in {run.wall_s:.0f} s ({run.s_per_step:.3f} s/step, peak {run.peak_rss_mb:.0f} MiB)")
    CONSOLE.rule("4/5 ns-render (held-out views: rgb, thermal)")
    renders = ns_render_dataset(run.config, config.out / "renders", outputs=["rgb", "thermal"], split="test")
    strip = image_strip(renders, config.out / "strip.png")
    CONSOLE.rule("5/5 ns-eval")
    metrics = ns_eval(run.config, config.out / "metrics.json")
    table = Table("metric", "value", title=f"agrinerf-lite on the {config.lighting} {config.scene} (held-out views)")
    for key, value in sorted(metrics.items()):
        if not key.endswith("_std"):
            table.add_row(key, f"{value:.4f}")
    CONSOLE.print(table)
    CONSOLE.print(f"config: {run.config}\nstrip: {strip}\nmetrics: {config.out / 'metrics.json'}")
    (config.out / "summary.json").write_text(json.dumps({"config": str(run.config), "metrics": metrics}, indent=2))
    return metrics


def entrypoint() -> None:
    """Console script ``agrinerf-demo``."""
    main(tyro.cli(DemoConfig))


if __name__ == "__main__":
    entrypoint()
