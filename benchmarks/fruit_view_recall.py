"""Where the view path on the fruit channel loses fruit: per training view of a count's render folder, the true fruit
at least ``--min-pixels`` in that view (the capture's truth/fruit_ids) and how many of them a detection of
``--source fruit`` covers, also by the fruit's size in the view (pixels); per fruit, in how many views it is that large
and in how many detected; and, with ``--config``, the share of the visible fruit inside the run's fitted
full-resolution box.

    python benchmarks/fruit_view_recall.py --renders COUNT/renders --raw RAW [--config RUN/config.yml]
"""

from __future__ import annotations

import collections
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import imageio.v3 as iio
import numpy as np
import tyro

from agrinerf_ns.count.render import load_renders
from agrinerf_ns.fruit.blobs import BlobConfig
from agrinerf_ns.fruit.regions import fruit_regions


@dataclass
class Args:
    renders: Path
    """A render folder written by ``agrinerf-count`` (OUT/renders) of a run with a fruit head."""
    raw: Path
    """The synthetic raw capture (agrinerf-synth) with truth/fruit_ids and truth/fruits.json."""
    config: Optional[Path] = None
    """The run's config.yml: also report the share of visible fruit inside its full-resolution box."""
    min_pixels: int = 20
    """A fruit this many pixels in a view is one the view should find."""


SIZE_EDGES = (100, 300, 1000)
"""Pixel counts that bucket a fruit's view: under 100 px (about 11 px across), 100-300, 300-1000, 1000 and more."""


def main(args: Args) -> str:
    renders = load_renders(args.renders)
    large, found, seen = collections.Counter(), collections.Counter(), collections.Counter()
    by_size: collections.Counter = collections.Counter()  # (bucket, found) -> fruit views
    per_view = []
    for view in renders.views:
        if view.split != "train":
            continue
        ids = iio.imread(args.raw / "truth" / "fruit_ids" / f"{view.name}.png").astype(np.int64)  # id + 1, 0: none
        labels, counts = np.unique(ids, return_counts=True)
        big = {int(i) for i, n in zip(labels, counts, strict=True) if i and n >= args.min_pixels}
        seen.update(int(i) for i, n in zip(labels, counts, strict=True) if i and n >= 3)
        large.update(big)
        hit = set()
        for detection in fruit_regions(view, renders.frame.scale, BlobConfig()):
            inside, n = np.unique(ids[detection.mask], return_counts=True)
            pairs = [(int(c), int(i)) for i, c in zip(inside, n, strict=True) if i]
            if pairs:
                hit.add(max(pairs)[1])
        found.update(hit & big)
        sizes = dict(zip(labels.tolist(), counts.tolist(), strict=True))
        by_size.update((int(np.searchsorted(SIZE_EDGES, sizes[i], side="right")), i in hit) for i in big)
        per_view.append(len(hit & big) / max(len(big), 1))
    visible = sorted(seen)
    lines = [
        f"views: {len(per_view)}; fruit at least {args.min_pixels} px per view found: "
        f"{sum(found.values())} of {sum(large.values())} ({sum(found.values()) / max(sum(large.values()), 1):.2f})",
        f"visible fruit (3 px in a view): {len(visible)}; at least {args.min_pixels} px in 2 views: "
        f"{sum(large[i] >= 2 for i in visible)}; found in 2 views: {sum(found[i] >= 2 for i in visible)}",
    ]
    bounds = [args.min_pixels, *SIZE_EDGES]
    names = [f"{a}-{b}" for a, b in zip(bounds[:-1], bounds[1:], strict=True)] + [f">={SIZE_EDGES[-1]}"]
    for bucket, name in enumerate(names):
        total = by_size[(bucket, True)] + by_size[(bucket, False)]
        if total:
            lines.append(f"fruit views of {name} px: {total}, found {by_size[(bucket, True)] / total:.2f}")
    if args.config is not None:
        import torch
        from nerfstudio.utils.eval_utils import eval_setup

        _, pipeline, _, _ = eval_setup(args.config, test_mode="inference")
        truth = json.loads((args.raw / "truth" / "fruits.json").read_text())
        centres = np.array([truth[i - 1]["center"] for i in visible], dtype=np.float64)
        ns = torch.as_tensor(renders.frame.to_ns(centres), dtype=torch.float32, device=pipeline.model.device)
        share = float(pipeline.model.field.full_resolution(ns).float().mean())
        lines.append(f"visible fruit inside the full-resolution box: {share:.2f}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(main(tyro.cli(Args)))
