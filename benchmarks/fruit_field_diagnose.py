"""Where a trained run's fruit head is right: per training view, the pixels its rendered ``fruit`` output calls fruit,
how many of them the frame's mask calls fruit, and the head's probability and the field's density at those pixels'
rendered surface points (and 3 cm before and behind them). The counter (``--path fruit``) reads the field there.

    python benchmarks/fruit_field_diagnose.py --config RUN/config.yml [--views 8 16]
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Tuple

import numpy as np
import torch
import tyro

from agrinerf_ns.count.volume import field_density, field_features


@dataclass
class Args:
    config: Path
    """A trained run with a fruit head (its dataset has fruit masks)."""
    views: Tuple[int, ...] = (8, 16)
    """Training views to look at (indices)."""
    offset: float = 0.03
    """Before / behind the rendered surface, in Nerfstudio units."""


def main(args: Args) -> str:
    from nerfstudio.utils.eval_utils import eval_setup

    _, pipeline, _, _ = eval_setup(args.config, test_mode="inference")
    model, dataset = pipeline.model, pipeline.datamanager.train_dataset
    model.eval()
    lines = ["| view | rendered fruit px | of them mask fruit | mask fruit px | p at surface | p before | p behind "
             "| density at surface |", "|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for i in args.views:
        camera = dataset.cameras[i : i + 1].to(model.device)
        with torch.no_grad():
            out = model.get_outputs_for_camera(camera)
            rays = camera.generate_rays(camera_indices=0, keep_shape=True)
        fruit = out["fruit"][..., 0].cpu() >= 0.5
        origins, directions = rays.origins[fruit].cpu().numpy(), rays.directions[fruit].cpu().numpy()
        depth = out["depth"][fruit].cpu().numpy()
        medians = []
        for shift in (0.0, -args.offset, args.offset):
            points = origins + directions * (depth + shift)
            p, _ = field_features(model, points, "fruit", np.zeros(3), model.device)
            medians.append(float(np.median(p)) if len(p) else float("nan"))
        density = field_density(model.field, origins + directions * depth, model.device)
        mask = dataset[i]["fruit"][..., 0] > 0.5
        lines.append(f"| {i} | {int(fruit.sum())} | {int((fruit & mask).sum())} | {int(mask.sum())} | {medians[0]:.3f} "
                     f"| {medians[1]:.3f} | {medians[2]:.3f} | {float(np.median(density)):.1f} |")  # fmt: skip
    text = "\n".join(lines) + "\n"
    print(text)
    return text


if __name__ == "__main__":
    main(tyro.cli(Args))
