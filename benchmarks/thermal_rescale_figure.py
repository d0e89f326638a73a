"""Real raw thermal frames rescaled three ways: figure (docs/img/thermal_rescale.png) and measures table.

    python benchmarks/thermal_rescale_figure.py --frames /work/shared/data/fieldscale-thermal

Measures (agrinerf_ns.process.thermal_rescale): local contrast = mean 9x9 local standard deviation (grey levels);
flicker = mean |out_t - out_t+1| over pixels whose raw count moved by <= 0.5 % of the sequence range; relative
flicker = flicker / local contrast.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import tyro

from agrinerf_ns.process.readers import read_thermal
from agrinerf_ns.process.thermal_rescale import (
    ThermalRescaleConfig,
    local_contrast,
    rescale_sequence,
    static_pixel_flicker,
)


@dataclass
class Args:
    frames: Path = Path(__file__).resolve().parents[1] / "tests" / "data" / "fieldscale-thermal"
    """Folder of raw 16-bit frames (*.tiff / *.png), one sequence in name order."""
    out: Path = Path(__file__).resolve().parents[1] / "docs" / "img" / "thermal_rescale.png"
    """Figure to write."""
    tile_width: int = 256
    """Width of each tile in the figure."""
    rows: int = 2
    """Frames shown (evenly spaced over the sequence)."""


def main(args: Args) -> None:
    paths = sorted(p for p in args.frames.iterdir() if p.suffix.lower() in (".tiff", ".tif", ".png"))
    raws = [read_thermal(p) for p in paths]
    methods = {"global min/max": "global", "per-frame min/max": "per-frame", "fieldscale": "fieldscale"}
    outs = {}
    print(f"{len(raws)} frames from {args.frames}")
    print(f"{'method':<20} {'local contrast':>15} {'flicker':>9} {'rel. flicker':>13}")
    for label, m in methods.items():
        outs[label] = rescale_sequence(raws, ThermalRescaleConfig(method=m))
        c = float(np.mean([local_contrast(o) for o in outs[label]]))
        f = static_pixel_flicker(raws, outs[label])
        print(f"{label:<20} {c:>15.2f} {f:>9.3f} {f / c:>13.3f}")
    h, w = raws[0].shape
    th = round(args.tile_width * h / w)
    pick = np.linspace(0, len(raws) - 1, args.rows).round().astype(int)
    rows = []
    for i in pick:
        tiles = []
        for label in methods:
            tile = cv2.resize(outs[label][i], (args.tile_width, th), interpolation=cv2.INTER_AREA)
            cv2.putText(tile, f"{label} #{i}", (4, 14), cv2.FONT_HERSHEY_SIMPLEX, 0.4, 255, 1, cv2.LINE_AA)
            tiles.append(tile)
        rows.append(np.concatenate(tiles, 1))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(args.out), np.concatenate(rows, 0), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    print(f"wrote {args.out} ({args.out.stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    main(tyro.cli(Args))
