"""Writing the dataset folder: atomic output directory, image files, transforms.json and transforms_thermal.json.

Layout (docs/formats.md, "Dataset folder"):
```
OUT/transforms.json            RGB (file_path images/NNNNNN.png) + per-frame thermal/event keys + agrinerf block
OUT/transforms_thermal.json    same frames and poses, file_path thermal/NNNNNN.png, mask_path thermal_masks/...
OUT/images/  OUT/thermal/  OUT/thermal_masks/  OUT/events/ (PNG + NPZ)  OUT/event_masks/
```
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Dict, List, Optional

import numpy as np
from jaxtyping import Float

from agrinerf_ns.atomic import OutputExistsError, atomic_output_dir  # noqa: F401 (re-exported)
from agrinerf_ns.dataset_format import BLOCK, IMAGE, THERMAL, THERMAL_MASK, THERMAL_TRANSFORMS, TIMESTAMP, TRANSFORMS


def check_output(raw: Path, out: Path, overwrite: bool) -> None:
    """Refuse to write into (or over) the raw folder, or over a non-empty folder without ``overwrite``."""
    raw_r, out_r = raw.resolve(), out.resolve()
    if out_r == raw_r or raw_r in out_r.parents or out_r in raw_r.parents:
        raise ValueError(f"{out}: output must not be inside the raw folder {raw} (or contain it)")
    if out.exists() and not out.is_dir():
        raise OutputExistsError(f"{out}: exists and is not a folder")
    if out.is_dir() and any(out.iterdir()) and not overwrite:
        raise OutputExistsError(f"{out}: folder exists and is not empty (pass --overwrite to replace it)")


def intrinsics_block(K: Float[np.ndarray, "3 3"], width: int, height: int) -> Dict:
    """Nerfstudio camera keys for an undistorted pinhole camera.

    Nerfstudio (like COLMAP) puts the centre of the top-left pixel at (0.5, 0.5); the calibration (OpenCV/Kalibr)
    at (0, 0), so cx, cy get + 0.5.
    """
    return {
        "camera_model": "OPENCV",
        "fl_x": float(K[0, 0]),
        "fl_y": float(K[1, 1]),
        "cx": float(K[0, 2]) + 0.5,
        "cy": float(K[1, 2]) + 0.5,
        "w": int(width),
        "h": int(height),
        "k1": 0.0,
        "k2": 0.0,
        "p1": 0.0,
        "p2": 0.0,
    }


def split_names(names: List[str], eval_every: int) -> Dict[str, List[str]]:
    """Every ``eval_every``-th frame (starting with the 4th of each block, so both splits span the path) is held
    out; val and test are the same list."""
    if eval_every <= 1 or len(names) < 2:
        return {"train_filenames": list(names), "val_filenames": list(names), "test_filenames": list(names)}
    offset = min(eval_every // 2, len(names) - 1)
    val = [n for i, n in enumerate(names) if i % eval_every == offset % eval_every]
    if not val:
        val = [names[-1]]
    train = [n for n in names if n not in set(val)]
    return {"train_filenames": train, "val_filenames": val, "test_filenames": list(val)}


def write_transforms(
    out: Path,
    intrinsics: Dict,
    frames: List[Dict],
    agrinerf: Dict,
    eval_every: int,
) -> None:
    """Write transforms.json (RGB) and, when frames carry thermal files, transforms_thermal.json."""
    rgb_names = [f[IMAGE.key] for f in frames]
    meta = {**intrinsics, **split_names(rgb_names, eval_every), "frames": frames, BLOCK: agrinerf}
    _write_json(out / TRANSFORMS, meta)
    if frames and all(THERMAL.key in f for f in frames):
        th_frames = []
        for f in frames:
            tf = {IMAGE.key: f[THERMAL.key], "transform_matrix": f["transform_matrix"]}
            if THERMAL_MASK.key in f:
                tf["mask_path"] = f[THERMAL_MASK.key]
            if TIMESTAMP in f:
                tf[TIMESTAMP] = f[TIMESTAMP]
            tf["rgb_file_path"] = f[IMAGE.key]
            th_frames.append(tf)
        th_names = [f[IMAGE.key] for f in th_frames]
        # this file's images *are* the thermal frames: no "modalities" list (it describes transforms.json's
        # per-frame keys), the dataset's list is kept as "dataset_modalities"
        th_block = {k: v for k, v in agrinerf.items() if k != "modalities"}
        th_block.update(image_modality="thermal", dataset_modalities=agrinerf.get("modalities", []))
        th_meta = {**intrinsics, **split_names(th_names, eval_every), "frames": th_frames, BLOCK: th_block}
        _write_json(out / THERMAL_TRANSFORMS, th_meta)


def _write_json(path: Path, obj: Dict) -> None:
    tmp = path.with_suffix(path.suffix + ".part")
    tmp.write_text(json.dumps(obj, indent=2))
    tmp.rename(path)


def remove_files(out: Path, rel_paths: List[Optional[str]]) -> None:
    """Delete dataset files (of frames that were dropped)."""
    for rel in rel_paths:
        if rel:
            p = out / rel
            if p.exists():
                p.unlink()
