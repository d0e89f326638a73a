"""How good a dataset's fruit masks are, against a synthetic capture's truth: pixel precision, recall and IoU over
the known pixels, the share of the truth's fruit (with at least ``--min-pixels`` in a frame) that a mask touches, the
share of the masks' regions that touch a fruit, and the fruit F1 of those two.

    python benchmarks/fruit_mask_quality.py --raw RAW --dataset DATASET [--out TABLE.md]
    python benchmarks/fruit_mask_quality.py --raw RAW --dataset DATASET --colour-scores 0.3 0.4 0.5  # tuning sweep
    python benchmarks/fruit_mask_quality.py --raw RAW --dataset DATASET --blob-thresholds 0.3 0.5 1 --thermal-contrast
    python benchmarks/fruit_mask_quality.py --raw RAW --write-oracle MASKS/   # truth masks, for the oracle row only

The truth (``truth/fruit_ids``) is the raw RGB frame's; it is undistorted with the RGB calibration as the processing
undistorts the frames (nearest pixel). ``--write-oracle`` writes 8-bit masks from it (fruit 255, background 0) to
feed ``agrinerf-process --fruit-masks``: an oracle that measures the ceiling, never an input to a reported row.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional, Tuple

import cv2
import numpy as np
import tyro
from scipy import ndimage

from agrinerf_ns.dataset_format import FRUIT_MASK_CAMERA
from agrinerf_ns.fruit_mask_format import FRUIT, fruit_and_known
from agrinerf_ns.process.fruit_mask_makers import ColourBalance


@dataclass
class Args:
    raw: Path
    """A synthetic raw capture (agrinerf-synth), with truth/fruit_ids."""
    dataset: Optional[Path] = None
    """Its processed dataset with fruit masks (agrinerf-process --fruit-masks / --fruit-mask-maker)."""
    out: Optional[Path] = None
    """Markdown table to write (else printed)."""
    min_pixels: int = 3
    colour_scores: Tuple[float, ...] = ()
    """Instead of the dataset's masks: the colour maker's masks of its RGB frames at each of these
    ``min_colour_score`` values (the other settings default), one row each: how the setting was chosen."""
    balance: Tuple[ColourBalance, ...] = ()
    """With or instead of --colour-scores: each ``colour_balance`` (none, grey-world) swept beside each score."""
    denoise_px: Tuple[float, ...] = ()
    """With or instead of --colour-scores: each ``colour_denoise_px`` swept beside each score (default score)."""
    min_region_pixels: Tuple[int, ...] = ()
    """With or instead of --colour-scores: each ``min_region_pixels`` swept beside each score and smoothing."""
    blob_thresholds: Tuple[float, ...] = ()
    """Instead of the dataset's masks: the thermal maker's masks of its thermal frames at each of these
    ``blob_threshold`` values (the ``blobs`` rule), one row each, scored in the thermal camera's view."""
    canopy_offsets: Tuple[float, ...] = (1.5,)
    """With --blob-thresholds: each ``min_canopy_offset`` (robust spreads) swept beside each threshold."""
    polarity: str = "both"
    """With --blob-thresholds: fruit warmer than the canopy (warm), cooler (cool) or either (both)."""
    thermal_contrast: bool = False
    """Also a row of the thermal maker's earlier rule (``--thermal-rule contrast``), scored the same way."""
    body_views: Tuple[int, ...] = ()
    """Instead of the dataset's masks: the ``bodies`` rule's masks of its thermal frames (every frame, placed in 3D
    with the dataset's poses), one row per ``bodies.min_views``, scored in the thermal camera's view."""
    write_oracle: Optional[Path] = None
    """Write the truth's masks here (8-bit, named like the raw RGB frames) and stop."""


