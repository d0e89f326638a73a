"""A small hand-made raw capture (docs/formats.md layout) with exact geometry, for the process tests.

The scene is a textured plane z = ``plane_depth`` in the RGB camera's frame (the rig translates sideways, the plane
moves with it, so every frame sees it fully). RGB frames sample a smooth texture; thermal frames render the same
plane through the thermal camera's own intrinsics, distortion and rig offset with counts from a real Fieldscale
frame; events are drawn at the plane points where the texture changes between frames. Warm "fruit" discs sit at
known plane points so alignment can be measured on images.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional

import cv2
import h5py
import numpy as np
import yaml

DATA = Path(__file__).parents[1] / "data" / "fieldscale-thermal"

RGB_K = np.array([[80.0, 0, 31.5], [0, 80.0, 23.5], [0, 0, 1]])
TH_K = np.array([[50.0, 0, 19.5], [0, 50.0, 15.5], [0, 0, 1]])
EV_K = np.array([[70.0, 0, 27.5], [0, 70.0, 20.5], [0, 0, 1]])
TH_DIST = np.array([-0.15, 0.03, 0.002, -0.002])
FRUIT_UV = np.array([[14.0, 11.0], [50.0, 36.0], [32.0, 24.0]])  # RGB pixels of fruit centres (undistorted)


def _rot(ax: float, ay: float) -> np.ndarray:
    rx = cv2.Rodrigues(np.array([ax, 0.0, 0.0]))[0]
    ry = cv2.Rodrigues(np.array([0.0, ay, 0.0]))[0]
    return ry @ rx


def rig() -> Dict[str, np.ndarray]:
    """T_thermal_rgb and T_event_rgb (4x4)."""
    T_th = np.eye(4)
    T_th[:3, :3] = _rot(0.03, -0.05)
    T_th[:3, 3] = [-0.05, 0.01, 0.0]
    T_ev = np.eye(4)
    T_ev[:3, :3] = _rot(-0.01, 0.015)
    T_ev[:3, 3] = [0.04, 0.0, 0.0]
    return {"thermal": T_th, "event": T_ev}


def texture_value(X: np.ndarray, Y: np.ndarray, shift: float) -> np.ndarray:
    """Smooth plane texture in [0, 1] at plane coordinates (metres), moving with ``shift``."""
    Xs = X + shift
    return 0.5 + 0.25 * np.sin(9.0 * Xs) * np.cos(7.0 * Y) + 0.2 * np.sin(23.0 * Xs + 3.0 * Y)


def plane_points(K: np.ndarray, T_cam_rgb: np.ndarray, w: int, h: int, depth: float, dist=None) -> np.ndarray:
    """Plane points (RGB frame) seen by each pixel of a camera (inverse of its distortion by cv2.undistortPoints)."""
    u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], -1)[:, None, :]
    d = np.zeros(4) if dist is None else dist
    norm = cv2.undistortPoints(pts, K, d).reshape(-1, 2)
    rays = np.concatenate([norm, np.ones((norm.shape[0], 1))], 1)
    R, t = T_cam_rgb[:3, :3], T_cam_rgb[:3, 3]
    # X_cam = R X_rgb + t  ->  X_rgb = R^T (X_cam - t); camera centre in RGB frame c = -R^T t, direction R^T ray
    c = -R.T @ t
    dirs = rays @ R  # (R^T ray) for each row
    s = (depth - c[2]) / dirs[:, 2]
    return (c[None] + s[:, None] * dirs).reshape(h, w, 3)


def make_raw_capture(
    root: Path,
    n: int = 6,
    plane_depth: float = 4.0,
    with_thermal: bool = True,
    with_events: bool = True,
    event_format: str = "h5",
    thermal_offset_s: float = 0.0,
    num_noise_events: int = 0,
    seed: int = 0,
) -> Path:
    """Write the raw capture under ``root`` and return it. 64x48 RGB, 40x32 thermal, 56x42 events, 10 fps."""
    rng = np.random.default_rng(seed)
    root.mkdir(parents=True, exist_ok=True)
    T = rig()
    times = 1.0 + 0.1 * np.arange(n)
    shifts = 0.05 * np.arange(n)
    cams = {"cam0": _cam_yaml(RGB_K, np.zeros(4), 64, 48, "rgb")}
    T_prev = np.eye(4)
    idx = 1
    if with_thermal:
        cams[f"cam{idx}"] = {**_cam_yaml(TH_K, TH_DIST, 40, 32, "thermal"), "T_cn_cnm1": T["thermal"].tolist()}
        T_prev = T["thermal"]
        idx += 1
    if with_events:
        T_rel = T["event"] @ np.linalg.inv(T_prev)
        cams[f"cam{idx}"] = {**_cam_yaml(EV_K, np.zeros(4), 56, 42, "event"), "T_cn_cnm1": T_rel.tolist()}
    (root / "calib.yaml").write_text(yaml.safe_dump(cams, sort_keys=False))

    # RGB
    (root / "rgb").mkdir(exist_ok=True)
    P = plane_points(RGB_K, np.eye(4), 64, 48, plane_depth)
    fruit_xy = [P[int(v), int(u), :2] for u, v in FRUIT_UV]
    lines = []
    for i in range(n):
        val = texture_value(P[..., 0], P[..., 1], shifts[i])
        img = np.stack([val, 0.8 * val, 1 - val], -1)
        img = np.clip(img * 255 + rng.normal(0, 2, img.shape), 0, 255).astype(np.uint8)
        cv2.imwrite(str(root / "rgb" / f"{i:06d}.png"), img[:, :, ::-1])
        lines.append(f"{i:06d}.png {times[i]:.6f}")
    (root / "rgb" / "timestamps.txt").write_text("\n".join(lines) + "\n")

    # thermal: counts from a real frame, plus warm fruit discs at known plane points
    if with_thermal:
        (root / "thermal").mkdir(exist_ok=True)
        real = cv2.imread(str(DATA / "0000.tiff"), cv2.IMREAD_UNCHANGED).astype(np.float64)
        Pt = plane_points(TH_K, T["thermal"], 40, 32, plane_depth, TH_DIST)
        lines = []
        for i in range(n):
            val = texture_value(Pt[..., 0], Pt[..., 1], shifts[i])
            counts = 2000 + 600 * val
            # the real frame adds realistic structure/noise (sampled at the same plane points)
            rx = np.clip(((Pt[..., 0] + 1.5) * 200).astype(int), 0, real.shape[1] - 1)
            ry = np.clip(((Pt[..., 1] + 1.2) * 200).astype(int), 0, real.shape[0] - 1)
            counts += 0.1 * (real[ry, rx] - real.mean())
            for fx, fy in fruit_xy:
                r2 = (Pt[..., 0] - fx) ** 2 + (Pt[..., 1] - fy) ** 2
                counts += 3000 * np.exp(-r2 / (2 * 0.08**2))
            cv2.imwrite(str(root / "thermal" / f"{i:06d}.png"), np.clip(counts, 0, 65535).astype(np.uint16))
            lines.append(f"{i:06d}.png {times[i] + thermal_offset_s:.6f}")
        (root / "thermal" / "timestamps.txt").write_text("\n".join(lines) + "\n")

    # events: per inter-frame interval, events where the texture's log value changed
    if with_events:
        (root / "events").mkdir(exist_ok=True)
        Pe = plane_points(EV_K, T["event"], 56, 42, plane_depth)
        xs, ys, ts, ps = [], [], [], []
        prev = np.log(texture_value(Pe[..., 0], Pe[..., 1], shifts[0] - 0.05) + 0.05)
        for i in range(n):
            cur = np.log(texture_value(Pe[..., 0], Pe[..., 1], shifts[i]) + 0.05)
            d = cur - prev
            nev = np.floor(np.abs(d) / 0.1).astype(int)
            yy, xx = np.nonzero(nev)
            for y_, x_ in zip(yy, xx, strict=True):
                k = nev[y_, x_]
                tt = times[i] - 0.1 + 0.1 * rng.uniform(0, 1, k)
                xs += [x_] * k
                ys += [y_] * k
                ts += list(tt)
                ps += [1 if d[y_, x_] > 0 else 0] * k
            prev = cur
        if num_noise_events:
            xs += list(rng.integers(0, 56, num_noise_events))
            ys += list(rng.integers(0, 42, num_noise_events))
            ts += list(rng.uniform(times[0] - 0.1, times[-1], num_noise_events))
            ps += list(rng.integers(0, 2, num_noise_events))
        order = np.argsort(np.asarray(ts), kind="stable")
        x = np.asarray(xs, np.uint16)[order]
        y = np.asarray(ys, np.uint16)[order]
        t = np.round(np.asarray(ts)[order] * 1e6).astype(np.int64)
        p = np.asarray(ps, np.uint8)[order]
        write_events(root / "events", x, y, t, p, event_format)

    # odometry (exact here): camera moves along +x with the texture shift; plane fixed in its frame is fine for
    # geometry checks, poses only need to be valid
    lines = []
    for i in range(n):
        lines.append(f"{times[i]:.6f} {shifts[i]:.6f} 0 0 0 0 0 1")
    (root / "odometry.txt").write_text("\n".join(lines) + "\n")
    return root


def write_events(folder: Path, x, y, t, p, fmt: str = "h5", name: Optional[str] = None) -> Path:
    """Write events in one of the accepted formats (t in microseconds in arrays; seconds in text)."""
    if fmt == "h5":
        path = folder / (name or "events.h5")
        with h5py.File(path, "w") as f:
            g = f.create_group("events")
            g["x"], g["y"], g["t"], g["p"] = x, y, t, p
    elif fmt == "npz":
        path = folder / (name or "events.npz")
        np.savez(path, x=x, y=y, t=t, p=p)
    else:
        path = folder / (name or "events.txt")
        with open(path, "w") as fh:
            for a, b, c, d in zip(t, x, y, p, strict=True):
                fh.write(f"{a / 1e6:.6f} {b} {c} {d}\n")
    return path


def _cam_yaml(K: np.ndarray, dist: np.ndarray, w: int, h: int, modality: str) -> Dict:
    return {
        "camera_model": "pinhole",
        "intrinsics": [float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])],
        "distortion_model": "radtan",
        "distortion_coeffs": [float(v) for v in dist],
        "resolution": [w, h],
        "modality": modality,
    }
