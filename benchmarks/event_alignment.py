"""Do a dataset's event counts agree with its RGB frames where the event loss reads them?

    python benchmarks/event_alignment.py --data outputs/ablation/scenes/orchard-dusk/data --out results/event-alignment

For consecutive frames k-1, k whose event window spans them, the change of log luminance between the two captured
frames (the event loss's response, ``agrinerf_ns.model.losses.log_luminance``) is compared, pixel by pixel inside the
event mask, with C (ON - OFF) of frame k's window (``event_sums_path``, in RGB pixels): their correlation with the
counts where they are, and with the counts shifted by whole pixels (the best shift, within +-6 px, says how far the
event frames sit from the RGB pixels they were warped onto). Writes ``OUT/event_alignment.md``.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import List, Tuple

import numpy as np
import torch
import tyro
from PIL import Image

from agrinerf_ns.model import losses


@dataclass
class Args:
    data: Path
    """A processed dataset with event sums (``event_sums_path``)."""
    out: Path = Path("results/event-alignment")
    threshold: float = 0.2
    """Contrast threshold C."""
    eps: float = 1e-2
    """Offset of the log response (linear units of the frames)."""
    max_shift: int = 6


def log_luma(path: Path, eps: float) -> np.ndarray:
    rgb = torch.from_numpy(np.asarray(Image.open(path).convert("RGB"), dtype=np.float32) / 255.0)
    return losses.log_luminance(rgb, eps)[..., 0].numpy()


def best_shift(change: np.ndarray, target: np.ndarray, mask: np.ndarray, max_shift: int) -> Tuple[float, int, int]:
    """Highest correlation of `change` with `target` over whole-pixel shifts of `change`, and that shift."""
    best = (-2.0, 0, 0)
    for dy in range(-max_shift, max_shift + 1):
        for dx in range(-max_shift, max_shift + 1):
            shifted = np.roll(np.roll(change, dy, 0), dx, 1)
            best = max(best, (float(np.corrcoef(shifted[mask], target[mask])[0, 1]), dy, dx))
    return best


def main(args: Args) -> None:
    meta = json.loads((args.data / "transforms.json").read_text())
    frames = sorted(meta["frames"], key=lambda f: f["timestamp"])
    rows: List[Tuple[str, float, float, int, int, float]] = []
    for prev, frame in zip(frames, frames[1:], strict=False):
        sums = np.load(args.data / frame["event_sums_path"])
        if (
            abs(float(sums["t_start"]) - prev["timestamp"]) > 1e-3
            or abs(float(sums["t_end"]) - frame["timestamp"]) > 1e-3
        ):
            continue  # the window does not span these two frames
        mask = sums["mask"].astype(bool)
        target = args.threshold * (sums["pos"].astype(np.float64) - sums["neg"].astype(np.float64))
        change = log_luma(args.data / frame["file_path"], args.eps) - log_luma(args.data / prev["file_path"], args.eps)
        change -= np.median(change[mask])  # the two frames' auto-exposures differ by a global factor
        here = float(np.corrcoef(change[mask], target[mask])[0, 1])
        corr, dy, dx = best_shift(change, target, mask, args.max_shift)
        rows.append(
            (Path(frame["file_path"]).name, here, corr, dy, dx, float((sums["pos"] + sums["neg"])[mask].mean()))
        )
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Event counts against the RGB frames' log-luminance change",
        "",
        f"Command: `python benchmarks/event_alignment.py {' '.join(sys.argv[1:])}`",
        "",
        f"Dataset `{args.data}` (events warped into the RGB camera at plane depth "
        f"{meta.get('agrinerf', {}).get('alignment', {}).get('plane_depth', '?')}). C = {args.threshold}, "
        f"eps = {args.eps}. Correlation over the event mask of log L(k) - log L(k-1) with C (ON - OFF) of frame k's "
        "window; best: over whole-pixel shifts (dy, dx) of the frames' change.",
        "",
        "| frame | correlation where the counts are | best correlation | at (dy, dx) | events per pixel |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {n} | {h:+.3f} | {c:+.3f} | ({dy}, {dx}) | {e:.2f} |" for n, h, c, dy, dx, e in rows]
    if rows:
        lines += ["", f"Median: {np.median([r[1] for r in rows]):+.3f} where the counts are, "
                      f"{np.median([r[2] for r in rows]):+.3f} at the best shift."]  # fmt: skip
    (args.out / "event_alignment.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(tyro.cli(Args))
