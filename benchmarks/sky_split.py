"""Where a run's held-out error and rendering weight sit: on the sky, on its blended edges, on the scene.

    python benchmarks/sky_split.py --config RUN/config.yml [--raw SCENE/raw]

Pixels are classed by the held-out temperature image (`model/sky.py`: sky below `sky_threshold_c`, scene from its
mirror at the warm end, the edges between). Prints, per class, the temperature MAE, the thermal-camera MSE (both
rendered from the thermal camera, as `ns-eval`) and the mean accumulation; with `--raw` (a synthetic capture), the
share of the rendering weight inside the full-resolution box over the pixels whose true depth is sky and over the rest.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional

import torch
import tyro
from nerfstudio.utils.eval_utils import eval_setup

from agrinerf_ns.model import sky, thermal_view


@dataclass
class Args:
    config: Path
    """A trained AgriNeRF run's config.yml (a dataset with temperatures)."""
    raw: Optional[Path] = None
    """The synthetic capture the dataset was processed from (its true depth tells the sky)."""


def main(args: Args) -> Dict[str, Dict[str, float]]:
    _, pipeline, _, _ = eval_setup(args.config, test_mode="test")
    model = pipeline.model
    truth = {}
    if args.raw is not None:
        from agrinerf_ns.count.oracle import oracle_renders

        dataset = Path(pipeline.datamanager.config.dataparser.data)
        dataset = dataset.parent if dataset.suffix == ".json" else dataset
        truth = {v.name: v for v in oracle_renders(args.raw, dataset).views if v.split == "eval"}
    names = [Path(f).stem for f in pipeline.datamanager.eval_dataset._dataparser_outputs.image_filenames]
    sums: Dict[str, Dict[str, float]] = {}

    def add(cls: str, key: str, value: float) -> None:
        sums.setdefault(cls, {}).setdefault(key, 0.0)
        sums[cls][key] += value

    for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
        with torch.no_grad():
            out = model.get_outputs_for_camera(camera)
            rgb_acc, in_box = out["accumulation"][..., 0], out["full_resolution_weight"][..., 0]
            out = thermal_view.eval_outputs(model, out)
        gt, valid = batch["temperature"], batch["temperature_mask"]
        cold = sky.sky_mask(model, gt, valid)[..., 0]
        warm = sky.sky_mask(model, gt, valid, scene=True)[..., 0]
        edge = (valid[..., 0] > 0.5) & ~cold & ~warm
        t_err = (out["temperature"] - gt).abs()[..., 0]
        th_err = ((out["thermal_camera"] - batch["thermal"]) ** 2)[..., 0]
        for cls, m in (("sky", cold), ("edge", edge), ("scene", warm)):
            add(cls, "pixels", float(m.sum()))
            add(cls, "temperature_abs", float(t_err[m].sum()))
            add(cls, "thermal_camera_sq", float(th_err[m].sum()))
            add(cls, "accumulation", float(rgb_acc[m].sum()))
        view = truth.get(names[int(batch["image_idx"])])
        if view is not None:
            hit = torch.from_numpy(view.accumulation > 0.5)
            for cls, m in (("true_sky", ~hit), ("true_surface", hit)):
                add(cls, "weight_in_box", float(in_box[m].sum()))
                add(cls, "weight", float(rgb_acc[m].sum()))
                add(cls, "pixels", float(m.sum()))
    result = {}
    for cls, s in sums.items():
        n = max(s["pixels"], 1.0)
        if "weight" in s:
            result[cls] = {"pixels": s["pixels"], "accumulation": s["weight"] / n,
                           "share_of_weight_in_box": s["weight_in_box"] / max(s["weight"], 1e-9)}  # fmt: skip
        else:
            result[cls] = {"pixels": s["pixels"], "temperature_mae": s["temperature_abs"] / n,
                           "thermal_camera_mse": s["thermal_camera_sq"] / n, "accumulation": s["accumulation"] / n}  # fmt: skip
    print(json.dumps(result, indent=1))
    return result


if __name__ == "__main__":
    main(tyro.cli(Args))
