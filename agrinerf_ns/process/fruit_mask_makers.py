"""Built-in fruit masks from the captured frames (``agrinerf-process --fruit-mask-maker``), never from renders.

- ``colour``: on the RGB frame, white-balanced (grey world), the fruit-colour score (red to yellow saturation,
  ``fruit/colour_score.py``) standing out from its surroundings (difference of Gaussians in robust spreads,
  ``fruit/contrast.py``) by ``colour_threshold`` and reaching ``min_colour_score`` is fruit, the rest
  background; fruit regions under ``min_region_pixels`` are left unknown.
- ``thermal``: on the thermal frame warped into the RGB camera (its temperature where the capture is radiometric),
  the fruit-sized blobs that differ from the canopy's temperature (warmer, cooler or either: ``polarity``) are fruit,
  filled as discs; the rest of the thermal camera's view is background, pixels outside its view unknown. Thermal
  contrast needs no light. ``--mask-maker.thermal-rule contrast`` restores the earlier per-pixel contrast rule.
- ``auto``: per frame, ``colour`` where the RGB frame is lit (its mean at least ``dark_level`` of full scale),
  ``thermal`` where it is dark and the capture has thermal frames (else ``colour``).
- ``yolo``: a YOLOv8 detector's boxes on the lit RGB frames (``yolo_weights``, e.g. from ``agrinerf-detect train``;
  Ultralytics is the optional AGPL-3.0 extra): each box scored ``box_confidence`` or more is fruit in its inscribed
  ellipse and unknown in its corners, a box scored from ``unsure_confidence`` unknown, the rest background. Dark
  frames get ``thermal`` masks where the capture has thermal frames, as with ``auto``.

Settings were chosen on tuning seeds only: the colour rule's on seed 0 (bright and dusk, garden and orchard,
results/fruit-masks), the thermal rule's on the dark garden of seeds 0 and 2 and the dark orchard of seed 0
(results/fruit-masks-dark); the rule and the settings are recorded in the dataset's ``agrinerf.fruit_masks``.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Dict, List, Literal, Optional, Tuple

import cv2
import numpy as np
from jaxtyping import Bool, Float, Shaped, UInt8
from scipy import ndimage

from agrinerf_ns.dataset_format import (
    FRUIT_BODIES,
    FRUIT_MASK,
    FRUIT_MASK_CAMERA,
    IMAGE,
    TEMPERATURE,
    THERMAL,
    THERMAL_MASK,
    THERMAL_TIMESTAMP,
    TIMESTAMP,
)
from agrinerf_ns.fruit.colour_score import fruit_colour
from agrinerf_ns.fruit.contrast import Polarity, contrast
from agrinerf_ns.fruit.ellipse import inscribed_ellipse
from agrinerf_ns.fruit.mask_bodies import mask_sightings, rgb_geometry
from agrinerf_ns.fruit.thermal_blobs import Blob, blob_discs, thermal_blob_list, thermal_blobs
from agrinerf_ns.fruit.thermal_bodies import BodySettings, FrameGeometry, Sighting, decide_bodies, fruit_sightings
from agrinerf_ns.fruit.yolo import INSTALL_HINT, box_predictor
from agrinerf_ns.fruit_mask_format import BACKGROUND, FRUIT, UNKNOWN
from agrinerf_ns.images import write_png
from agrinerf_ns.modalities import DARK_RGB_LEVEL
from agrinerf_ns.process.readers import RigCalib
from agrinerf_ns.temperature import decode_celsius

MaskMaker = Literal["none", "colour", "thermal", "auto", "yolo"]
ColourBalance = Literal["none", "grey-world"]


@dataclass(frozen=True)
class MaskMakerConfig:
    """Settings of the built-in mask makers."""

    colour_threshold: float = 3.0
    min_colour_score: float = 0.3
    """``colour``: a fruit pixel's own fruit-colour score (saturation x sqrt(value) in the fruit hues) is at least
    this: bark, stakes and dry ground are of a fruit's hue but duller."""
    colour_balance: ColourBalance = "grey-world"
    """``colour``: white-balance the RGB frame before its colour is scored. ``grey-world`` scales each channel so
    that its frame mean is the mean of the three: a warm low sun tints dry wood and ground into the fruit hues, the
    balance takes the illuminant's tint out (and a foliage frame's green cast with it, the same in every light)."""
    colour_denoise_px: float = 0.0
    """``colour``: Gaussian sigma (pixels) the RGB frame is smoothed with before its colour is scored: a dim frame's
    chroma noise puts single pixels of foliage in the fruit hues (0: none)."""
    min_region_pixels: int = 8
    """``colour``: fruit regions smaller than this many pixels are left unknown, neither fruit nor background (a
    speck of noise is not taught as fruit, a sliver of a hidden fruit not as background; 0: all kept)."""
    thermal_rule: Literal["bodies", "blobs", "contrast"] = "bodies"
    """``bodies``: the fruit-sized blobs of every thermal frame, decided in 3D across the capture with its poses
    (`fruit/thermal_bodies.py`: a body seen at one place in several frames, compact, near the leaves' temperature, on the side of the leaves' temperature where the capture's bodies are; no polarity to set);
    ``blobs``: fruit-sized blobs of the thermal frame (its temperature where the dataset has one), found by the
    scale-normalised Laplacian of Gaussian over the sizes of `thermal_sizes` and filled as discs; ``contrast``: the
    pixels standing out from their surroundings at `background_sigma` by `thermal_threshold`, the rule before
    (rings at a fruit's rim and bands along every large warm or cool edge once fruit are wider than the
    surroundings' scale: results/fruit-masks-dark)."""
    thermal_threshold: float = 3.0
    """``contrast``: robust spreads a fruit pixel stands out by."""
    blob_threshold: float = 2.0
    """``blobs``: the least scale-normalised Laplacian response of a blob, in robust spreads of the frame's values."""
    thermal_sizes: Tuple[float, float] = (0.02, 0.3)
    """``blobs``: the least and largest fruit diameter, as fractions of the frame's shorter side."""
    min_canopy_offset: float = 1.5
    """``blobs``: a blob's median differs from the canopy's value (the mode of the frame's values: leaves fill a
    tree row's frames) by at least this many robust spreads, on its own side: a cluster of leaves against the sky is
    a blob too, but at the leaves' temperature."""
    polarity: Polarity = "both"
    """``blobs``, ``contrast``: thermal fruit warmer than their surroundings, cooler, or either (the synthetic scenes
    draw warm or cool fruit per seed; set to the scene's, it halves the false fruit where the other side holds sky
    gaps or warm ground: results/fruit-masks-dark). ``bodies`` reads the side from the capture instead."""
    bodies: BodySettings = field(default_factory=BodySettings)
    """``bodies``: how blobs are placed and judged in 3D."""
    rgb_bodies: BodySettings = field(default_factory=lambda: BodySettings(min_views=3))
    """How the fruit of the lit frames' masks are placed in 3D (``fruit/mask_bodies.py``; only ``neighbours``,
    ``min_views``, ``depth_range``, ``depths``, ``match_px`` and ``size_ratio`` apply): a fruit shows at one place in
    three frames (two placed more false fruit on the bright tuning captures, seeds 0 and 2: the row's countable
    fruit F1 0.44 against 0.54, the count error +81% against +8%; results/fruit-count-lit)."""
    background_sigma: float = 0.05
    """Scale of a pixel's surroundings, as a fraction of the image's shorter side."""
    dark_level: float = DARK_RGB_LEVEL
    """``auto``, ``yolo``: an RGB frame whose mean is below this fraction of full scale is dark (the model's
    low_light_level)."""
    dim_level: float = 0.25
    """A lit frame with a thermal frame whose mean is below this fraction of full scale is dim (dusk): its mask stays
    the colour rule's, but its fruit are placed in 3D from the thermal camera (the ``bodies`` rule) rather than from
    that mask, whose fruit a dim frame's noise and blur break up (the four dusk tuning captures, seeds 0 and 2, the
    row's countable fruit: F1 0.43 from the thermal bodies against 0.38 from the masks, count error -24% against
    +69%; by day 0.43 against 0.53; results/fruit-count-lit). The synthetic frames average 0.31-0.35 by day and in
    shade, 0.14-0.16 at dusk; 0: never."""
    yolo_weights: Optional[Path] = None
    """``yolo``: the detector's weights (a ``.pt`` file; ``agrinerf-detect train`` writes one)."""
    box_confidence: float = 0.25
    """``yolo``: a box scored this or more is a fruit (Ultralytics' default prediction threshold)."""
    unsure_confidence: float = 0.05
    """``yolo``: a box scored from this up to ``box_confidence`` is left unknown: not taught as fruit, nor its
    pixels as background."""


