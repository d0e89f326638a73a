"""agrinerf-synth truth: fruit boxes against the rendered fruit mask and the 3D fruit list, calibration round trip."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from PIL import Image

from agrinerf_ns.synth import SynthConfig, generate_capture
from agrinerf_ns.synth.camera_rig import THERMAL_DELAY
from agrinerf_ns.synth.capture import make_scene
from agrinerf_ns.synth.raycast import cast

CONFIG = SynthConfig.tiny(seed=2, width=96, height=72, views=4)


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_capture(CONFIG, tmp_path_factory.mktemp("synth_truth") / "raw")


def _K_D(cam: dict) -> tuple:
    fx, fy, cx, cy = cam["intrinsics"]
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.array(cam["distortion_coeffs"], dtype=np.float64)


def _tum_T(row: np.ndarray) -> np.ndarray:
    x, y, z, w = row[4:8]
    R = np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, row[1:4]
    return T


def _project(P_c: np.ndarray, cam: dict) -> np.ndarray:
    K, D = _K_D(cam)
    uv, _ = cv2.projectPoints(P_c.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), K, D)
    return uv.reshape(-1, 2)


def test_boxes_match_fruit_mask_and_3d_fruits(capture: Path) -> None:
    coco = json.loads((capture / "truth" / "boxes_coco.json").read_text())
    fruits = {f["id"]: f for f in json.loads((capture / "truth" / "fruits.json").read_text())}
    calib = yaml.safe_load((capture / "calib.yaml").read_text())
    poses = np.loadtxt(capture / "truth" / "poses.txt", ndmin=2)
    W, H = CONFIG.width, CONFIG.height
    n_boxes = 0
    for img in coco["images"]:
        name = img["file_name"]
        ids = np.asarray(Image.open(capture / "truth" / "fruit_ids" / name)).astype(np.int64) - 1
        clean = np.asarray(Image.open(capture / "truth" / "rgb_clean" / name)).astype(np.float64)
        anns = [a for a in coco["annotations"] if a["image_id"] == img["id"]]
        yolo = np.loadtxt(capture / "truth" / "boxes_yolo" / name.replace(".png", ".txt"), ndmin=2)
        assert len(yolo) == len(anns)
        T_cw = np.linalg.inv(_tum_T(poses[img["id"]]))
        for a, row in zip(anns, yolo, strict=True):
            x, y, w, h = a["bbox"]
            np.testing.assert_allclose(row[1:], [(x + w / 2) / W, (y + h / 2) / H, w / W, h / H], atol=1e-5)
            ys, xs = np.nonzero(ids == a["fruit_id"])
            assert a["area"] == xs.size >= CONFIG.min_box_pixels
            assert (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1) == (x, y, x + w, y + h)
            # the 3D fruit projects (with the written calibration and exact pose) onto its box
            f = fruits[a["fruit_id"]]
            P_c = T_cw[:3, :3] @ np.array(f["center"]) + T_cw[:3, 3]
            u, v = _project(P_c, calib["cam0"])[0]
            r_px = calib["cam0"]["intrinsics"][0] * max(f["radii"]) / P_c[2]
            gap = np.hypot(max(x - 0.5 - u, 0, u - (x + w - 0.5)), max(y - 0.5 - v, 0, v - (y + h - 0.5)))
            assert gap <= r_px + 0.75, (name, a)
            n_boxes += 1
        fruit_px = ids >= 0
        depth = np.load(capture / "truth" / "depth" / name.replace(".png", ".npy"))
        other = ~fruit_px & np.isfinite(depth)
        if fruit_px.sum() >= 5:  # fruit is redder than the rest of the scene in the clean image
            redness = clean[..., 0] - clean[..., 1]
            assert redness[fruit_px].mean() > redness[other].mean() + 15
    assert n_boxes >= 5


def test_calibration_round_trip(capture: Path) -> None:
    """Depth pixels of the RGB truth, back-projected with calib.yaml, land on the same surface in the other cameras."""
    calib = yaml.safe_load((capture / "calib.yaml").read_text())
    poses = np.loadtxt(capture / "truth" / "poses.txt", ndmin=2)
    scene, rig = make_scene(CONFIG)
    T10 = np.array(calib["cam1"]["T_cn_cnm1"])
    T21 = np.array(calib["cam2"]["T_cn_cnm1"])
    rng = np.random.default_rng(0)
    for i in (0, CONFIG.views - 1):
        depth = np.load(capture / "truth" / "depth" / f"{i:06d}.npy").astype(np.float64)
        # pixels on smooth surfaces (no depth edge nearby)
        pad = np.pad(np.where(np.isfinite(depth), depth, 1e6), 2, mode="edge")
        win = np.stack([pad[dy : dy + depth.shape[0], dx : dx + depth.shape[1]] for dy in range(5) for dx in range(5)])
        smooth = np.isfinite(depth) & (win.max(0) - win.min(0) < 0.02 * depth)
        vs, us = np.nonzero(smooth)
        pick = rng.choice(us.size, size=min(60, us.size), replace=False)
        uv = np.stack([us[pick], vs[pick]], -1).astype(np.float64)
        K0, D0 = _K_D(calib["cam0"])
        xy = cv2.undistortPointsIter(uv.reshape(-1, 1, 2), K0, D0, np.eye(3), np.eye(3), (3, 50, 1e-12))
        xy = xy.reshape(-1, 2)
        z = depth[vs[pick], us[pick]]
        P0 = np.stack([xy[:, 0] * z, xy[:, 1] * z, z], -1)
        np.testing.assert_allclose(_project(P0, calib["cam0"]), uv, atol=1e-3)
        t = poses[i, 0]
        for name, T_c0, cam_key, dt in (("thermal", T10, "cam1", THERMAL_DELAY), ("event", T21 @ T10, "cam2", 0.0)):
            P = P0 @ T_c0[:3, :3].T + T_c0[:3, 3]
            uvn = _project(P, calib[cam_key])
            w, h = calib[cam_key]["resolution"]
            px = np.round(uvn).astype(int)
            inside = (px[:, 0] >= 0) & (px[:, 0] < w) & (px[:, 1] >= 0) & (px[:, 1] < h)
            assert inside.mean() > 0.5, name
            hits = cast(scene.prims, rig.cams[name], rig.pose(t + dt, name))
            zr = hits.zdepth.reshape(h, w)[px[inside, 1], px[inside, 0]]
            rel = np.abs(zr - P[inside, 2]) / P[inside, 2]
            assert np.median(rel) < 0.01 and (rel < 0.05).mean() > 0.8, (name, np.median(rel))
