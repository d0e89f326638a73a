"""Temperature error in degrees C of a trained AgriNeRF run on held-out views of a synthetic capture, and per fruit.

    python benchmarks/bench_temperature.py --config outputs/.../config.yml --raw RAW --out results/temperature

For every eval view of the run's dataset (the frames the training never saw), the rendered `temperature` is compared
with the capture's truth (``truth/temperature/``: the sharp scene's surface temperature at the RGB camera, undistorted
as ``agrinerf-process`` undistorts the frames) over the thermal mask (where the thermal camera sees), and, for
reference, the dataset's own temperature image (the camera's measurement warped into the RGB camera, what the model
learns from and what ``ns-eval``'s ``temperature_mae`` compares with) against the same truth. Per fruit: the mean
rendered temperature over each true fruit's pixels (``truth/fruit_ids``, inside the thermal mask, at least
``min_fruit_pixels``) against the mean truth over the same pixels. Writes ``OUT/temperature.json`` and
``OUT/temperature.md``.
"""

from __future__ import annotations

import json
import platform
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import cv2
import numpy as np
import tyro
from jaxtyping import Float, Int
from PIL import Image
from scipy.ndimage import maximum_filter, minimum_filter

from agrinerf_ns.run_loading import dataset_folder


@dataclass
class Args:
    config: Path
    """config.yml of a trained AgriNeRF run whose dataset has temperatures."""
    raw: Path
    """The synthetic raw capture the dataset was processed from (its truth/)."""
    out: Path = Path("results/temperature")
    flat_range_c: float = 0.5
    """"Interior" pixels: the truth varies less than this over their 5 x 5 neighbourhood (away from edges, where the
    thermal camera's resolution, optics blur and the warp's parallax dominate)."""
    min_fruit_pixels: int = 4
    """A fruit counts when at least this many of its pixels lie inside the thermal mask of a view."""
    command: str = ""
    """The commands that made the run, recorded in the report."""


