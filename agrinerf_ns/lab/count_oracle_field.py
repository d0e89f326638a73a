"""The field a perfect reconstruction would learn, sampled as the field path samples a trained one: a synthetic
capture's own primitives (ellipsoid leaves and fruit, bark and stakes, the ground) on the voxel grid, with their true
temperatures, seen from the training views through the true depth. Counting it measures the field path's grouping
(:mod:`agrinerf_ns.count.components`) apart from the reconstruction: the ceiling of the 3D count at that voxel size.

``python -m agrinerf_ns.lab.count_oracle_field --raw RAW --data DATASET`` prints its score (and writes ``--out``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated, Any, Dict, List, Optional, Tuple

import numpy as np
import tyro

from agrinerf_ns.count.components import ComponentConfig, find_fruit
from agrinerf_ns.count.fruit_score import (
    CountScore,
    Similarity,
    align_to_capture,
    read_split,
    score_fruit,
    visible_fruit,
)
from agrinerf_ns.count.render import CountInputError, RenderSet, WorldFrame
from agrinerf_ns.count.volume import DepthView, SampledField, VolumeConfig, VoxelGrid, occupied_box, views_seeing
from agrinerf_ns.dataset_format import TRANSFORMS

GROUND_LAYER = 0.03
"""The ground is dense from z = 0 down this far (metres): a surface, as a trained field learns it."""


def depth_views(renders: RenderSet, dataset: Path, split: Tuple[str, ...] = ("train",)) -> List[DepthView]:
    """Depth views of oracle renders (dataset frame, unit rays), with the dataset's pinhole intrinsics."""
    meta = json.loads((Path(dataset) / TRANSFORMS).read_text())
    poses = {f["file_path"]: np.asarray(f["transform_matrix"], np.float64)[:3] for f in meta["frames"]}
    views = []
    for view in renders.views:
        if view.split not in split:
            continue
        solid = np.isfinite(view.depth) & (view.accumulation >= 0.5)
        views.append(
            DepthView(poses[view.file_path], float(meta["fl_x"]), float(meta["fl_y"]), float(meta["cx"]),
                      float(meta["cy"]), np.where(solid, view.depth, np.inf).astype(np.float64),
                      view.points()[solid].astype(np.float64))
        )  # fmt: skip
    return views


