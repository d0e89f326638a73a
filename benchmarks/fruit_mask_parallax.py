"""Whether a dataset's fruit masks sit where the RGB camera saw the fruit or a baseline off: the pixel IoU of the
masks against the capture's true fruit (truth/fruit_ids, the RGB camera's view) as they are, and at the best
whole-pixel shift of all frames together. Masks made on the thermal frames (warped into the RGB plane at the
alignment plane) hold the thermal camera's view: a shift that lifts the IoU far above its unshifted value is the
rig's parallax, not a bad mask (docs/model.md, Fruit head).

    python benchmarks/fruit_mask_parallax.py --dataset DS --raw RAW
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import tyro

from agrinerf_ns.dataset_format import FRUIT_MASK
from agrinerf_ns.fruit_mask_format import fruit_and_known


@dataclass
class Args:
    dataset: Path
    """A processed dataset with fruit masks (agrinerf-process --fruit-mask-maker or --fruit-masks)."""
    raw: Path
    """The synthetic raw capture it came from (truth/fruit_ids)."""
    max_shift: int = 16
    """Largest shift tried, in pixels, along each image axis."""


def main(args: Args) -> str:
    frames = json.loads((args.dataset / "transforms.json").read_text())["frames"]
    masks, truth = [], []
    for frame in frames:
        fruit, known = fruit_and_known(iio.imread(args.dataset / frame[FRUIT_MASK.key]))
        masks.append(fruit & known)
        truth.append(iio.imread(args.raw / "truth" / "fruit_ids" / f"{Path(frame['file_path']).stem}.png") > 0)
    m, t = np.array(masks), np.array(truth)

    def iou(dx: int, dy: int) -> float:
        shifted = np.roll(np.roll(m, dy, axis=1), dx, axis=2)
        return float((shifted & t).sum() / max(int((shifted | t).sum()), 1))

    shifts = range(-args.max_shift, args.max_shift + 1)
    best, dx, dy = max((iou(x, y), x, y) for x in shifts for y in shifts)
    return f"frames: {len(frames)}; pixel IoU as they are: {iou(0, 0):.3f}; best shift ({dx}, {dy}) px: {best:.3f}"


if __name__ == "__main__":
    print(main(tyro.cli(Args)))
