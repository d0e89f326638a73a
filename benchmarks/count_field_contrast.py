"""Whether a trained field shows the fruit at all: at each visible true fruit's front point (its centre moved one
radius towards the training cameras' mean centre), the field's density and temperature, against the true fruit
temperature and the field's temperature over the seen dense voxels near it (the surroundings the field path compares
with). Prints a Markdown table.

    python benchmarks/count_field_contrast.py --run RUN/config.yml --raw RAW [--out FILE.md]
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np
import tyro

from agrinerf_ns.count.field_count import FieldCountConfig, count_model
from agrinerf_ns.count.fruit_score import align_to_capture, read_truth_fruit, visible_fruit
from agrinerf_ns.count.pipeline import raw_training_frames
from agrinerf_ns.count.render import WorldFrame, relative_path
from agrinerf_ns.count.volume import field_density, field_features
from agrinerf_ns.run_loading import dataset_folder, trained_run_config


@dataclass
class Args:
    run: Path
    """The trained run (folder or config.yml)."""
    raw: Path
    """Its synthetic capture."""
    out: Optional[Path] = None


def main(args: Args) -> str:
    from agrinerf_ns.run_loading import load_run

    config = trained_run_config(args.run)
    frame = WorldFrame.read(config.parent / "dataparser_transforms.json")
    loaded = load_run(config)
    model = loaded.pipeline.model.eval()
    dm = loaded.pipeline.datamanager
    dataset = dataset_folder(Path(dm.config.data))
    names = [relative_path(Path(p), dataset) for p in dm.train_dataset.image_filenames]
    truth = read_truth_fruit(args.raw)
    visible = visible_fruit(args.raw, raw_training_frames(dataset, names), truth)
    to_capture = align_to_capture(dataset, args.raw)
    _, sampled, _ = count_model(model, dm.train_dataset.cameras, frame, FieldCountConfig(source="temperature"))
    centres_ns = frame.to_ns(to_capture.inverse(truth.centres[visible]))
    radii_ns = 0.5 * truth.diameters[visible] * frame.scale / to_capture.scale
    towards = sampled.eye - centres_ns
    front = centres_ns + towards / np.linalg.norm(towards, axis=1, keepdims=True) * radii_ns[:, None]
    density = field_density(model.field, front, model.device)  # the points go where the field lives (CUDA runs)
    _, temperature = field_features(model, front, "temperature", sampled.eye, model.device)
    assert temperature is not None and sampled.temperature is not None
    seen = sampled.points()
    near = []
    for point in front:
        close = np.linalg.norm(seen - point, axis=1) < 0.3 * frame.scale
        near.append(float(np.median(sampled.temperature[close])) if close.any() else np.nan)
    near = np.asarray(near)
    true_t = truth.temperatures[visible] if truth.temperatures is not None else np.full(len(front), np.nan)
    leaf_c = float(json.loads((args.raw / "truth" / "scene.json").read_text())["temperatures_c"]["leaf"])
    dense = density >= FieldCountConfig().volume.density_threshold
    lines = [
        f"Run `{config}` (step {loaded.step}), capture `{args.raw}`: {int(visible.sum())} visible true fruit.",
        "",
        "| measure | median over the visible fruit |",
        "|---|---|",
        f"| field density at the fruit's front point (per Nerfstudio unit; dense from "
        f"{FieldCountConfig().volume.density_threshold:g}) | {np.median(density):.2f} ({dense.mean():.0%} dense) |",
        f"| true fruit temperature minus the true leaf temperature (C) | {np.nanmedian(true_t) - leaf_c:+.2f} |",
        f"| field temperature at the front point minus its surroundings (C) | {np.nanmedian(temperature - near):+.2f} |",
        f"| abs. error of the field temperature at the front point (C) | {np.nanmedian(np.abs(temperature - true_t)):.2f} |",
        f"| voxels seen, dense | {len(sampled.flat)} of {sampled.dense} |",
    ]
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out is not None:
        args.out.write_text(text)
    return text


if __name__ == "__main__":
    main(tyro.cli(Args))
