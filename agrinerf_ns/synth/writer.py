"""Deterministic writers of the raw-capture files (PNG without metadata, HDF5 without timestamps, YAML, TUM)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, ContextManager, Dict, List, Optional, Sequence, Tuple, Union

import h5py
import numpy as np
import yaml

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.synth.camera_rig import quat_from_R
from agrinerf_ns.synth.raycast import PinholeRadtan


def frame_name(i: int) -> str:
    return f"{i:06d}.png"


def write_timestamps(path: Path, names: Sequence[str], times: Union[np.ndarray, Sequence[float]]) -> None:
    path.write_text("".join(f"{n} {t:.6f}\n" for n, t in zip(names, times, strict=True)))


def write_exposures(
    path: Path,
    names: Sequence[str],
    starts: Union[np.ndarray, Sequence[float]],
    ends: Union[np.ndarray, Sequence[float]],
) -> None:
    """rgb/exposures.txt: "<file name> <exposure start> <exposure end>" (seconds, the timestamps' clock)."""
    path.write_text("".join(f"{n} {a:.6f} {b:.6f}\n" for n, a, b in zip(names, starts, ends, strict=True)))


def tum_line(t: float, T: np.ndarray) -> str:
    q = quat_from_R(T[:3, :3])
    x, y, z = T[:3, 3]
    return f"{t:.6f} {x:.6f} {y:.6f} {z:.6f} {q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}\n"


def write_tum(
    path: Path, times: Union[np.ndarray, Sequence[float]], poses: Sequence[np.ndarray], header: str = ""
) -> None:
    path.write_text(header + "".join(tum_line(t, T) for t, T in zip(times, poses, strict=True)))


def write_events(
    path: Path, x: np.ndarray, y: np.ndarray, t_us: np.ndarray, p: np.ndarray, width: int, height: int
) -> None:
    """events/{x,y,t,p} datasets (uint16, uint16, int64 microseconds, uint8), no object timestamps."""
    with h5py.File(path, "w", libver="earliest") as f:
        g = f.create_group("events", track_order=False)
        for name, arr in (
            ("x", x.astype(np.uint16)),
            ("y", y.astype(np.uint16)),
            ("t", t_us.astype(np.int64)),
            ("p", p.astype(np.uint8)),
        ):
            kw = (
                dict(chunks=(min(65536, arr.size),), compression="gzip", compression_opts=4, shuffle=True)
                if arr.size
                else {}
            )
            g.create_dataset(name, data=arr, track_times=False, **kw)
        g.attrs["width"] = np.int64(width)
        g.attrs["height"] = np.int64(height)


def camchain(
    cams: Dict[str, PinholeRadtan], T_c_c0: Dict[str, np.ndarray], radiometric: Optional[Dict[str, Any]] = None
) -> dict:
    """Kalibr camchain dict: cam0 rgb, cam1 thermal, cam2 event, T_cn_cnm1 chaining them; ``radiometric`` (the
    thermal camera's counts-to-temperature calibration) goes into cam1's entry."""
    order = ["rgb", "thermal", "event"]
    out = {}
    for n, key in enumerate(order):
        c = cams[key]
        entry: Dict[str, Any] = {
            "camera_model": "pinhole",
            "intrinsics": [float(c.fx), float(c.fy), float(c.cx), float(c.cy)],
            "distortion_model": "radtan",
            "distortion_coeffs": [float(v) for v in c.dist],
            "resolution": [int(c.width), int(c.height)],
            "modality": key,
            "rostopic": f"/{key}/image_raw" if key != "event" else "/prophesee/events",
        }
        if key == "thermal" and radiometric is not None:
            entry["radiometric"] = dict(radiometric)
        if n > 0:
            T = T_c_c0[key] @ np.linalg.inv(T_c_c0[order[n - 1]])
            entry["T_cn_cnm1"] = [[round(float(v), 12) for v in row] for row in T]
            entry["cam_overlaps"] = [n - 1]
        out[f"cam{n}"] = entry
    return out


def write_yaml(path: Path, data: dict) -> None:
    path.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None))


def yolo_lines(boxes: List[Tuple[int, int, int, int, int, int]], width: int, height: int) -> str:
    """YOLO "0 cx cy w h" (normalised) lines of (fruit, x0, y0, x1, y1, pixels) boxes (x1, y1 inclusive)."""
    lines = []
    for _, x0, y0, x1, y1, _ in boxes:
        w, h = x1 - x0 + 1, y1 - y0 + 1
        lines.append(f"0 {(x0 + w / 2) / width:.6f} {(y0 + h / 2) / height:.6f} {w / width:.6f} {h / height:.6f}\n")
    return "".join(lines)


def coco(
    boxes_per_image: List[List[Tuple[int, int, int, int, int, int]]], names: List[str], width: int, height: int
) -> dict:
    """COCO detection dict; bbox [x, y, w, h] in pixels with the top-left pixel corner at (0, 0)."""
    images: List[dict] = []
    anns: List[dict] = []
    for i, (name, boxes) in enumerate(zip(names, boxes_per_image, strict=True)):
        images.append({"id": i, "file_name": name, "width": width, "height": height})
        for fid, x0, y0, x1, y1, npx in boxes:
            anns.append(
                {
                    "id": len(anns) + 1,
                    "image_id": i,
                    "category_id": 1,
                    "bbox": [x0, y0, x1 - x0 + 1, y1 - y0 + 1],
                    "area": npx,
                    "iscrowd": 0,
                    "fruit_id": fid,
                }
            )
    return {"images": images, "annotations": anns, "categories": [{"id": 1, "name": "fruit"}]}


def write_json(path: Path, data: object) -> None:
    path.write_text(json.dumps(data, indent=1) + "\n")


def atomic_folder(out: Path) -> ContextManager[Path]:
    """Yield a temporary sibling folder; on success it replaces ``out`` (absent or empty), on failure it is removed."""
    return atomic_output_dir(out, overwrite=False)
