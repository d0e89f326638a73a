"""A render folder made of a synthetic capture's own frames and true depth, as a perfect reconstruction would render
them: ``python -m agrinerf_ns.lab.count_oracle --raw RAW --data DATASET --out FOLDER``, then
``agrinerf-count --renders FOLDER --truth RAW``.

It measures the counting itself (detector, lift, fusion) apart from the reconstruction: ``rgb`` is the dataset's
captured RGB frame (noise in the dark), ``depth`` the true z-depth (``truth/depth``, raw distorted pixels) undistorted
onto the dataset's pinhole camera and turned into a distance along the unit ray, in the dataset's frame (identity
dataparser transform, scale 1). ``thermal`` (and ``temperature``, degrees C) is, by ``--thermal``:

- ``reprojected`` (default): the raw thermal frame sampled where each pixel's true surface point falls in the
  thermal camera (calibration ``T_cn_cnm1``, intrinsics, distortion, radiometric map): the captured thermal
  information registered as a perfect cross-spectral field would register it, at the thermal camera's resolution;
- ``captured``: the dataset's thermal frame (warped into the RGB camera at one plane depth, so misregistered off that
  depth by the rig's baseline), NaN outside the thermal camera's view;
- ``true``: the synthetic capture's true temperature in the RGB camera (``truth/temperature``), an upper bound.

``fruit`` (the fruit head's channel, for ``--source fruit``), by ``--fruit``: ``none``; ``dataset``: the dataset's
own fruit masks (``fruit_mask_file_path``, what a fruit head is trained on; unknown pixels and thermal-camera masks
left out), as a perfect fruit head would render them; ``true``: the truth's fruit pixels (``truth/fruit_ids``), the
ceiling of the counting itself.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path
from typing import List, Literal, Optional, Tuple

import cv2
import numpy as np
import tyro
from jaxtyping import Float, Int

from agrinerf_ns.count.fruit_score import FRUIT_IDS_DIR, raw_stem, read_frames, read_split
from agrinerf_ns.count.render import CountInputError, RenderedView, RenderSet, WorldFrame, save_renders
from agrinerf_ns.dataset_format import FRUIT_MASK, FRUIT_MASK_CAMERA, THERMAL, THERMAL_MASK, TRANSFORMS
from agrinerf_ns.fruit_mask_format import fruit_and_known
from agrinerf_ns.process.readers import CameraCalib, read_calibration

ThermalMode = Literal["reprojected", "captured", "true"]
FruitMode = Literal["none", "dataset", "true"]


def undistort_maps(rgb: CameraCalib, meta: dict) -> tuple:
    """OpenCV remap tables from the raw RGB camera (``rgb``, distorted) onto the dataset's pinhole camera."""
    # the dataset's cx, cy follow Nerfstudio's pixel-centre convention (+0.5), OpenCV's do not
    k_new = np.array([[meta["fl_x"], 0, meta["cx"] - 0.5], [0, meta["fl_y"], meta["cy"] - 0.5], [0, 0, 1.0]])
    size = (int(meta["w"]), int(meta["h"]))
    return cv2.initUndistortRectifyMap(rgb.K, rgb.dist, None, k_new, size, cv2.CV_32FC1)