def true_field(raw: Path, grid: VoxelGrid, to_capture: Similarity) -> Tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(flat indices of the voxels inside the capture's primitives or the ground layer, their material, their true
    temperature in degrees C); the grid is in the dataset's frame, the primitives in the capture's."""
    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.capture import make_scene
    from agrinerf_ns.synth.raycast import GROUND
    from agrinerf_ns.synth.scene import BARK, FRUIT, LEAF, STAKE

    written = json.loads((Path(raw) / "truth" / "scene.json").read_text())["config"]
    settings: Dict[str, Any] = {k: tuple(v) if isinstance(v, list) else v for k, v in written.items()}
    config = SynthConfig(**settings)
    scene, _ = make_scene(config)
    prims, temps = scene.prims, scene.temps
    shape = np.array(grid.shape)
    material = np.full(int(np.prod(shape)), -1, np.int8)
    temperature = np.full(int(np.prod(shape)), np.nan, np.float32)

    def voxels_in(lo: np.ndarray, hi: np.ndarray) -> Tuple[np.ndarray, np.ndarray]:
        """Flat indices and capture-frame centres of the voxels whose centres may lie in the capture box lo..hi."""
        box = to_capture.inverse(np.stack(np.meshgrid(*zip(lo, hi, strict=True), indexing="ij"), -1).reshape(-1, 3))
        i0 = np.clip(np.floor((box.min(0) - grid.origin) / grid.step).astype(int), 0, shape - 1)
        i1 = np.clip(np.ceil((box.max(0) - grid.origin) / grid.step).astype(int), 0, shape - 1)
        if np.any(box.max(0) < grid.origin) or np.any(box.min(0) > grid.origin + (shape - 1) * grid.step):
            return np.zeros(0, np.int64), np.zeros((0, 3))
        ijk = np.stack(
            np.meshgrid(*[np.arange(a, b + 1) for a, b in zip(i0, i1, strict=True)], indexing="ij"), -1
        ).reshape(-1, 3)
        flat = np.ravel_multi_index(ijk.T, grid.shape)
        return flat, to_capture.apply(grid.origin + ijk * grid.step)

    # the ground layer first, so that anything standing on it overwrites it
    lo = to_capture.apply(np.stack([grid.origin, grid.origin + (shape - 1) * grid.step]))
    flat, points = voxels_in(np.minimum(lo[0], lo[1]) * [1, 1, 0] + [0, 0, -GROUND_LAYER],
                             np.maximum(lo[0], lo[1]) * [1, 1, 0])  # fmt: skip
    inside = (points[:, 2] <= 0) & (points[:, 2] > -GROUND_LAYER)
    material[flat[inside]] = GROUND
    temperature[flat[inside]] = temps["ground"]
    base = {LEAF: temps["leaf"], FRUIT: temps["fruit"], BARK: temps["bark"], STAKE: temps["stake"]}
    for k in range(prims.num_ellipsoids):
        flat, points = voxels_in(prims.aabb_lo[k], prims.aabb_hi[k])
        if len(flat) == 0:
            continue
        inside = (((points - prims.ell_center[k]) / prims.ell_radii[k]) ** 2).sum(1) <= 1.0
        mat = int(scene.material[k])
        material[flat[inside]] = mat
        temperature[flat[inside]] = base[mat] + scene.temp_offset[k]
    for c in range(len(prims.cyl_radius)):
        k = prims.num_ellipsoids + c
        flat, points = voxels_in(prims.aabb_lo[k], prims.aabb_hi[k])
        if len(flat) == 0:
            continue
        p0, p1 = prims.cyl_p0[c], prims.cyl_p1[c]
        axis = p1 - p0
        t = np.clip((points - p0) @ axis / max(float(axis @ axis), 1e-12), 0.0, 1.0)
        inside = np.linalg.norm(points - (p0 + t[:, None] * axis), axis=1) <= prims.cyl_radius[c]
        keep = flat[inside & (material[flat] < 0)]  # leaves and fruit in front of a branch stay
        material[keep] = int(scene.material[k])
        temperature[keep] = base[int(scene.material[k])]
    solid = np.nonzero(material >= 0)[0]
    return solid, material[solid], temperature[solid]


def oracle_field(raw: Path, data: Path, config: VolumeConfig, seen_margin: float, pad: float) -> SampledField:
    """The capture's true field on the grid over the occupied box of its training views' true depth, as
    :func:`agrinerf_ns.count.volume.sample_field` samples a trained one (identity dataparser frame, scale 1)."""
    from agrinerf_ns.lab.count_oracle import oracle_renders

    renders = oracle_renders(Path(raw), Path(data), "true")
    train_names = set(read_split(Path(data), "train_filenames"))
    for view in renders.views:
        view.split = "train" if not train_names or view.file_path in train_names else "eval"
    views = depth_views(renders, Path(data))
    frame = WorldFrame(np.eye(4)[:3], 1.0)
    box = occupied_box(views, config, pad)
    grid = VoxelGrid.over(box, config.voxel_size, config.max_voxels)
    to_capture = align_to_capture(Path(data), Path(raw))
    flat, _, temperature = true_field(Path(raw), grid, to_capture)
    seen_by = views_seeing(grid.centres(flat), views, seen_margin)
    keep = seen_by > 0
    eye = np.mean([v.centre for v in views], axis=0)
    return SampledField(grid, flat[keep], temperature[keep, None], temperature[keep], seen_by[keep], len(flat),
                        "temperature", "the capture's true temperature", frame, eye, views, seen_margin)  # fmt: skip


@dataclass
class OracleFieldArgs:
    """Count the fruit of a synthetic capture's true field (the field path's ceiling at its voxel size)."""

    raw: Path
    """The synthetic raw capture (agrinerf-synth, with truth/)."""
    data: Path
    """Its processed dataset (agrinerf-process)."""
    volume: Annotated[VolumeConfig, tyro.conf.arg(name="")] = field(default_factory=VolumeConfig)
    components: Annotated[ComponentConfig, tyro.conf.arg(name="")] = field(default_factory=ComponentConfig)
    seen_margin: float = 0.05
    """A voxel is seen when at most this far behind a training view's true depth (metres)."""
    match_distance: float = 0.05
    """Scoring distance (metres)."""
    out: Optional[Path] = None
    """Where to write the score as JSON."""


def main(args: OracleFieldArgs) -> CountScore:
    from agrinerf_ns.count.fruit_score import read_truth_fruit
    from agrinerf_ns.count.pipeline import raw_training_frames

    truth = read_truth_fruit(args.raw)
    if not (args.raw / "truth" / "scene.json").is_file():
        raise CountInputError(f"{args.raw / 'truth' / 'scene.json'}: missing; the true field needs the scene")
    sampled = oracle_field(args.raw, args.data, args.volume, args.seen_margin, args.components.max_diameter)
    fruit, stats = find_fruit(sampled, args.components)
    frames = json.loads((args.data / TRANSFORMS).read_text())["frames"]
    train = raw_training_frames(args.data, [f["file_path"] for f in frames])
    visible = visible_fruit(args.raw, train, truth)
    centres = align_to_capture(args.data, args.raw).apply(
        np.stack([f.centre for f in fruit]) if fruit else np.zeros((0, 3))
    )
    temps = np.array([np.nan if f.temperature is None else f.temperature for f in fruit])
    score = score_fruit(centres, truth, visible, args.match_distance, temps)
    report = {"score": score.as_dict(), "grid_shape": list(sampled.grid.shape), "voxel_size": sampled.grid.step,
              "dense_voxels": sampled.dense, "seen_voxels": len(sampled.flat), **stats}  # fmt: skip
    print(json.dumps(report, indent=1))
    if args.out is not None:
        Path(args.out).write_text(json.dumps(report, indent=1) + "\n")
    return score


if __name__ == "__main__":
    main(tyro.cli(OracleFieldArgs))
