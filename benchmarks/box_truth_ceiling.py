"""How much of a synthetic scene's held-out views a trained run's full-resolution box can hold at all.

    python benchmarks/box_truth_ceiling.py --config RUN/config.yml --raw SCENE/raw --data SCENE/data

`fine_region_weight` (ns-eval) is the share of the rendered weight inside the run's fitted box. Its ceiling is the
share of held-out pixels whose true surface (the capture's true depth) lies in that box: sky and the far background
sit outside any box that keeps fruit-sized voxels. Prints both shares and, for boxes that would hold 80% and 90% of
the true surfaces (`grid_mapping.smallest_box`, as the box fit finds them), the voxel size in metres at the preset's final
grids, as JSON; and the box that the run's own fit rules (`GridSchedule.box_for_surface`) give the true surfaces of
every view (what a perfect field would be fitted), with its share of the held-out surfaces and its voxel.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict

import numpy as np
import torch
import tyro

from agrinerf_ns.count.render import WorldFrame
from agrinerf_ns.lab.count_oracle import oracle_renders
from agrinerf_ns.model.grid_mapping import box_voxel, smallest_box
from agrinerf_ns.run_loading import load_run


@dataclass
class Args:
    config: Path
    """A trained run's config.yml (an AgriNeRF model with a fitted box)."""
    raw: Path
    """The synthetic capture (with truth/depth) the run's dataset was processed from."""
    data: Path
    """The processed dataset the run trained on."""


def share_box_voxel(points: np.ndarray, share: float, resolution: int, grid_fraction: float) -> float:
    """Voxel side (units, the largest axis) of the smallest box that `grid_mapping.smallest_box` finds holding `share`
    of `points`, at the grid resolution per axis that the field would give it (`grid_mapping.box_voxel`)."""
    pts = torch.from_numpy(points).double()
    return box_voxel(smallest_box(pts, torch.ones(pts.shape[0], dtype=torch.float64), share), grid_fraction, resolution)


def main(args: Args) -> Dict[str, float]:
    run = load_run(args.config)
    model = run.pipeline.model
    frame = WorldFrame.read(args.config.parent / "dataparser_transforms.json")
    every = oracle_renders(args.raw, args.data).views
    seen, origins = [], []  # the true surface of every pixel that has one, in the run's scene frame, and its camera
    for view in every:
        hit = view.accumulation > 0.5
        seen.append(frame.to_ns(view.points()[hit]))
        origins.append(frame.to_ns(view.origins[hit]))
    views = [v for v in every if v.split == "eval"]
    points = np.concatenate([p for v, p in zip(every, seen, strict=True) if v.split == "eval"])
    device = model.device  # the box lives on the model's device (CUDA runs): the points go there
    with torch.no_grad():
        inside = int(model.field.full_resolution(torch.from_numpy(points).float().to(device)).sum())
    hits = points.shape[0]
    pixels = sum(v.accumulation.size for v in views)
    final = int(model.config.final_resolution)
    metres = float(model.metres_per_unit) if model.metres_per_unit is not None else float("nan")
    result = {
        "heldout_views": len(views),
        "share_of_pixels_with_true_surface_in_box": inside / pixels,
        "share_of_pixels_with_any_true_surface": hits / pixels,
        "share_of_true_surfaces_in_box": inside / max(hits, 1),
        "voxel_m_box_holding_80pct_of_surfaces": share_box_voxel(points, 0.8, final, model.config.box_grid_fraction)
        * metres,
        "voxel_m_box_holding_90pct_of_surfaces": share_box_voxel(points, 0.9, final, model.config.box_grid_fraction)
        * metres,
        "final_resolution": final,
    }
    # the box the run's fit rules would give a perfect field: the true surfaces of every view, seen from its camera
    truth_box = model.grid.box_for_surface(
        torch.from_numpy(np.concatenate(seen)).float().to(device),
        None,
        torch.from_numpy(np.concatenate(origins)).float().to(device),
    )
    if truth_box is not None:
        truth_box = truth_box.cpu()
        held = ((points >= truth_box[0].numpy()) & (points <= truth_box[1].numpy())).all(axis=1)
        result["truth_fit_share_of_true_surfaces_in_box"] = float(held.mean())
        result["truth_fit_voxel_m"] = box_voxel(truth_box, model.config.box_grid_fraction, final) * metres
    print(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