def reproject_thermal(
    counts: np.ndarray, z: Float[np.ndarray, "h w"], meta: dict, camera: CameraCalib
) -> Float[np.ndarray, "h w"]:
    """Temperature (degrees C; NaN off the thermal view or without depth) of the raw thermal frame ``counts`` at
    each dataset pixel's surface point (``z``: z-depth on the dataset's pinhole camera)."""
    height, width = z.shape
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    hit = np.isfinite(z) & (z > 0)
    zz = np.where(hit, z, 1.0)
    points = np.stack([(u - meta["cx"]) / meta["fl_x"] * zz, (v - meta["cy"]) / meta["fl_y"] * zz, zz], -1)
    points = points.reshape(-1, 3) @ camera.T_cam_rgb[:3, :3].T + camera.T_cam_rgb[:3, 3]
    pixels, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), camera.K, camera.dist)
    pixels = pixels.reshape(height, width, 2).astype(np.float32)
    sampled = cv2.remap(counts.astype(np.float32), pixels[..., 0], pixels[..., 1], cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_REPLICATE)  # fmt: skip
    rows, cols = counts.shape[:2]
    on_view = (np.abs(pixels[..., 0] - (cols - 1) / 2) <= cols / 2) & (
        np.abs(pixels[..., 1] - (rows - 1) / 2) <= rows / 2
    )
    celsius = camera.radiometric.celsius(sampled) if camera.radiometric is not None else sampled
    in_front = points.reshape(height, width, 3)[..., 2] > 0
    return np.where(hit & in_front & on_view, celsius, np.nan).astype(np.float32)