def colour_mask(rgb: UInt8[np.ndarray, "h w 3"], config: MaskMakerConfig) -> UInt8[np.ndarray, "h w"]:
    """Fruit where the fruit colour stands out (see the module)."""
    valid = np.ones(rgb.shape[:2], bool)
    image = rgb.astype(np.float32) / 255.0
    if config.colour_balance == "grey-world":
        means = image.reshape(-1, 3).mean(0)
        image = image * (means.mean() / np.maximum(means, 1e-6))
    if config.colour_denoise_px > 0:
        image = cv2.GaussianBlur(image, (0, 0), config.colour_denoise_px)
    score = fruit_colour(image, valid)
    z = contrast(score, valid, config.background_sigma)
    fruit = (z >= config.colour_threshold) & (score >= config.min_colour_score)
    mask = np.where(fruit, FRUIT, BACKGROUND).astype(np.uint8)
    if config.min_region_pixels > 0:
        labels, _ = ndimage.label(fruit, structure=np.ones((3, 3), bool))
        sizes = np.bincount(labels.ravel())
        mask[(labels > 0) & (sizes[labels] < config.min_region_pixels)] = UNKNOWN
    return mask


def thermal_mask(
    thermal: Shaped[np.ndarray, "h w"], seen: Bool[np.ndarray, "h w"], config: MaskMakerConfig
) -> UInt8[np.ndarray, "h w"]:
    """Fruit in the thermal frame (degrees C, or the 8-bit frame) by ``config.thermal_rule`` (see the module);
    unknown outside the thermal camera's view."""
    if not seen.any():
        return np.full(thermal.shape, UNKNOWN, np.uint8)
    thermal = as_float(thermal)
    if config.thermal_rule != "contrast":  # one frame: the bodies rule has only its blobs
        fruit = thermal_blobs(thermal, seen, sizes=config.thermal_sizes, polarity=config.polarity,
                              threshold=config.blob_threshold, min_canopy_offset=config.min_canopy_offset)  # fmt: skip
    else:
        z = contrast(thermal, seen, config.background_sigma)
        t = config.thermal_threshold
        fruit = {"warm": z >= t, "cool": z <= -t, "both": np.abs(z) >= t}[config.polarity]
    return np.where(~seen, UNKNOWN, np.where(fruit, FRUIT, BACKGROUND)).astype(np.uint8)


