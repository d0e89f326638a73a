"""Check a processed dataset against a synthetic capture's truth/ (processing itself never reads truth/).

- alignment: for every fruit centre of ``truth/fruits.json`` in view, the distance in the aligned frame between its
  RGB pixel and where the aligned thermal (event) frame shows it, through the warp maps the dataset was made with;
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

from agrinerf_ns.process import align, readers
from agrinerf_ns.process.pipeline import recorded_plane_depth
from agrinerf_ns.process.poses import match_times, opencv_to_opengl, pose_errors


def alignment_report(raw: Path, plane_depth: float = float("inf")) -> Dict[str, Dict[str, float]]:
    """Fruit-centre reprojection error (RGB pixels) of the thermal and event warps, over all frames."""
    calib = readers.read_calibration(raw / "calib.yaml")
    rgb_times = readers.read_timestamps(raw / "rgb").times
    t, c2w = readers.read_tum(raw / "truth" / "poses.txt")
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


def pose_report(raw: Path, dataset: Path) -> Dict[str, float]:
    """Pose error of ``dataset/transforms.json`` against ``raw/truth/poses.txt`` (matched by frame timestamp)."""
    meta = json.loads((dataset / "transforms.json").read_text())
    t_true, c2w_true = readers.read_tum(raw / "truth" / "poses.txt")
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
    meta = json.loads((args.dataset / "transforms.json").read_text())
    result = {
        "alignment": alignment_report(args.raw, recorded_plane_depth(args.dataset)),
        "poses": {**pose_report(args.raw, args.dataset), "source": meta["agrinerf"]["poses"]["source"]},
        "frames_kept": len(meta["frames"]),
        "frames_dropped": len(meta["agrinerf"]["poses"].get("dropped_frames", [])),
    }
    print(json.dumps(result, indent=2))
    return result


if __name__ == "__main__":
    main(tyro.cli(EvaluateArgs))
