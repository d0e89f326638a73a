"""Alignment of thermal/event frames into the RGB camera, measured on images and on geometry."""

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.process_raw_fixture import FRUIT_UV, make_raw_capture

from agrinerf_ns.process import align, readers
from agrinerf_ns.process.readers import CameraCalib


def _cams():
    K1 = np.array([[100.0, 0, 40], [0, 100.0, 30], [0, 0, 1]])
    K2 = np.array([[60.0, 0, 25], [0, 62.0, 20], [0, 0, 1]])
    T = np.eye(4)
    T[:3, :3] = cv2.Rodrigues(np.array([0.02, -0.03, 0.01]))[0]
    T[:3, 3] = [0.1, -0.02, 0.01]
    rgb = CameraCalib("cam0", "rgb", K1, np.zeros(4), 80, 60)
    oth = CameraCalib("cam1", "thermal", K2, np.zeros(4), 50, 40, T)
    return rgb, oth


@pytest.mark.parametrize("depth", [float("inf"), 3.0])
def test_maps_equal_opencv_homography_warp_without_distortion(depth):
    rgb, oth = _cams()
    rng = np.random.default_rng(0)
    img = cv2.GaussianBlur(rng.uniform(0, 255, (40, 50)).astype(np.float32), (5, 5), 1.5)
    maps = align.warp_maps(rgb, oth, depth)
    ours = align.warp_image(img, maps)
    H = align.plane_homography(rgb, oth, depth)
    ref = cv2.warpPerspective(img, H, (80, 60), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    mx, my = maps[0], maps[1]
    valid = maps[2] & (mx >= 0) & (mx <= 49) & (my >= 0) & (my <= 39)  # away from OpenCV's border blending
    assert valid.mean() > 0.3
    np.testing.assert_allclose(ours[valid], ref[valid], atol=1e-2)


def test_plane_point_reprojection_error_is_zero_at_the_plane_and_parallax_off_it():
    rgb, oth = _cams()
    oth = CameraCalib(oth.name, oth.modality, oth.K, np.array([-0.1, 0.02, 0.002, -0.001]), 50, 40, oth.T_cam_rgb)
    rng = np.random.default_rng(0)
    uv = rng.uniform([10, 10], [70, 50], (20, 2))
    rays = np.concatenate([(uv - rgb.K[:2, 2]) / rgb.K[[0, 1], [0, 1]], np.ones((20, 1))], 1)
    maps = align.warp_maps(rgb, oth, 5.0)
    err = align.reprojection_errors(rgb, oth, maps, rays * 5.0)
    assert len(err) >= 10 and err.max() < 0.05
    # off the plane (z = 2.5 m): error within the parallax bound
    err2 = align.reprojection_errors(rgb, oth, maps, rays * 2.5)
    bound = align.parallax_bound(rgb, oth, 2.5, 5.0)
    assert err2.mean() > 0.5 * bound and err2.max() < 1.3 * bound


def _warm_centroid(img: np.ndarray, mask: np.ndarray, uv, r=5):
    u0, v0 = int(round(uv[0])), int(round(uv[1]))
    ys, xs = np.mgrid[v0 - r : v0 + r + 1, u0 - r : u0 + r + 1]
    patch = img[ys, xs].astype(np.float64) * (mask[ys, xs] > 0)
    wts = np.clip(patch - np.percentile(patch, 60), 0, None)
    return np.array([(wts * xs).sum() / wts.sum(), (wts * ys).sum() / wts.sum()])


def _fruit_errors(tmp_path: Path, plane_depth: float, invert_extrinsics: bool = False):
    raw = make_raw_capture(tmp_path / "raw", n=2, with_events=False)
    calib = readers.read_calibration(raw / "calib.yaml")
    th = calib.thermal
    if invert_extrinsics:
        th = CameraCalib(th.name, th.modality, th.K, th.dist, th.width, th.height, np.linalg.inv(th.T_cam_rgb))
    frame = readers.read_thermal(raw / "thermal" / "000000.png", (32, 40)).astype(np.float32)
    maps = align.warp_maps(calib.rgb, th, plane_depth)
    aligned = align.warp_image(frame, maps)
    return np.array([np.linalg.norm(_warm_centroid(aligned, maps[2], uv) - uv) for uv in FRUIT_UV])


def test_warm_fruit_centres_line_up_with_rgb(tmp_path: Path):
    """Images, not formulas: warm discs at known RGB pixels are found (warmth-weighted centroid) at the same
    pixels of the aligned thermal frame. Plane at the true 4 m: sub-pixel. Default inf: the parallax
    f * baseline / z = 80 * 0.051 / 4 = 1.0 px shows up. Wrong (inverted) extrinsics: clearly worse."""
    at_plane = _fruit_errors(tmp_path / "a", 4.0)
    at_inf = _fruit_errors(tmp_path / "b", float("inf"))
    wrong = _fruit_errors(tmp_path / "c", 4.0, invert_extrinsics=True)
    assert at_plane.mean() < 0.5, at_plane
    assert 0.5 < at_inf.mean() < 1.5, at_inf
    assert wrong.mean() > 1.5, wrong
