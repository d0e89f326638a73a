"""Check a processed dataset against a synthetic capture's truth/ (processing itself never reads truth/).

- alignment: for every fruit centre of ``truth/fruits.json`` in view, the distance in the aligned frame between its
  RGB pixel and where the aligned thermal (event) frame shows it, through the warp maps the dataset was made with;
- visible fruit depth: where the fruit the RGB views show sit (the plane to warp thermal frames at for detection);
- poses: rotation and translation error of the dataset's poses against ``truth/poses.txt`` after a similarity
  (Umeyama) alignment of the camera centres.

``python -m agrinerf_ns.process.evaluate --raw RAW --dataset DATASET`` prints both as JSON.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Dict

import numpy as np
import tyro

from agrinerf_ns.dataset_format import TRANSFORMS
from agrinerf_ns.process import align, readers
from agrinerf_ns.process.capture_to_dataset import recorded_plane_depth
from agrinerf_ns.process.poses import match_times, opencv_to_opengl, pose_errors
from agrinerf_ns.trajectory import read_tum


def alignment_report(raw: Path, plane_depth: float = float("inf")) -> Dict[str, Dict[str, float]]:
    """Fruit-centre reprojection error (RGB pixels) of the thermal and event warps, over all frames."""
    calib = readers.read_calibration(raw / "calib.yaml")
    rgb_times = readers.read_timestamps(raw / "rgb").times
    t, c2w = read_tum(raw / "truth" / "poses.txt")
    idx = match_times(rgb_times, t, 1e-3)
    fruits = json.loads((raw / "truth" / "fruits.json").read_text())
    centres = np.array([f["center"] for f in fruits], dtype=np.float64)
    report = {}
    for name, cam in (("thermal", calib.thermal), ("event", calib.event)):
        if cam is None:
            continue
        maps = align.warp_maps(calib.rgb, cam, plane_depth)
        errs, depths = [], []
        for j in idx[idx >= 0]:
            w2c = np.linalg.inv(c2w[j])
            X = centres @ w2c[:3, :3].T + w2c[:3, 3]
            X = X[X[:, 2] > 0.1]
            e = align.reprojection_errors(calib.rgb, cam, maps, X)
            errs.append(e)
            depths.append(X[:, 2])
        e = np.concatenate(errs) if errs else np.zeros(0)
        report[name] = {
            "mean_px": float(e.mean()) if e.size else float("nan"),
            "median_px": float(np.median(e)) if e.size else float("nan"),
            "max_px": float(e.max()) if e.size else float("nan"),
            "count": int(e.size),
            "median_fruit_depth_m": float(np.median(np.concatenate(depths))) if depths else float("nan"),
        }
    return report


def visible_fruit_depth(raw: Path, min_pixels: int = 30) -> Dict[str, float]:
    """Depth (m, RGB camera) of the fruit the RGB views show: per true box of ``truth/boxes_coco.json`` with at least
    ``min_pixels`` visible pixels, the median ``truth/depth`` over that fruit's pixels (``truth/fruit_ids``). The
    plane to warp the thermal frames at for detection; ``alignment_report``'s depth counts every fruit centre in
    front of the camera, hidden ones too."""
    from PIL import Image

    truth = raw / "truth"
    coco = json.loads((truth / "boxes_coco.json").read_text())
    names = {image["id"]: Path(image["file_name"]).stem for image in coco["images"]}
    depths = []
    for image_id, stem in names.items():
        boxes = [a for a in coco["annotations"] if a["image_id"] == image_id and a["area"] >= min_pixels]
        if not boxes:
            continue
        depth = np.load(truth / "depth" / f"{stem}.npy")
        ids = np.asarray(Image.open(truth / "fruit_ids" / f"{stem}.png")).astype(np.int64) - 1  # 0: no fruit
        depths += [float(np.median(depth[ids == box["fruit_id"]])) for box in boxes]
    if not depths:
        return {"median": float("nan"), "p25": float("nan"), "p75": float("nan"), "count": 0}
    p25, median, p75 = np.percentile(depths, [25, 50, 75])
    return {"median": float(median), "p25": float(p25), "p75": float(p75), "count": len(depths)}


def pose_report(raw: Path, dataset: Path) -> Dict[str, float]:
    """Pose error of ``dataset/transforms.json`` against ``raw/truth/poses.txt`` (matched by frame timestamp)."""
    meta = json.loads((dataset / TRANSFORMS).read_text())
    t_true, c2w_true = read_tum(raw / "truth" / "poses.txt")
    times = np.array([f["timestamp"] for f in meta["frames"]])
    est = opencv_to_opengl(np.array([f["transform_matrix"] for f in meta["frames"]]))  # back to OpenCV axes
    idx = match_times(times, t_true, 1e-3)
    ok = idx >= 0
    out = pose_errors(est[ok], c2w_true[idx[ok]])
    out["frames"] = int(ok.sum())
    return out


@dataclass
class EvaluateArgs:
    """Compare a processed dataset with the synthetic truth of its raw capture."""

    raw: Path
    """Raw capture folder with truth/."""
    dataset: Path
    """Dataset written by agrinerf-process from it."""


def main(args: EvaluateArgs) -> Dict:
    meta = json.loads((args.dataset / TRANSFORMS).read_text())
    result = {
        "alignment": alignment_report(args.raw, recorded_plane_depth(args.dataset)),
        "visible_fruit_depth_m": visible_fruit_depth(args.raw),
        "poses": {**pose_report(args.raw, args.dataset), "source": meta["agrinerf"]["poses"]["source"]},
        "frames_kept": len(meta["frames"]),
        "frames_dropped": len(meta["agrinerf"]["poses"].get("dropped_frames", [])),
    }
    print(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main(tyro.cli(EvaluateArgs))
