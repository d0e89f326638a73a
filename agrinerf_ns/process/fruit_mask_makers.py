"""Built-in fruit masks from the captured frames (``agrinerf-process --fruit-mask-maker``), never from renders.

- ``colour``: on the RGB frame, the fruit-colour score (red to yellow saturation, ``count/blobs.py:fruit_colour``)
  standing out from its surroundings (difference of Gaussians in robust spreads, ``count/blobs.py:contrast``) by
  ``colour_threshold`` is fruit, the rest background.
- ``thermal``: on the thermal frame warped into the RGB camera, the value standing out from its surroundings by
  ``thermal_threshold`` (warmer, cooler or either: ``polarity``) is fruit, the rest of the thermal camera's view
  background, pixels outside its view unknown. Thermal contrast needs no light.
- ``auto``: per frame, ``colour`` where the RGB frame is lit (its mean at least ``dark_level`` of full scale),
  ``thermal`` where it is dark and the capture has thermal frames (else ``colour``).

Settings were chosen on tuning seed 0 only (bright garden and orchard, results/fruit-masks); the rule and the
settings are recorded in the dataset's ``agrinerf.fruit_masks``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Dict, List, Literal, Tuple

import cv2
import numpy as np
from jaxtyping import Bool, Float, Shaped, UInt8

from agrinerf_ns.fruit_mask_format import BACKGROUND, CAMERA_KEY, FOLDER, FRAME_KEY, FRUIT, UNKNOWN
from agrinerf_ns.images import write_png
from agrinerf_ns.temperature import FRAME_KEY as TEMPERATURE_KEY
from agrinerf_ns.temperature import decode_celsius

MaskMaker = Literal["none", "colour", "thermal", "auto"]


@dataclass(frozen=True)
class MaskMakerConfig:
    """Settings of the built-in mask makers."""

    colour_threshold: float = 3.0
    min_colour_score: float = 0.3
    """``colour``: a fruit pixel's own fruit-colour score (saturation x sqrt(value) in the fruit hues) is at least
    this: bark, stakes and dry ground are of a fruit's hue but duller."""
    thermal_rule: Literal["blobs", "contrast"] = "contrast"
    """``blobs``: fruit-sized blobs of the thermal frame (its temperature where the dataset has one), found by the
    scale-normalised Laplacian of Gaussian over the sizes of `thermal_sizes` and filled as discs; ``contrast``: the
    pixels standing out from their surroundings at `background_sigma` by `thermal_threshold`, the rule before
    (rings at a fruit's rim and bands along every large warm or cool edge once fruit are wider than the
    surroundings' scale: results/fruit-masks-dark)."""
    thermal_threshold: float = 3.0
    """``contrast``: robust spreads a fruit pixel stands out by."""
    blob_threshold: float = 0.5
    """``blobs``: the least scale-normalised Laplacian response of a blob, in robust spreads of the frame's values."""
    thermal_sizes: Tuple[float, float] = (0.02, 0.3)
    """``blobs``: the least and largest fruit diameter, as fractions of the frame's shorter side."""
    polarity: Literal["warm", "cool", "both"] = "both"
    """Thermal fruit warmer than their surroundings, cooler, or either."""
    background_sigma: float = 0.05
    """Scale of a pixel's surroundings, as a fraction of the image's shorter side."""
    dark_level: float = 0.04
    """``auto``: an RGB frame whose mean is below this fraction of full scale is dark (the model's low_light_level)."""


def colour_mask(rgb: UInt8[np.ndarray, "h w 3"], config: MaskMakerConfig) -> UInt8[np.ndarray, "h w"]:
    """Fruit where the fruit colour stands out (see the module)."""
    from agrinerf_ns.count.blobs import contrast, fruit_colour

    valid = np.ones(rgb.shape[:2], bool)
    score = fruit_colour(rgb.astype(np.float32) / 255.0, valid)
    z = contrast(score, valid, config.background_sigma)
    fruit = (z >= config.colour_threshold) & (score >= config.min_colour_score)
    return np.where(fruit, FRUIT, BACKGROUND).astype(np.uint8)


def thermal_mask(
    thermal: Shaped[np.ndarray, "h w"], seen: Bool[np.ndarray, "h w"], config: MaskMakerConfig
) -> UInt8[np.ndarray, "h w"]:
    """Fruit in the thermal frame (degrees C, or the 8-bit frame) by ``config.thermal_rule`` (see the module);
    unknown outside the thermal camera's view."""
    if not seen.any():
        return np.full(thermal.shape, UNKNOWN, np.uint8)
    thermal = thermal.astype(np.float32) / 255.0 if thermal.dtype == np.uint8 else thermal.astype(np.float32)
    if config.thermal_rule == "blobs":
        fruit = thermal_blobs(thermal, seen, config)
    else:
        from agrinerf_ns.count.blobs import contrast

        z = contrast(thermal, seen, config.background_sigma)
        t = config.thermal_threshold
        fruit = {"warm": z >= t, "cool": z <= -t, "both": np.abs(z) >= t}[config.polarity]
    return np.where(~seen, UNKNOWN, np.where(fruit, FRUIT, BACKGROUND)).astype(np.uint8)