class TruthTemperature:
    """Truth temperature and fruit ids of a synthetic capture's frames, undistorted like the processed RGB frames."""

    def __init__(self, raw: Path) -> None:
        from agrinerf_ns.process import align, readers

        self.raw = raw
        self.maps = align.undistort_maps(readers.read_calibration(raw / "calib.yaml").rgb)

    def get(self, raw_rgb: str) -> Tuple[Float[np.ndarray, "h w"], Int[np.ndarray, "h w"]]:
        """(degrees C, fruit index or -1) of the raw RGB frame ``raw_rgb`` (e.g. "rgb/000004.png")."""
        stem = Path(raw_rgb).stem
        path = self.raw / "truth" / "temperature" / f"{stem}.npy"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no truth temperature (only agrinerf-synth captures have it)")
        celsius = np.load(path).astype(np.float32)
        ids = np.asarray(Image.open(self.raw / "truth" / "fruit_ids" / f"{stem}.png")).astype(np.int32)
        if self.maps is not None:
            mx, my = self.maps
            celsius = cv2.remap(celsius, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
            ids = cv2.remap(ids.astype(np.float32), mx, my, cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return celsius, np.asarray(ids).astype(np.int64) - 1


def fruit_errors(
    rendered: Float[np.ndarray, "h w"],
    camera: Float[np.ndarray, "h w"],
    truth: Float[np.ndarray, "h w"],
    ids: Int[np.ndarray, "h w"],
    mask: np.ndarray,
    min_pixels: int,
) -> List[Dict[str, float]]:
    """Per visible fruit: mean rendered, camera (dataset image) and true temperature over its pixels inside ``mask``."""
    rows = []
    for fruit in np.unique(ids[(ids >= 0) & mask]):
        sel = (ids == fruit) & mask
        if int(sel.sum()) >= min_pixels:
            rows.append({"fruit": int(fruit), "pixels": int(sel.sum()), "rendered_c": float(rendered[sel].mean()),
                         "truth_c": float(truth[sel].mean()), "camera_c": float(camera[sel].mean())})  # fmt: skip
    return rows


def machine() -> str:
    try:
        out = subprocess.run(["lscpu"], capture_output=True, text=True, check=False).stdout
        name = next((ln.split(":", 1)[1].strip() for ln in out.splitlines() if ln.startswith("Model name")), "")
    except OSError:
        name = ""
    return f"{name or platform.processor()}, {__import__('os').cpu_count()} cores"


def main(args: Args) -> Dict:
    import torch

    from agrinerf_ns.run_loading import load_run, render_camera

    run = load_run(args.config)
    model = run.pipeline.model
    if not getattr(getattr(model, "plan", model), "has_temperature", False):
        sys.exit(f"{args.config}: the model has no temperature output (its dataset has no radiometric calibration)")
    dataset = run.pipeline.datamanager.eval_dataset
    data_dir = dataset_folder(Path(run.pipeline.datamanager.config.dataparser.data))
    meta = json.loads((data_dir / "transforms.json").read_text())
    raw_of = {Path(f["file_path"]).name: f["raw_rgb"] for f in meta["frames"]}
    truth = TruthTemperature(args.raw)
    views, fruits = [], []
    for index in range(len(dataset)):
        name = Path(dataset._dataparser_outputs.image_filenames[index]).name
        with torch.no_grad():
            rendered = render_camera(run, dataset, index)["temperature"][..., 0].cpu().numpy()
        data = dataset[index]
        mask = data["temperature_mask"][..., 0].numpy() > 0.5
        camera = data["temperature"][..., 0].numpy()
        true_c, ids = truth.get(raw_of[name])
        flat = mask & ((maximum_filter(true_c, 5) - minimum_filter(true_c, 5)) < args.flat_range_c)
        views.append({
            "view": name,
            "pixels": int(mask.sum()),
            "mae_c": float(np.abs(rendered - true_c)[mask].mean()),
            "bias_c": float((rendered - true_c)[mask].mean()),
            "camera_mae_c": float(np.abs(camera - true_c)[mask].mean()),
            "vs_camera_mae_c": float(np.abs(rendered - camera)[mask].mean()),
            "interior_pixels": int(flat.sum()),
            "interior_mae_c": float(np.abs(rendered - true_c)[flat].mean()),
            "interior_camera_mae_c": float(np.abs(camera - true_c)[flat].mean()),
        })  # fmt: skip
        fruits += [
            {"view": name, **row} for row in fruit_errors(rendered, camera, true_c, ids, mask, args.min_fruit_pixels)
        ]
    pixels = np.array([v["pixels"] for v in views], dtype=np.float64)

    interior = np.array([v["interior_pixels"] for v in views], dtype=np.float64)

    def pooled(key: str) -> float:
        weights = interior if key.startswith("interior") else pixels
        return float((np.array([v[key] for v in views]) * weights).sum() / weights.sum())

    fruit_abs = np.array([abs(f["rendered_c"] - f["truth_c"]) for f in fruits])
    fruit_camera_abs = np.array([abs(f["camera_c"] - f["truth_c"]) for f in fruits])
    result = {
        "config": str(args.config),
        "raw": str(args.raw),
        "step": run.step,
        "views": views,
        "temperature_mae_c": pooled("mae_c"),
        "temperature_bias_c": pooled("bias_c"),
        "camera_mae_c": pooled("camera_mae_c"),
        "ns_eval_temperature_mae_c": pooled("vs_camera_mae_c"),
        "interior_fraction": float(interior.sum() / pixels.sum()),
        "interior_mae_c": pooled("interior_mae_c"),
        "interior_camera_mae_c": pooled("interior_camera_mae_c"),
        "fruits": fruits,
        "fruit_mae_c": float(fruit_abs.mean()) if fruits else float("nan"),
        "fruit_median_abs_c": float(np.median(fruit_abs)) if fruits else float("nan"),
        "fruit_camera_mae_c": float(fruit_camera_abs.mean()) if fruits else float("nan"),
        "machine": machine(),
        "command": args.command,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "temperature.json").write_text(json.dumps(result, indent=1) + "\n")
    (args.out / "temperature.md").write_text(report(result))
    print(report(result))
    return result


def report(r: Dict) -> str:
    lines = [
        "# Temperature error (degrees C) on held-out views",
        "",
        f"Run `{r['config']}` (step {r['step']}), truth from `{r['raw']}`. Machine: {r['machine']}.",
        "",
        "| | MAE (C) |",
        "|---|---|",
        f"| rendered `temperature` vs truth, over the thermal mask | {r['temperature_mae_c']:.3f} "
        f"(bias {r['temperature_bias_c']:+.3f}) |",
        f"| the dataset's temperature image (the camera) vs truth, same pixels | {r['camera_mae_c']:.3f} |",
        f"| rendered vs the dataset's temperature image (`ns-eval` temperature_mae) | "
        f"{r['ns_eval_temperature_mae_c']:.3f} |",
        f"| interior pixels ({100 * r['interior_fraction']:.0f}% of them), rendered vs truth | "
        f"{r['interior_mae_c']:.3f} |",
        f"| interior pixels, the camera vs truth | {r['interior_camera_mae_c']:.3f} |",
        f"| per fruit: mean over its pixels, rendered vs truth ({len(r['fruits'])} fruit-views) | "
        f"{r['fruit_mae_c']:.3f} (median {r['fruit_median_abs_c']:.3f}) |",
        f"| per fruit, the camera vs truth | {r['fruit_camera_mae_c']:.3f} |",
        "",
        "| view | pixels | MAE | bias | camera MAE |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {v['view']} | {v['pixels']} | {v['mae_c']:.3f} | {v['bias_c']:+.3f} | {v['camera_mae_c']:.3f} |"
              for v in r["views"]]  # fmt: skip
    if r["command"]:
        lines += ["", "Commands:", "```", r["command"], "```"]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(tyro.cli(Args))