def oracle_thermal(
    raw: Path,
    dataset: Path,
    frame: dict,
    z: np.ndarray,
    meta: dict,
    maps: Tuple,
    mode: ThermalMode,
    camera: Optional[CameraCalib],
) -> Tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    """(thermal, temperature) of one oracle view by ``mode`` (see the module docstring); ``camera`` is the capture's
    thermal camera (``reprojected`` needs it)."""
    if mode == "true":
        stem = raw_stem(frame, frame["file_path"])
        t = np.load(raw / "truth" / "temperature" / f"{stem}.npy").astype(np.float32)
        t = cv2.remap(t, maps[0], maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
        return t, t
    if mode == "captured":
        if THERMAL.key not in frame:
            return None, None
        image = cv2.imread(str(dataset / frame[THERMAL.key]), cv2.IMREAD_GRAYSCALE) / 255.0
        if THERMAL_MASK.key in frame:
            mask = cv2.imread(str(dataset / frame[THERMAL_MASK.key]), cv2.IMREAD_GRAYSCALE)
            image = np.where(mask > 0, image, np.nan)
        return image.astype(np.float32), None
    if "raw_thermal" not in frame:
        return None, None
    if camera is None:
        raise CountInputError(f"{raw / 'calib.yaml'}: no thermal camera to reproject the thermal frames from")
    counts = cv2.imread(str(raw / frame["raw_thermal"]), cv2.IMREAD_UNCHANGED)
    t = reproject_thermal(counts, z, meta, camera)
    return t, t


def true_fruit_ids(raw: Path, stem: str, maps: Tuple) -> Int[np.ndarray, "h w"]:
    """The true fruit id of each pixel (-1 none) of the raw RGB frame ``stem`` (``truth/fruit_ids``), undistorted onto
    the dataset's pinhole camera by ``maps`` (:func:`undistort_maps`)."""
    path = raw / FRUIT_IDS_DIR / f"{stem}.png"
    ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if ids is None:
        raise CountInputError(f"{path}: missing or unreadable fruit mask")
    ids = cv2.remap(ids, maps[0], maps[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return ids.astype(np.int64) - 1


def oracle_fruit(raw: Path, dataset: Path, frame: dict, maps: Tuple, mode: FruitMode) -> Optional[np.ndarray]:
    """The ``fruit`` channel of one oracle view by ``mode`` (see the module docstring); NaN where unknown."""
    if mode == "none":
        return None
    if mode == "true":
        return (true_fruit_ids(raw, raw_stem(frame, frame["file_path"]), maps) >= 0).astype(np.float32)
    if FRUIT_MASK.key not in frame or frame.get(FRUIT_MASK_CAMERA, "rgb") != "rgb":
        return None
    fruit, known = fruit_and_known(cv2.imread(str(dataset / frame[FRUIT_MASK.key]), cv2.IMREAD_GRAYSCALE))
    return np.where(known, fruit.astype(np.float32), np.nan).astype(np.float32)


def oracle_renders(
    raw: Path, dataset: Path, thermal_mode: ThermalMode = "reprojected", fruit_mode: FruitMode = "none"
) -> RenderSet:
    """Every frame of ``dataset`` (processed from the synthetic capture ``raw``) as a rendered view."""
    meta = json.loads((dataset / TRANSFORMS).read_text())
    if not (raw / "truth" / "depth").is_dir():
        raise CountInputError(f"{raw / 'truth' / 'depth'}: missing; the oracle needs a synthetic capture's true depth")
    calib = read_calibration(raw / "calib.yaml")
    map_x, map_y = undistort_maps(calib.rgb, meta)
    width, height, fx, fy = int(meta["w"]), int(meta["h"]), float(meta["fl_x"]), float(meta["fl_y"])
    u, v = np.meshgrid(np.arange(width) + 0.5, np.arange(height) + 0.5)
    cam_dirs = np.stack([(u - meta["cx"]) / fx, -(v - meta["cy"]) / fy, -np.ones_like(u)], -1)  # OpenGL camera
    norm = np.linalg.norm(cam_dirs, axis=-1)
    train = set(read_split(dataset, "train_filenames"))
    views: List[RenderedView] = []
    for frame in read_frames(dataset):
        stem = raw_stem(frame, frame["file_path"])
        z = np.load(raw / "truth" / "depth" / f"{stem}.npy").astype(np.float32)
        z = cv2.remap(z, map_x, map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
        hit = np.isfinite(z)
        c2w = np.asarray(frame["transform_matrix"], np.float64)
        rgb = cv2.imread(str(dataset / frame["file_path"]), cv2.IMREAD_COLOR)[..., ::-1] / 255.0
        thermal, temperature = oracle_thermal(raw, dataset, frame, z, meta, (map_x, map_y), thermal_mode, calib.thermal)
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
                thermal=thermal,
                temperature=temperature,
                fruit=oracle_fruit(raw, dataset, frame, (map_x, map_y), fruit_mode),
            )
        )
    method = f"oracle (captured frames, true depth, {thermal_mode} thermal, {fruit_mode} fruit)"
    return RenderSet(views, WorldFrame(np.eye(4)[:3], 1.0), dataset, None, method)


def with_true_depth(renders: RenderSet, raw: Path) -> RenderSet:
    """A trained run's ``renders`` with each view's depth replaced by the synthetic capture's true depth along the
    same pixel rays (in Nerfstudio units: the dataparser's scale applied): the count of the run's colours on a
    perfect geometry. Against the count on the rendered depth it measures what the field's geometry costs."""
    if renders.dataset is None:
        raise CountInputError(f"{raw}: the renders do not name their dataset folder, needed for the true depth")
    truth = {v.file_path: v for v in oracle_renders(raw, renders.dataset, "true").views}
    views = []
    for view in renders.views:
        true = truth.get(view.file_path)
        if true is None or true.depth.shape != view.depth.shape:
            what = "no frame" if true is None else f"a {true.depth.shape} frame for a {view.depth.shape} render"
            raise CountInputError(f"{renders.dataset}: {what} for the rendered view {view.file_path}")
        views.append(replace(view, depth=(true.depth * renders.frame.scale).astype(np.float32)))
    return replace(renders, views=views, method=f"{renders.method or 'the run'} with the true depth")


@dataclass
class OracleArgs:
    """Write a render folder of a synthetic capture's frames and true depth, for agrinerf-count --renders."""

    raw: Path
    """The synthetic raw capture (agrinerf-synth)."""
    data: Path
    """Its dataset (agrinerf-process)."""
    out: Path
    """Render folder to write."""
    thermal: ThermalMode = "reprojected"
    """The thermal output: the raw frame reprojected through the true depth, the dataset's plane-warped frame, or the
    true temperature."""
    fruit: FruitMode = "none"
    """The fruit channel: none, the dataset's fruit masks, or the truth's fruit pixels."""


def entrypoint() -> None:
    args = tyro.cli(OracleArgs)
    save_renders(oracle_renders(args.raw, args.data, args.thermal, args.fruit), args.out)


if __name__ == "__main__":
    entrypoint()
