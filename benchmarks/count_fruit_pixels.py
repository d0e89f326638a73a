"""How many pixels a fruit covers in a synthetic capture: per capture, the median visible pixels of a fruit in a
training view's truth mask (``truth/boxes_coco.json`` areas), the same at the thermal camera (scaled by the square of
the focal-length ratio of the two cameras: the thermal truth is not rendered), and how many fruit show in two or more
views; "across" is the diameter of a disc of the median visible area. Writes a Markdown table.

    python benchmarks/count_fruit_pixels.py RAW [RAW ...] --out results/count-3d/fruit_pixels.md
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Tuple

import numpy as np
import tyro

from agrinerf_ns.synth import SynthConfig
from agrinerf_ns.synth.camera_rig import build_rig


@dataclass
class Args:
    raws: tyro.conf.Positional[Tuple[Path, ...]]
    """Synthetic raw captures (agrinerf-synth)."""
    out: Optional[Path] = None
    """Markdown table to write (else printed)."""


def row(raw: Path) -> str:
    written = json.loads((raw / "truth" / "scene.json").read_text())["config"]
    config = SynthConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in written.items()})
    rig = build_rig(config)
    ratio = rig.cams["thermal"].fx / rig.cams["rgb"].fx
    coco = json.loads((raw / "truth" / "boxes_coco.json").read_text())
    area = np.array([a["area"] for a in coco["annotations"]], np.float64)
    _, views = np.unique([a["fruit_id"] for a in coco["annotations"]], return_counts=True)
    tw, th = config.thermal_wh
    across = 2.0 * np.sqrt(np.median(area) / np.pi)  # the diameter of a disc of the median visible area
    return (
        f"| {config.scene} | {config.lighting} | {config.seed} | {config.views} | {config.width}x{config.height} | "
        f"{config.rgb_hfov_deg:g} / {config.thermal_hfov_deg:g} | {tw}x{th} | {np.median(area):.0f} | {across:.1f} | "
        f"{np.median(area) * ratio**2:.1f} | {across * ratio:.1f} | {len(views)} | {int((views >= 2).sum())} |"
    )


def main(args: Args) -> str:
    lines = [
        "| scene | lighting | seed | views | RGB | FOV RGB / thermal (deg) | thermal | median fruit pixels, RGB "
        "| across (px), RGB | pixels, thermal (focal ratio^2) | across (px), thermal | fruit with >= 3 px in a view "
        "| of them in >= 2 views |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ] + [row(Path(raw)) for raw in args.raws]
    text = "\n".join(lines) + "\n"
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    print(text)
    return text


if __name__ == "__main__":
    main(tyro.cli(Args))