def as_float(thermal: Shaped[np.ndarray, "h w"]) -> Float[np.ndarray, "h w"]:
    """A thermal frame as float32: an 8-bit frame in [0, 1], a temperature (degrees C) as it is."""
    return thermal.astype(np.float32) / 255.0 if thermal.dtype == np.uint8 else thermal.astype(np.float32)


def box_mask(
    height: int, width: int, boxes: Float[np.ndarray, "n 4"], scores: Float[np.ndarray, " n"], config: MaskMakerConfig
) -> UInt8[np.ndarray, "h w"]:
    """A frame's mask from a detector's pixel boxes ``x1 y1 x2 y2`` (see the module): fruit in the inscribed ellipse
    of a confident box, unknown in its corners and in an unsure box, background elsewhere."""
    mask = np.full((height, width), BACKGROUND, np.uint8)
    fruit = np.zeros((height, width), bool)
    for box, score in zip(np.asarray(boxes).reshape(-1, 4), np.asarray(scores).reshape(-1), strict=True):
        if score < config.unsure_confidence:
            continue
        cols = slice(max(int(np.floor(box[0])), 0), max(int(np.ceil(box[2])), 0))
        rows = slice(max(int(np.floor(box[1])), 0), max(int(np.ceil(box[3])), 0))
        mask[rows, cols] = UNKNOWN
        if score >= config.box_confidence:
            fruit |= inscribed_ellipse(height, width, box)
    mask[fruit] = FRUIT  # a confident fruit wins over an overlapping box's corner
    return mask


