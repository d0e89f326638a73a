"""Warp thermal and event frames into the RGB camera ("aligned intrinsics").

For an RGB pixel u (undistorted pinhole, intrinsics K_rgb), the scene is assumed to lie on the plane z = d in the
RGB camera's frame (``plane_depth`` d; ``inf`` by default). With X_o = R X_rgb + t the other camera's frame
(``T_cam_rgb`` from the calibration), the pinhole part of the mapping is the plane homography

    H = K_o (R + t n^T / d) K_rgb^-1,   n = (0, 0, 1);   d = inf gives H = K_o R K_rgb^-1,

and the other camera's radtan distortion is applied after it, so undistortion and warp are one resampling
(``cv2.remap``). Pixels that land outside the other sensor get mask 0. Points off the plane are misplaced by the
parallax ``f * |t_xy| * |1/z - 1/d|`` pixels (:func:`parallax_bound`).
"""

from __future__ import annotations

from typing import Tuple

import cv2
import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.process.readers import CameraCalib


def plane_homography(
    rgb: CameraCalib, other: CameraCalib, plane_depth: float = float("inf")
) -> Float[np.ndarray, "3 3"]:
    """Homography from RGB pixels to the other camera's undistorted pixels, for the plane z = plane_depth."""
    R = other.T_cam_rgb[:3, :3]
    t = other.T_cam_rgb[:3, 3:4]
    M = R.copy()
    if np.isfinite(plane_depth):
        if plane_depth <= 0:
            raise ValueError(f"plane depth must be positive, got {plane_depth}")
        M = R + t @ np.array([[0.0, 0.0, 1.0 / plane_depth]])
    return other.K @ M @ np.linalg.inv(rgb.K)


def distort_normalized(xy: Float[np.ndarray, "*b 2"], dist: Float[np.ndarray, "4"]) -> Float[np.ndarray, "*b 2"]:
    """Apply radtan distortion (k1, k2, p1, p2) to normalised image coordinates."""
    k1, k2, p1, p2 = dist
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


def warp_maps(
    rgb: CameraCalib, other: CameraCalib, plane_depth: float = float("inf")
) -> Tuple[Float[np.ndarray, "h w"], Float[np.ndarray, "h w"], Bool[np.ndarray, "h w"]]:
    """cv2.remap maps (x, y in the other camera's raw image, float32) for every RGB pixel, and the valid mask."""
    h, w = rgb.height, rgb.width
    H = plane_homography(rgb, other, plane_depth)
    Kinv = np.linalg.inv(other.K)
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pix = np.stack([u, v, np.ones_like(u)], axis=-1) @ H.T  # undistorted pixels of the other camera (homog.)
    z = pix[..., 2]
    front = z > 1e-9
    z_safe = np.where(front, z, 1.0)
    und = pix / z_safe[..., None]
    norm = und @ Kinv.T
    xy = distort_normalized(norm[..., :2], other.dist)
    mx = other.K[0, 0] * xy[..., 0] + other.K[0, 2]
    my = other.K[1, 1] * xy[..., 1] + other.K[1, 2]
    valid = front & (mx >= -0.5) & (mx <= other.width - 0.5) & (my >= -0.5) & (my <= other.height - 0.5)
    mx = np.where(valid, mx, -10.0).astype(np.float32)
    my = np.where(valid, my, -10.0).astype(np.float32)
    return mx, my, valid


def warp_image(image: np.ndarray, maps: Tuple[np.ndarray, np.ndarray, np.ndarray], nearest: bool = False) -> np.ndarray:
    """Resample ``image`` (the other camera's raw frame) into the RGB camera; invalid pixels become 0."""
    mx, my, valid = maps
    interp = cv2.INTER_NEAREST if nearest else cv2.INTER_LINEAR
    out = cv2.remap(image, mx, my, interpolation=interp, borderMode=cv2.BORDER_REPLICATE)
    out[~valid] = 0
    return out


def undistort_maps(rgb: CameraCalib) -> Tuple[np.ndarray, np.ndarray] | None:
    """Maps that undistort the RGB frames keeping K_rgb (None when the RGB camera has no distortion)."""
    if not np.any(rgb.dist):
        return None
    return cv2.initUndistortRectifyMap(rgb.K, rgb.dist, None, rgb.K, (rgb.width, rgb.height), cv2.CV_32FC1)


