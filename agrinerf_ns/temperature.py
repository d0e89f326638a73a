"""The dataset's linear temperature images: 16-bit PNG in centikelvin (docs/formats.md, ``thermal_temperature_path``).

``png = round((T_celsius + 273.15) * 100)``, so one unit is 0.01 K (FLIR's "TLinear" high-resolution convention) and
the range is 0.01 K .. 655.35 K (-273.14 .. 382.2 degrees C); ``png = 0`` means no value (outside the thermal camera's
view, or counts the calibration cannot map). Written by ``agrinerf-process`` and read by the dataset, so both sides
share these two functions.
"""

from __future__ import annotations

import numpy as np
from jaxtyping import Bool, Float, UInt16

KELVIN_PER_UNIT = 0.01
"""Temperature step of one PNG unit (kelvin)."""
ZERO_CELSIUS_K = 273.15
ENCODING = "png = round((T_celsius + 273.15) * 100), uint16; png 0 = no value"
"""How the dataset's temperature PNGs encode degrees Celsius (recorded in ``agrinerf.thermal_temperature``)."""


def encode_celsius(celsius: Float[np.ndarray, "*s"]) -> UInt16[np.ndarray, "*s"]:
    """Degrees C -> 16-bit centikelvin; NaN / Inf -> 0 (no value), values beyond the range clip to 1 and 65535."""
    c = np.asarray(celsius, np.float64)
    units = np.round((np.nan_to_num(c, nan=-ZERO_CELSIUS_K) + ZERO_CELSIUS_K) / KELVIN_PER_UNIT)
    out = np.clip(units, 1, 65535).astype(np.uint16)
    out[~np.isfinite(c)] = 0
    return out


def decode_celsius(png: UInt16[np.ndarray, "*s"]) -> tuple[Float[np.ndarray, "*s"], Bool[np.ndarray, "*s"]]:
    """16-bit centikelvin -> (degrees C as float32, valid mask); pixels without a value read 0 C and are invalid."""
    units = np.asarray(png)
    valid = units > 0
    celsius = np.where(valid, units.astype(np.float64) * KELVIN_PER_UNIT - ZERO_CELSIUS_K, 0.0)
    return celsius.astype(np.float32), valid