def thermal_blobs(
    thermal: Float[np.ndarray, "h w"], seen: Bool[np.ndarray, "h w"], config: MaskMakerConfig
) -> Bool[np.ndarray, "h w"]:
    """Discs of the fruit-sized blobs of a thermal frame: scikit-image's scale-normalised Laplacian of Gaussian
    (`blob_log`) on the frame in robust spreads (median and 1.4826 MAD over the seen pixels, the unseen ones set to
    the median so the view's border is no blob), warm blobs on it and cool ones on its negative, each a disc of
    radius sqrt(2) sigma: a blob responds to the Laplacian at its own scale and an edge does not, so the rims of large
    warm or cool regions, which a local contrast marks, are not fruit."""
    from skimage.feature import blob_log

    values = thermal[seen].astype(np.float64)
    median = float(np.median(values))
    spread = max(1.4826 * float(np.median(np.abs(values - median))), 1e-6)
    z = np.where(seen, (thermal - median) / spread, 0.0)
    short = min(thermal.shape)
    # a disc of diameter d is found at sigma d / (2 sqrt 2)
    low, high = (max(0.5, f * short / (2.0 * np.sqrt(2.0))) for f in config.thermal_sizes)
    signs = {"warm": (1.0,), "cool": (-1.0,), "both": (1.0, -1.0)}[config.polarity]
    fruit = np.zeros(thermal.shape, bool)
    rows, cols = np.mgrid[0 : thermal.shape[0], 0 : thermal.shape[1]]
    for sign in signs:
        for row, col, sigma in blob_log(np.clip(sign * z, 0.0, None), min_sigma=low, max_sigma=high, num_sigma=12,
                                        threshold=config.blob_threshold, log_scale=True):  # fmt: skip
            fruit |= (rows - row) ** 2 + (cols - col) ** 2 <= 2.0 * sigma**2
    return fruit & seen


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
    if config.thermal_rule == "blobs" and TEMPERATURE_KEY in frame:
        celsius, seen = decode_celsius(_read(folder / frame[TEMPERATURE_KEY], cv2.IMREAD_UNCHANGED))
        return celsius, seen
    thermal = _read(folder / frame["thermal_file_path"], cv2.IMREAD_GRAYSCALE)
    seen = (
        _read(folder / frame["thermal_mask_path"], cv2.IMREAD_GRAYSCALE) > 127
        if "thermal_mask_path" in frame
        else np.ones(thermal.shape, bool)
    )
    return thermal, seen


def make_fruit_masks(
    tmp: Path, frames: List[Dict], names: List[str], maker: MaskMaker, config: MaskMakerConfig
) -> dict:
    """Write a mask per frame (from the frames already written under `tmp`) and name it in the frame; returns the
    dataset's record (the rule, the settings and how many frames each maker labelled)."""
    (tmp / FOLDER).mkdir(parents=True, exist_ok=True)
    used = {"colour": 0, "thermal": 0}
    for frame, name in zip(frames, names, strict=True):
        rgb = _read(tmp / frame["file_path"], cv2.IMREAD_COLOR)[..., ::-1]
        has_thermal = "thermal_file_path" in frame
        dark = float(rgb.mean()) / 255.0 < config.dark_level
        kind = maker if maker != "auto" else ("thermal" if dark and has_thermal else "colour")
        if kind == "thermal":
            if not has_thermal:
                raise ValueError(f"--fruit-mask-maker thermal: frame {frame['file_path']} has no thermal frame")
            thermal, seen = thermal_frame(tmp, frame, config)
            mask = thermal_mask(thermal, seen, config)
        else:
            mask = colour_mask(np.ascontiguousarray(rgb), config)
        used[kind] += 1
        frame[FRAME_KEY] = f"{FOLDER}/{name}.png"
        if kind == "thermal":  # the thermal camera's view: supervised along its rays
            frame[CAMERA_KEY] = "thermal"
        write_png(tmp / frame[FRAME_KEY], mask)
    return {"source": f"maker:{maker}", "frames": used, "settings": asdict(config),
            "values": f"0 background, {UNKNOWN} unknown, {FRUIT} fruit"}  # fmt: skip