def project_points(cam: CameraCalib, X_cam: Float[np.ndarray, "n 3"], distort: bool = True) -> Float[np.ndarray, "n 2"]:
    """Project points given in ``cam``'s frame to its (distorted) pixels."""
    xy = X_cam[:, :2] / X_cam[:, 2:3]
    if distort:
        xy = distort_normalized(xy, cam.dist)
    return np.stack([cam.K[0, 0] * xy[:, 0] + cam.K[0, 2], cam.K[1, 1] * xy[:, 1] + cam.K[1, 2]], axis=-1)


def locate_in_aligned(
    maps: Tuple[np.ndarray, np.ndarray, np.ndarray], target: Float[np.ndarray, "2"], iters: int = 3
) -> Float[np.ndarray, "2"] | None:
    """Invert a warp map numerically: the aligned (RGB) pixel whose map value is the other camera's ``target``.

    Nearest grid node first, then Gauss-Newton steps on the bilinearly interpolated map. None when not found or
    when the map at the result is more than 0.1 px from ``target``.
    """
    mx, my, valid = maps
    d2 = (mx - target[0]) ** 2 + (my - target[1]) ** 2
    d2 = np.where(valid, d2, np.inf)
    idx = int(np.argmin(d2))
    if not np.isfinite(d2.flat[idx]):
        return None
    v, u = divmod(idx, mx.shape[1])
    p = np.array([u, v], dtype=np.float64)
    h, w = mx.shape
    for _ in range(iters):
        ui, vi = int(np.clip(round(p[0]), 1, w - 2)), int(np.clip(round(p[1]), 1, h - 2))
        J = np.array(
            [
                [(mx[vi, ui + 1] - mx[vi, ui - 1]) / 2, (mx[vi + 1, ui] - mx[vi - 1, ui]) / 2],
                [(my[vi, ui + 1] - my[vi, ui - 1]) / 2, (my[vi + 1, ui] - my[vi - 1, ui]) / 2],
            ]
        )
        val = _bilinear(mx, my, p)
        if np.linalg.cond(J) > 1e6:
            break
        p = p - np.linalg.solve(J, val - target)
    if np.linalg.norm(_bilinear(mx, my, p) - target) > 0.1:
        return None  # not converged (e.g. at the edge of the valid region)
    return p


def _bilinear(mx: np.ndarray, my: np.ndarray, p: np.ndarray) -> np.ndarray:
    pts = np.array([[p]], dtype=np.float32)
    x = cv2.remap(mx, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    y = cv2.remap(my, pts[..., 0], pts[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return np.array([float(x[0, 0]), float(y[0, 0])])


def reprojection_errors(
    rgb: CameraCalib,
    other: CameraCalib,
    maps: Tuple[np.ndarray, np.ndarray, np.ndarray],
    X_rgb: Float[np.ndarray, "n 3"],
) -> Float[np.ndarray, " m"]:
    """Pixel distance, in the aligned image, between where 3D points (RGB camera frame) appear in the RGB frame
    and where the warped other frame shows them. Points outside either image are skipped."""
    X_rgb = X_rgb[X_rgb[:, 2] > 1e-6]
    u_rgb = project_points(rgb, X_rgb, distort=False)
    X_o = X_rgb @ other.T_cam_rgb[:3, :3].T + other.T_cam_rgb[:3, 3]
    keep = X_o[:, 2] > 1e-6
    u_o = project_points(other, X_o[keep])
    u_rgb = u_rgb[keep]
    errs = []
    for a, b in zip(u_rgb, u_o, strict=True):
        if not (0 <= a[0] < rgb.width and 0 <= a[1] < rgb.height):
            continue
        if not (0 <= b[0] < other.width and 0 <= b[1] < other.height):
            continue
        p = locate_in_aligned(maps, b)
        if p is not None:
            errs.append(float(np.linalg.norm(p - a)))
    return np.asarray(errs)


def parallax_bound(rgb: CameraCalib, other: CameraCalib, z: float, plane_depth: float = float("inf")) -> float:
    """Misplacement (RGB pixels) of a point at depth z when the warp assumes the plane at ``plane_depth``."""
    t = other.T_cam_rgb[:3, 3]
    inv_d = 0.0 if not np.isfinite(plane_depth) else 1.0 / plane_depth
    return float(rgb.K[0, 0] * np.linalg.norm(t[:2]) * abs(1.0 / z - inv_d))
