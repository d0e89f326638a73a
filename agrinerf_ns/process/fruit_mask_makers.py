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
from typing import Dict, List, Literal

import cv2
import numpy as np
from jaxtyping import Bool, UInt8

from agrinerf_ns.fruit_mask_format import BACKGROUND, CAMERA_KEY, FOLDER, FRAME_KEY, FRUIT, UNKNOWN
from agrinerf_ns.images import write_png

MaskMaker = Literal["none", "colour", "thermal", "auto"]


@dataclass(frozen=True)
class MaskMakerConfig:
    """Settings of the built-in mask makers."""

    colour_threshold: float = 3.0
    min_colour_score: float = 0.3
    """``colour``: a fruit pixel's own fruit-colour score (saturation x sqrt(value) in the fruit hues) is at least
    this: bark, stakes and dry ground are of a fruit's hue but duller."""
    thermal_threshold: float = 3.0
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
    thermal: UInt8[np.ndarray, "h w"], seen: Bool[np.ndarray, "h w"], config: MaskMakerConfig
) -> UInt8[np.ndarray, "h w"]:
    """Fruit where the thermal value stands out (see the module); unknown outside the thermal camera's view."""
    from agrinerf_ns.count.blobs import contrast

    if not seen.any():
        return np.full(thermal.shape, UNKNOWN, np.uint8)
    z = contrast(thermal.astype(np.float32) / 255.0, seen, config.background_sigma)
    t = config.thermal_threshold
    fruit = {"warm": z >= t, "cool": z <= -t, "both": np.abs(z) >= t}[config.polarity]
    return np.where(~seen, UNKNOWN, np.where(fruit, FRUIT, BACKGROUND)).astype(np.uint8)


def _read(path: Path, flags: int) -> np.ndarray:
    image = cv2.imread(str(path), flags)
    if image is None:
        raise OSError(f"{path}: cannot read a frame the processing wrote")
    return image


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
            thermal = _read(tmp / frame["thermal_file_path"], cv2.IMREAD_GRAYSCALE)
            seen = (
                _read(tmp / frame["thermal_mask_path"], cv2.IMREAD_GRAYSCALE) > 127
                if "thermal_mask_path" in frame
                else np.ones(thermal.shape, bool)
            )
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