def check_mask_maker(maker: MaskMaker, config: MaskMakerConfig) -> None:
    """Refuse a maker that cannot run, before any output is written: ``yolo`` without its weights file (named) or
    without Ultralytics."""
    if maker != "yolo":
        return
    if config.yolo_weights is None:
        raise ValueError(
            "--fruit-mask-maker yolo needs --mask-maker.yolo-weights PATH (agrinerf-detect train writes one)"
        )
    if not Path(config.yolo_weights).is_file():
        raise ValueError(f"{config.yolo_weights}: --mask-maker.yolo-weights: no such weights file")
    try:
        import ultralytics  # noqa: F401
    except ImportError as err:
        raise ValueError(f"--fruit-mask-maker yolo: {INSTALL_HINT}") from err


def _read(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise OSError(f"{path}: cannot read a frame the processing wrote")
    return image


def thermal_frame(
    folder: Path, frame: Dict, config: MaskMakerConfig
) -> Tuple[Shaped[np.ndarray, "h w"], Bool[np.ndarray, "h w"]]:
    """A frame's thermal image in the RGB plane and where the thermal camera saw. For the ``blobs`` rule its
    temperature (degrees C) where the dataset has one, a physical contrast that the 8-bit frame's local rescaling
    (Fieldscale) bends; else the 8-bit frame."""
    if config.thermal_rule != "contrast" and TEMPERATURE.key in frame:
        celsius, seen = decode_celsius(_read(folder / frame[TEMPERATURE.key], cv2.IMREAD_UNCHANGED))
        return celsius, seen
    thermal = _read(folder / frame[THERMAL.key], cv2.IMREAD_GRAYSCALE)
    seen = (
        _read(folder / frame[THERMAL_MASK.key], cv2.IMREAD_GRAYSCALE) > 127
        if THERMAL_MASK.key in frame
        else np.ones(thermal.shape, bool)
    )
    return thermal, seen


def make_fruit_masks(
    tmp: Path,
    frames: List[Dict],
    names: List[str],
    maker: MaskMaker,
    config: MaskMakerConfig,
    geometry: Optional[List[Optional[FrameGeometry]]] = None,
    rgb_views: Optional[List[Optional[FrameGeometry]]] = None,
) -> dict:
    """Write a mask per frame (from the frames already written under `tmp`) and name it in the frame; returns the
    dataset's record (the rule, the settings and how many frames each maker labelled). ``geometry``: each frame's
    thermal view (None where the frame has no pose), which the ``bodies`` rule needs; ``rgb_views``: each frame's RGB
    view, with which the fruit of the RGB frames' masks are placed in 3D too (``fruit/mask_bodies.py``). The placed
    fruit of both cameras are written to ``FRUIT_BODIES`` (``agrinerf-count --path bodies``)."""
    (tmp / FRUIT_MASK.folder).mkdir(parents=True, exist_ok=True)
    used = {"colour": 0, "thermal": 0, "yolo": 0}
    predict = None
    if maker == "yolo":
        predict = box_predictor(
            config.yolo_weights, min(config.unsure_confidence, config.box_confidence), hint="--mask-maker.yolo-weights"
        )
    masks: Dict[int, np.ndarray] = {}
    thermal_index: List[int] = []
    dim_index: List[int] = []  # lit frames whose fruit are placed from the thermal camera (``dim_level``)
    for i, frame in enumerate(frames):  # the RGB frames' makers now (one read each); the thermal frames' below
        kind, bgr = _mask_kind(tmp, frame, maker, config)
        used[kind] += 1
        if kind == "thermal" or bgr is None:
            thermal_index.append(i)
            continue
        if kind == "yolo" and predict is not None:
            boxes, scores = predict(bgr)
            masks[i] = box_mask(bgr.shape[0], bgr.shape[1], boxes, scores, config)
        else:
            masks[i] = colour_mask(np.ascontiguousarray(bgr[..., ::-1]), config)
        if geometry is not None and THERMAL.key in frame and float(bgr.mean()) / 255.0 < config.dim_level:
            dim_index.append(i)
    record: dict = {}
    sightings: List[Tuple[str, Sighting]] = []
    body_index = sorted(thermal_index + dim_index) if config.thermal_rule == "bodies" else []
    if body_index:  # decided across the frames at once; the dim frames keep their colour masks
        bodies, record["bodies"], found = thermal_body_masks(tmp, frames, body_index, config, geometry)
        masks.update({i: bodies[i] for i in thermal_index})
        sightings += [("thermal", s) for s in found]
        record["bodies"]["dim_frames"] = len(dim_index)
    placed = set(body_index)
    lit = [i for i in sorted(masks) if i not in placed and rgb_views is not None and rgb_views[i] is not None]
    if lit and rgb_views is not None:
        found = rgb_mask_sightings(tmp, frames, lit, masks, config, rgb_views, geometry)
        sightings += [("rgb", s) for s in found]
        record["rgb_bodies"] = {"frames": len(lit), "sightings": len(found)}
    if "bodies" in record or "rgb_bodies" in record:
        write_sightings(tmp / FRUIT_BODIES, sightings, frames)
        record.setdefault("bodies", {})["file"] = FRUIT_BODIES
    for i in thermal_index:
        if i not in masks:
            masks[i] = thermal_mask(*thermal_frame(tmp, frames[i], config), config)
    thermal_set = set(thermal_index)
    for i, (frame, name) in enumerate(zip(frames, names, strict=True)):
        frame[FRUIT_MASK.key] = FRUIT_MASK.path(name)
        if i in thermal_set:  # the thermal camera's view: supervised along its rays
            frame[FRUIT_MASK_CAMERA] = "thermal"
        write_png(tmp / frame[FRUIT_MASK.key], masks[i])
    settings = {k: str(v) if isinstance(v, Path) else v for k, v in asdict(config).items()}
    return {"source": f"maker:{maker}", "frames": used, "settings": settings,
            "values": f"0 background, {UNKNOWN} unknown, {FRUIT} fruit", **record}  # fmt: skip


def write_sightings(path: Path, sightings: List[Tuple[str, Sighting]], frames: List[Dict]) -> None:
    """The fruit bodies' sightings (``FRUIT_BODIES``), each by its camera (``thermal`` or ``rgb``) and its frame's
    RGB file, its centre in the poses' world frame (that of ``transforms.json``), its diameter, temperature and the
    ray of the camera that saw it."""
    rows = [
        {"frame": frames[s.frame][IMAGE.key], "camera": camera, "centre": [round(float(v), 6) for v in s.centre],
         "diameter": round(s.diameter, 6), "temperature": None if s.temperature is None else round(s.temperature, 3),
         "origin": [round(float(v), 6) for v in s.origin], "ray": [round(float(v), 7) for v in s.ray]}
        for camera, s in sightings
    ]  # fmt: skip
    path.write_text(json.dumps({"sightings": rows}, indent=1) + "\n")


def _mask_kind(
    tmp: Path, frame: Dict, maker: MaskMaker, config: MaskMakerConfig
) -> Tuple[str, Optional[UInt8[np.ndarray, "h w 3"]]]:
    """Which maker labels a frame (``thermal`` for a dark frame with a thermal frame under ``auto`` and ``yolo``),
    with its RGB frame (BGR) where that maker reads it or the choice needed it (None under ``thermal``)."""
    has_thermal = THERMAL.key in frame
    if maker == "thermal":
        if not has_thermal:
            raise ValueError(f"--fruit-mask-maker thermal: frame {frame[IMAGE.key]} has no thermal frame")
        return "thermal", None
    bgr = _read(tmp / frame[IMAGE.key], cv2.IMREAD_COLOR)
    if maker == "colour":
        return "colour", bgr
    dark = float(bgr.mean()) / 255.0 < config.dark_level
    return ("thermal" if dark and has_thermal else ("yolo" if maker == "yolo" else "colour")), bgr


def rgb_mask_sightings(
    tmp: Path,
    frames: List[Dict],
    lit: List[int],
    masks: Dict[int, np.ndarray],
    config: MaskMakerConfig,
    rgb_views: List[Optional[FrameGeometry]],
    thermal: Optional[List[Optional[FrameGeometry]]],
) -> List[Sighting]:
    """The fruit of the lit frames ``lit``' masks placed in 3D (``fruit/mask_bodies.py``; frames by their index in
    ``frames``), each with its temperature where the capture is radiometric."""
    celsius: Optional[List[Optional[np.ndarray]]] = None
    if thermal is not None and all(TEMPERATURE.key in frames[i] for i in lit):
        celsius = []
        for i in lit:
            image, seen = decode_celsius(_read(tmp / frames[i][TEMPERATURE.key], cv2.IMREAD_UNCHANGED))
            celsius.append(np.where(seen, image.astype(np.float32), np.nan))
    found = mask_sightings([masks[i] == FRUIT for i in lit], [rgb_views[i] for i in lit], config.rgb_bodies,  # type: ignore[misc]
                           None if thermal is None else [thermal[i] for i in lit], celsius)  # fmt: skip
    return [replace(s, frame=lit[s.frame]) for s in found]


def rgb_views_of(
    c2w: Float[np.ndarray, "n 4 4"], posed: Bool[np.ndarray, " n"], calib: RigCalib
) -> List[Optional[FrameGeometry]]:
    """Each posed frame's RGB view (OpenCV axes), None for a frame without a pose."""
    return [rgb_geometry(calib.rgb.K, c2w[i]) if posed[i] else None for i in range(len(c2w))]


def thermal_views(
    frames: List[Dict],
    c2w: Float[np.ndarray, "n 4 4"],
    posed: Bool[np.ndarray, " n"],
    calib: RigCalib,
    plane_depth: float,
) -> List[Optional[FrameGeometry]]:
    """Each frame's warped thermal view: the RGB camera's pose (OpenCV axes) at the thermal frame's own time
    (``thermal_timestamp``; the RGB poses interpolated), the thermal camera's centre beside it; None for a frame
    without a pose or a capture without a thermal camera."""
    from agrinerf_ns.trajectory import CameraTrajectory

    index = np.flatnonzero(posed)
    if calib.thermal is None or len(index) == 0:
        return [None] * len(frames)
    times = np.array([float(frames[i][TIMESTAMP]) for i in index])
    order = np.flatnonzero(np.diff(times, prepend=-np.inf) > 0)  # strictly increasing samples
    trajectory = CameraTrajectory(times[order], c2w[index[order]])
    rotation, shift = calib.thermal.T_cam_rgb[:3, :3], calib.thermal.T_cam_rgb[:3, 3]
    centre = -rotation.T @ shift  # the thermal camera's centre in the RGB camera's frame
    views: List[Optional[FrameGeometry]] = [None] * len(frames)
    for i in index:
        pose = np.eye(4)
        pose[:3] = trajectory.poses_at(np.array(float(frames[i].get(THERMAL_TIMESTAMP, frames[i][TIMESTAMP]))))
        views[i] = FrameGeometry(calib.rgb.K, pose, centre, plane_depth)
    return views


def thermal_body_masks(
    tmp: Path,
    frames: List[Dict],
    index: List[int],
    config: MaskMakerConfig,
    geometry: Optional[List[Optional[FrameGeometry]]],
) -> Tuple[Dict[int, np.ndarray], dict, List[Sighting]]:
    """The ``bodies`` rule's masks of the frames ``index`` (``fruit/thermal_bodies.py``): fruit on the blobs decided
    fruit, unknown on the blobs of the fruit's side that no other frame confirms (a fruit seen once is not taught as
    background), background on the rest of the thermal camera's view; with the decision's record and the fruit
    sightings (frames by their index in ``frames``)."""
    if geometry is None:
        raise ValueError("--mask-maker.thermal-rule bodies needs the frames' poses")
    posed = [i for i in index if geometry[i] is not None]
    images = {i: thermal_frame(tmp, frames[i], config) for i in index}
    radiometric = all(TEMPERATURE.key in frames[i] for i in posed)
    found, record, sightings = body_masks([images[i] for i in posed], [geometry[i] for i in posed], config, radiometric)  # type: ignore[misc]
    masks = dict(zip(posed, found, strict=True))
    for i in index:
        if i not in masks:  # no pose: the frame is dropped; its mask says nothing
            masks[i] = np.full(images[i][0].shape, UNKNOWN, np.uint8)
    return masks, record, [replace(s, frame=posed[s.frame]) for s in sightings]


def frame_blobs(thermal: Shaped[np.ndarray, "h w"], seen: Bool[np.ndarray, "h w"], config: MaskMakerConfig,
                frame: int) -> List[Blob]:  # fmt: skip
    """The blobs of thermal frame number ``frame`` at the maker's settings (both sides of the canopy)."""
    return thermal_blob_list(as_float(thermal), seen, sizes=config.thermal_sizes, threshold=config.blob_threshold,
                             min_canopy_offset=config.min_canopy_offset, frame=frame)  # fmt: skip


def body_masks(
    images: List[Tuple[Shaped[np.ndarray, "h w"], Bool[np.ndarray, "h w"]]],
    views: List[FrameGeometry],
    config: MaskMakerConfig,
    radiometric: bool,
) -> Tuple[List[np.ndarray], dict, List[Sighting]]:
    """The ``bodies`` rule on consecutive thermal frames (each its image, degrees C where ``radiometric`` else 8-bit,
    and where the thermal camera saw) and their views: a mask per frame, the decision's record and the fruit
    sightings placed in 3D (frames by their index in ``images``)."""
    blobs = [b for k, (thermal, seen) in enumerate(images) for b in frame_blobs(thermal, seen, config, k)]
    decision = decide_bodies(blobs, views, config.bodies, radiometric)
    sides = (1.0, -1.0) if decision.polarity is None else ((1.0,) if decision.polarity == "warm" else (-1.0,))
    by_frame: Dict[int, List[int]] = {}
    for j, b in enumerate(blobs):
        by_frame.setdefault(b.frame, []).append(j)
    masks = []
    for k, (thermal, seen) in enumerate(images):
        own = by_frame.get(k, [])
        fruit = blob_discs(thermal.shape, seen, [blobs[j] for j in own if decision.fruit[j]])
        # a blob of the fruit's side that no other frame confirms may be a fruit seen once: neither fruit nor background
        once = [blobs[j] for j in own if not decision.placed[j] and blobs[j].sign in sides]
        unsure = blob_discs(thermal.shape, seen, once) & ~fruit
        mask = np.where(~seen, UNKNOWN, np.where(fruit, FRUIT, np.where(unsure, UNKNOWN, BACKGROUND)))
        masks.append(mask.astype(np.uint8))
    record = {
        "polarity": decision.polarity or "both (undecided)",
        "sightings_per_side": decision.sightings,
        "blobs": len(blobs),
        "fruit_blobs": int(decision.fruit.sum()),
        "dropped": decision.dropped,
    }
    celsius = [np.where(seen, as_float(thermal), np.nan) for thermal, seen in images] if radiometric else None
    return masks, record, fruit_sightings(blobs, decision, views, celsius)
