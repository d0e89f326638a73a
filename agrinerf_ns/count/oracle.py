"""A render folder made of a synthetic capture's own frames and true depth, as a perfect reconstruction would render
them: ``python -m agrinerf_ns.count.oracle --raw RAW --data DATASET --out FOLDER``, then
``agrinerf-count --renders FOLDER --truth RAW``.

It measures the counting itself (detector, lift, fusion) apart from the reconstruction: ``rgb`` is the dataset's
captured RGB frame (noise in the dark), ``thermal`` its rescaled thermal frame warped into the RGB camera, ``depth``
the true z-depth (``truth/depth``, raw distorted pixels) undistorted onto the dataset's pinhole camera and turned into a
distance along the unit ray, in the dataset's frame (identity dataparser transform, scale 1).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import List

import cv2
import numpy as np
import tyro
import yaml

from agrinerf_ns.count.render import CountInputError, RenderedView, RenderSet, WorldFrame, save_renders
from agrinerf_ns.count.score import read_frames, read_split


def undistort_maps(raw: Path, meta: dict) -> tuple:
    """OpenCV remap tables from the raw RGB camera (``calib.yaml``, distorted) onto the dataset's pinhole camera."""
    calib = yaml.safe_load((raw / "calib.yaml").read_text())
    cam = next(c for c in calib.values() if isinstance(c, dict) and c.get("modality") == "rgb")
    fx, fy, cx, cy = cam["intrinsics"]
    k_raw = np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])
    # the dataset's cx, cy follow Nerfstudio's pixel-centre convention (+0.5), OpenCV's do not
    k_new = np.array([[meta["fl_x"], 0, meta["cx"] - 0.5], [0, meta["fl_y"], meta["cy"] - 0.5], [0, 0, 1.0]])
    size = (int(meta["w"]), int(meta["h"]))
    return cv2.initUndistortRectifyMap(k_raw, np.asarray(cam["distortion_coeffs"]), None, k_new, size, cv2.CV_32FC1)


def oracle_renders(raw: Path, dataset: Path) -> RenderSet:
    """Every frame of ``dataset`` (processed from the synthetic capture ``raw``) as a rendered view."""
    meta = json.loads((dataset / "transforms.json").read_text())
    if not (raw / "truth" / "depth").is_dir():
        raise CountInputError(f"{raw / 'truth' / 'depth'}: missing; the oracle needs a synthetic capture's true depth")
    map_x, map_y = undistort_maps(raw, meta)
    width, height, fx, fy = int(meta["w"]), int(meta["h"]), float(meta["fl_x"]), float(meta["fl_y"])
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    cam_dirs = np.stack([(u - meta["cx"]) / fx, -(v - meta["cy"]) / fy, -np.ones_like(u)], -1)  # OpenGL camera
    norm = np.linalg.norm(cam_dirs, axis=-1)
    train = set(read_split(dataset, "train_filenames"))
    views: List[RenderedView] = []
    for frame in read_frames(dataset):
        stem = Path(str(frame.get("raw_rgb", frame["file_path"]))).stem
        z = np.load(raw / "truth" / "depth" / f"{stem}.npy").astype(np.float32)
        z = cv2.remap(z, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
        hit = np.isfinite(z)
        c2w = np.asarray(frame["transform_matrix"], np.float64)
        rgb = cv2.imread(str(dataset / frame["file_path"]), cv2.IMREAD_COLOR)[..., ::-1] / 255.0
        thermal = None
        if "thermal_file_path" in frame:
            thermal = cv2.imread(str(dataset / frame["thermal_file_path"]), cv2.IMREAD_GRAYSCALE) / 255.0
        views.append(
            RenderedView(
                name=Path(frame["file_path"]).stem,
                split="train" if frame["file_path"] in train or not train else "eval",
                file_path=str(frame["file_path"]),
                rgb=rgb.astype(np.float32),
                depth=np.where(hit, z * norm, 0.0).astype(np.float32),
                accumulation=hit.astype(np.float32),
                origins=np.broadcast_to(c2w[:3, 3], (height, width, 3)).astype(np.float32),
                directions=((cam_dirs / norm[..., None]) @ c2w[:3, :3].T).astype(np.float32),
                focal=(fx + fy) / 2,
                thermal=None if thermal is None else thermal.astype(np.float32),
            )
        )
    return RenderSet(views, WorldFrame(np.eye(4)[:3], 1.0), dataset, None, "oracle (captured frames, true depth)")


@dataclass
class OracleArgs:
    """Write a render folder of a synthetic capture's frames and true depth, for agrinerf-count --renders."""

    raw: Path
    """The synthetic raw capture (agrinerf-synth)."""
    data: Path
    """Its dataset (agrinerf-process)."""
    out: Path
    """Render folder to write."""


def entrypoint() -> None:
    args = tyro.cli(OracleArgs)
    save_renders(oracle_renders(args.raw, args.data), args.out)


if __name__ == "__main__":
    entrypoint()