def truth_fruit(raw: Path, name: str, maps) -> np.ndarray:
    """The fruit ids of raw RGB frame `name` (undistorted like the frame; 0: no fruit)."""
    ids = cv2.imread(str(raw / "truth" / "fruit_ids" / name), cv2.IMREAD_UNCHANGED)
    if maps is not None:
        ids = cv2.remap(ids, maps[0], maps[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    return ids


def thermal_view_fruit(raw: Path, frame: dict, rgb_ids: np.ndarray, maps, calib, warp) -> np.ndarray:
    """The fruit ids (0: none) that a mask made on the thermal frame warped into the RGB plane should hold: what the
    thermal camera sees along its own ray at each warped pixel. The RGB frame's true surface points (true depth, its
    fruit ids) are projected into the raw thermal camera, the nearest kept per thermal pixel, and that image is
    warped into the RGB plane as the processing warps the thermal frames (``warp``: `align.warp_maps` of the
    capture's calibration ``calib`` at the dataset's plane depth)."""
    from agrinerf_ns.process import align

    thermal = calib.thermal
    assert thermal is not None, f"{raw / 'calib.yaml'}: no thermal camera"
    z = np.load(raw / "truth" / "depth" / f"{Path(frame['raw_rgb']).stem}.npy").astype(np.float32)
    if maps is not None:
        z = cv2.remap(z, maps[0], maps[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=np.inf)
    height, width = z.shape
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    hit = np.isfinite(z) & (z > 0)
    rays = np.stack([u, v, np.ones_like(u)], -1)[hit] @ np.linalg.inv(calib.rgb.K).T
    points = (rays * z[hit][:, None]) @ thermal.T_cam_rgb[:3, :3].T + thermal.T_cam_rgb[:3, 3]
    front = points[:, 2] > 1e-6
    pixels = np.round(align.project_points(thermal, points[front])).astype(np.int64)
    inside = (
        (pixels[:, 0] >= 0) & (pixels[:, 0] < thermal.width) & (pixels[:, 1] >= 0) & (pixels[:, 1] < thermal.height)
    )
    cell = pixels[inside, 1] * thermal.width + pixels[inside, 0]
    depth, ids = points[front][inside, 2], rgb_ids[hit][front][inside]
    order = np.argsort(-depth, kind="stable")  # farthest first: the nearest surface is written last and kept
    seen = np.zeros(thermal.height * thermal.width, np.float32)
    seen[cell[order]] = ids[order]
    warped = align.warp_image(seen.reshape(thermal.height, thermal.width), warp, nearest=True)
    return np.rint(warped).astype(np.int64)


HEADER = (
    "| capture | masks | frames | pixel precision | pixel recall | pixel IoU | fruit touched | regions on a fruit | "
    "fruit F1 | fruit pixels unknown |\n"
    "|---|---|---|---|---|---|---|---|---|---|\n"
)


def quality(args: Args, masks: Callable[[dict], np.ndarray], source: str, thermal_view: bool = False) -> str:
    """One table row: the masks `masks(frame)` of the dataset's frames against the truth."""
    assert args.dataset is not None
    meta = json.loads((args.dataset / "transforms.json").read_text())
    from agrinerf_ns.process import align
    from agrinerf_ns.process.readers import read_calibration

    calib = read_calibration(args.raw / "calib.yaml")
    maps = align.undistort_maps(calib.rgb)
    warp = None  # the thermal frames' warp into the RGB plane, made once when a thermal-view mask needs it
    tp = fp = fn = 0
    touched = total = 0
    components = components_on_fruit = 0
    fruit_pixels = unknown_fruit_pixels = 0
    plane_depth = float(meta.get("agrinerf", {}).get("alignment", {}).get("plane_depth", "inf"))
    for frame in meta["frames"]:
        ids = truth_fruit(args.raw, Path(frame["raw_rgb"]).name, maps)
        if (
            thermal_view or frame.get(FRUIT_MASK_CAMERA, "rgb") == "thermal"
        ):  # the thermal camera's view (thermal_view_fruit)
            if warp is None:
                assert calib.thermal is not None, f"{args.raw / 'calib.yaml'}: no thermal camera"
                warp = align.warp_maps(calib.rgb, calib.thermal, plane_depth)
            ids = thermal_view_fruit(args.raw, frame, ids, maps, calib, warp)
        fruit, known = fruit_and_known(masks(frame))
        truth = ids > 0
        tp += int((fruit & truth & known).sum())
        fp += int((fruit & ~truth & known).sum())
        fn += int((~fruit & truth & known).sum())
        fruit_pixels += int(truth.sum())
        unknown_fruit_pixels += int((truth & ~known).sum())
        parts, found = ndimage.label(fruit & known, structure=np.ones((3, 3), bool))
        components += found
        components_on_fruit += len(np.unique(parts[(parts > 0) & truth]))
        labels, counts = np.unique(ids[ids > 0], return_counts=True)
        for label in labels[counts >= args.min_pixels]:
            total += 1
            touched += int((fruit & (ids == label)).any())
    precision, recall = tp / max(tp + fp, 1), tp / max(tp + fn, 1)
    region_precision, fruit_recall = components_on_fruit / max(components, 1), touched / max(total, 1)
    fruit_f1 = 2 * region_precision * fruit_recall / max(region_precision + fruit_recall, 1e-12)
    iou = tp / max(tp + fp + fn, 1)
    scene = json.loads((args.raw / "truth" / "scene.json").read_text())["config"]
    return (
        f"| {scene['scene']} {scene['lighting']} seed {scene['seed']} | {source} | {len(meta['frames'])} | "
        f"{precision:.3f} | {recall:.3f} | {iou:.3f} | {touched}/{total} ({touched / max(total, 1):.0%}) | "
        f"{components_on_fruit}/{components} ({region_precision:.0%}) | {fruit_f1:.3f} | "
        f"{unknown_fruit_pixels / max(fruit_pixels, 1):.3f} |\n"
    )


def dataset_views(raw: Path, dataset: Path) -> list:
    """Each dataset frame's warped thermal view (``fruit_mask_makers.thermal_views``) from its pose in
    ``transforms.json`` (OpenGL axes, as written) and the capture's calibration."""
    from agrinerf_ns.process.fruit_mask_makers import thermal_views
    from agrinerf_ns.process.readers import read_calibration

    meta = json.loads((dataset / "transforms.json").read_text())
    c2w = np.stack([np.asarray(f["transform_matrix"], np.float64) for f in meta["frames"]]) @ np.diag([1, -1, -1, 1.0])
    plane_depth = float(meta.get("agrinerf", {}).get("alignment", {}).get("plane_depth", "inf"))
    posed = np.ones(len(meta["frames"]), bool)
    return thermal_views(meta["frames"], c2w, posed, read_calibration(raw / "calib.yaml"), plane_depth)


def body_rows(args: Args) -> str:
    """The ``bodies`` rule's rows (``--body-views``)."""
    assert args.dataset is not None
    from dataclasses import replace

    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, thermal_body_masks

    frames = json.loads((args.dataset / "transforms.json").read_text())["frames"]
    views = dataset_views(args.raw, args.dataset)
    out = ""
    for n in args.body_views:
        config = MaskMakerConfig(thermal_rule="bodies")
        config = replace(config, bodies=replace(config.bodies, min_views=n))
        masks, record = thermal_body_masks(args.dataset, frames, list(range(len(frames))), config, views)
        by_path = {frame["file_path"]: masks[i] for i, frame in enumerate(frames)}
        label = (f"thermal bodies, {n} views (polarity {record['polarity']}; sightings {record['sightings_per_side']}; "
                 f"dropped {record['dropped']})")  # fmt: skip
        out += quality(args, lambda frame, found=by_path: found[frame["file_path"]], label, thermal_view=True)
    return out


def rows(args: Args) -> str:
    assert args.dataset is not None
    dataset = args.dataset
    if args.body_views:
        return body_rows(args)
    if args.blob_thresholds or args.thermal_contrast:
        from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, thermal_frame, thermal_mask

        def thermal(config: MaskMakerConfig) -> Callable[[dict], np.ndarray]:
            return lambda frame: thermal_mask(*thermal_frame(dataset, frame, config), config)

        configs = [(MaskMakerConfig(thermal_rule="blobs", blob_threshold=t, min_canopy_offset=o,
                                    polarity=args.polarity),  # type: ignore[arg-type]
                    f"thermal blobs ({args.polarity}), threshold {t:g}, canopy offset {o:g}")
                   for t in args.blob_thresholds for o in args.canopy_offsets]  # fmt: skip
        if args.thermal_contrast:
            configs.append((MaskMakerConfig(thermal_rule="contrast"), "thermal contrast (the earlier rule)"))
        return "".join(quality(args, thermal(c), label, thermal_view=True) for c, label in configs)
    if not (args.colour_scores or args.balance or args.denoise_px or args.min_region_pixels):
        meta = json.loads((dataset / "transforms.json").read_text())
        source = meta.get("agrinerf", {}).get("fruit_masks", {}).get("source", "?")
        return quality(
            args, lambda f: cv2.imread(str(dataset / f["fruit_mask_file_path"]), cv2.IMREAD_GRAYSCALE), source
        )
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, colour_mask

    def maker(config: MaskMakerConfig) -> Callable[[dict], np.ndarray]:
        def masks(frame: dict) -> np.ndarray:
            rgb = np.ascontiguousarray(cv2.imread(str(dataset / frame["file_path"]))[..., ::-1])
            return colour_mask(rgb, config)

        return masks

    default = MaskMakerConfig()
    configs = [MaskMakerConfig(min_colour_score=s, colour_balance=b, colour_denoise_px=d, min_region_pixels=r)
               for s in args.colour_scores or (default.min_colour_score,)
               for b in args.balance or (default.colour_balance,)
               for d in args.denoise_px or (default.colour_denoise_px,)
               for r in args.min_region_pixels or (default.min_region_pixels,)]  # fmt: skip
    label = "colour, min score {:g}, balance {}, smoothing {:g} px, specks under {} px unknown"
    return "".join(
        quality(
            args, maker(c), label.format(c.min_colour_score, c.colour_balance, c.colour_denoise_px, c.min_region_pixels)
        )
        for c in configs
    )


def write_oracle(args: Args) -> None:
    assert args.write_oracle is not None
    args.write_oracle.mkdir(parents=True, exist_ok=True)
    for path in sorted((args.raw / "truth" / "fruit_ids").glob("*.png")):
        ids = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)  # raw frame geometry: the processing undistorts it
        cv2.imwrite(str(args.write_oracle / path.name), np.where(ids > 0, FRUIT, 0).astype(np.uint8))


def main(args: Args) -> None:
    if args.write_oracle is not None:
        write_oracle(args)
        return
    import datetime
    import os
    import sys

    from agrinerf_ns.machine import machine_note

    text = HEADER + rows(args)
    text += (f"\nCommand: `python benchmarks/fruit_mask_quality.py {' '.join(sys.argv[1:])}`; {machine_note()}; "
             f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; {datetime.date.today().isoformat()}.\n")  # fmt: skip
    if args.out is not None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(text)
    print(text)


if __name__ == "__main__":
    main(tyro.cli(Args))
