"""Sensor models: an 8-bit RGB camera, a radiometric-like 16-bit thermal camera and an event camera simulator."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Dict, Tuple

import numpy as np
from jaxtyping import Float, Int64, UInt8, UInt16
from scipy.ndimage import gaussian_filter

from agrinerf_ns.images import to_uint8

FULL_WELL_E = 8000.0
"""Electrons at linear level 1.0 (saturation) of the RGB sensor."""
READ_NOISE_E = 4.0
"""RGB read noise, electrons RMS."""
MAX_GAIN = 4.0
"""The RGB auto-exposure can brighten at most this much beyond what the bright preset needs (then it saturates)."""
TARGET_MEAN = 0.18
"""Mean linear level the auto-exposure aims for."""

THERMAL_OFFSET = 3500.0
"""Thermal counts at 0 degrees Celsius."""
THERMAL_GAIN = 100.0
"""Thermal counts per kelvin."""
RADIOMETRIC_CALIBRATION: Dict[str, Any] = {
    "model": "linear",
    "counts_at_0c": THERMAL_OFFSET,
    "counts_per_kelvin": THERMAL_GAIN,
}
"""The thermal camera's counts-to-temperature map as its calibration gives it (calib.yaml, cam1 ``radiometric``):
``counts = counts_at_0c + counts_per_kelvin * T_celsius``. The fixed pattern and noise are what it does not know."""


def gamma_encode(lin: np.ndarray) -> np.ndarray:
    """sRGB transfer curve."""
    lin = np.clip(lin, 0.0, 1.0)
    return np.where(lin <= 0.0031308, 12.92 * lin, 1.055 * np.power(lin, 1 / 2.4) - 0.055)


def clean_rgb(radiance: Float[np.ndarray, "h w 3"], gain: float) -> UInt8[np.ndarray, "h w 3"]:
    """Noise-free, well-exposed 8-bit image (the truth): auto-exposed, sRGB-encoded."""
    return to_uint8(gamma_encode(radiance * gain))


def noisy_rgb(
    radiance: Float[np.ndarray, "h w 3"], gain: float, rng: np.random.Generator
) -> UInt8[np.ndarray, "h w 3"]:
    """The camera's frame: exposure ``gain``, shot noise, read noise, black-level clip, sRGB, 8-bit."""
    electrons = np.clip(radiance * gain, 0.0, 1.5) * FULL_WELL_E
    noisy = electrons + np.sqrt(electrons) * rng.standard_normal(electrons.shape)
    noisy += READ_NOISE_E * rng.standard_normal(electrons.shape)
    return to_uint8(gamma_encode(noisy / FULL_WELL_E))


def exposure_gains(mean_lum_preset: float, mean_lum_bright: float) -> Tuple[float, float]:
    """(camera gain, truth gain): the truth is always auto-exposed; the camera is capped at MAX_GAIN x bright."""
    truth = TARGET_MEAN / max(mean_lum_preset, 1e-12)
    cap = MAX_GAIN * TARGET_MEAN / max(mean_lum_bright, 1e-12)
    return min(truth, cap), truth


@dataclass
class ThermalSensor:
    """Fixed-pattern offsets of one thermal camera; renders counts from supersampled temperatures."""

    fpn: Float[np.ndarray, "h w"]

    @staticmethod
    def create(width: int, height: int, rng: np.random.Generator) -> "ThermalSensor":
        yy, xx = np.mgrid[0:height, 0:width]
        r2 = ((xx - width / 2) / (width / 2)) ** 2 + ((yy - height / 2) / (height / 2)) ** 2
        fpn = rng.normal(0, 20.0, (height, width)) + rng.normal(0, 12.0, (1, width)) - 40.0 * r2
        return ThermalSensor(fpn)

    def counts(
        self, temp_c: Float[np.ndarray, "hs ws"], supersample: int, rng: np.random.Generator
    ) -> UInt16[np.ndarray, "h w"]:
        """Optics blur, pixel integration, fixed pattern and temporal noise -> raw 16-bit counts."""
        s = supersample
        blurred = gaussian_filter(temp_c, sigma=0.7 * s, mode="nearest")
        h, w = self.fpn.shape
        pix = blurred.reshape(h, s, w, s).mean(axis=(1, 3))
        counts = THERMAL_OFFSET + THERMAL_GAIN * pix + self.fpn + rng.normal(0, 6.0, (h, w))
        return np.clip(np.round(counts), 0, 65535).astype(np.uint16)


class EventSimulator:
    """Events from the log intensity of a pixel array sampled at increasing times (linear in between).

    Each pixel keeps a reference log level; when the log intensity moves a contrast threshold (its own, drawn
    around the mean) above or below it, an ON or OFF event fires at the linearly interpolated crossing time and the
    reference moves by one threshold. Events closer than the refractory period to the previous event of the same
    pixel are dropped. Background-activity noise events are added uniformly in time.
    """

    def __init__(
        self,
        width: int,
        height: int,
        threshold: float,
        sigma: float,
        refractory_us: int,
        eps: float,
        rng: np.random.Generator,
        max_per_step: int = 8,
    ) -> None:
        n = width * height
        self.width, self.height = width, height
        self.c_on = np.clip(rng.normal(threshold, sigma, n), 0.05, None)
        self.c_off = np.clip(rng.normal(threshold, sigma, n), 0.05, None)
        self.refractory_us = refractory_us
        self.eps = eps
        self.max_per_step = max_per_step
        self.ref: np.ndarray | None = None
        self.prev_log: np.ndarray | None = None
        self.prev_t = 0.0
        self._chunks: list = []

    def log_intensity(self, lum: Float[np.ndarray, " n"]) -> Float[np.ndarray, " n"]:
        return np.log(lum + self.eps)

    def reset(self, lum: Float[np.ndarray, " n"], t: float) -> None:
        """Start at time ``t`` (seconds) with every reference at the current level."""
        self.prev_log = self.log_intensity(lum)
        self.ref = self.prev_log.copy()
        self.prev_t = t

    def step(self, lum: Float[np.ndarray, " n"], t: float) -> None:
        """Advance to time ``t`` with the pixels' new linear intensity ``lum``."""
        assert self.ref is not None and self.prev_log is not None, "call reset() first"
        cur = self.log_intensity(lum)
        prev, ref = self.prev_log, self.ref
        n_on = np.clip(np.floor((cur - ref) / self.c_on), 0, self.max_per_step).astype(np.int64)
        n_off = np.clip(np.floor((ref - cur) / self.c_off), 0, self.max_per_step).astype(np.int64)
        dl = cur - prev
        safe = np.where(np.abs(dl) > 1e-12, dl, 1e-12)
        for counts, sign, c in ((n_on, 1, self.c_on), (n_off, -1, self.c_off)):
            pix = np.nonzero(counts)[0]
            if pix.size == 0:
                continue
            k = counts[pix]
            rep = np.repeat(pix, k)
            j = np.arange(rep.size) - np.repeat(np.cumsum(k) - k, k) + 1
            level = ref[rep] + sign * j * c[rep]
            frac = np.clip((level - prev[rep]) / safe[rep], 0.0, 1.0)
            tt = self.prev_t + frac * (t - self.prev_t)
            self._chunks.append((rep, tt, np.full(rep.size, 1 if sign > 0 else 0, np.uint8)))
        self.ref = ref + n_on * self.c_on - n_off * self.c_off
        self.prev_log = cur
        self.prev_t = t

    def finish(
        self, t_start: float, t_end: float, noise_hz: float, rng: np.random.Generator
    ) -> Tuple[UInt16[np.ndarray, " m"], UInt16[np.ndarray, " m"], Int64[np.ndarray, " m"], UInt8[np.ndarray, " m"]]:
        """All events as (x uint16, y uint16, t int64 microseconds, p uint8), sorted by time."""
        if self._chunks:
            pix = np.concatenate([c[0] for c in self._chunks])
            t = np.concatenate([c[1] for c in self._chunks])
            p = np.concatenate([c[2] for c in self._chunks])
        else:
            pix, t, p = np.zeros(0, np.int64), np.zeros(0), np.zeros(0, np.uint8)
        t_us = np.round(t * 1e6).astype(np.int64)
        if self.refractory_us > 0 and t_us.size:
            order = np.lexsort((t_us, pix))
            pix, t_us, p = pix[order], t_us[order], p[order]
            same = np.zeros(pix.size, bool)
            same[1:] = pix[1:] == pix[:-1]
            dt = np.diff(t_us, prepend=t_us[:1])
            keep = ~same | (dt >= self.refractory_us)
            pix, t_us, p = pix[keep], t_us[keep], p[keep]
        n = self.width * self.height
        n_noise = int(rng.poisson(noise_hz * n * max(t_end - t_start, 0.0)))
        if n_noise:
            pix = np.concatenate([pix, rng.integers(0, n, n_noise)])
            t_us = np.concatenate([t_us, np.round(rng.uniform(t_start, t_end, n_noise) * 1e6).astype(np.int64)])
            p = np.concatenate([p, rng.integers(0, 2, n_noise).astype(np.uint8)])
        order = np.lexsort((pix, t_us))
        pix, t_us, p = pix[order], t_us[order], p[order]
        x = (pix % self.width).astype(np.uint16)
        y = (pix // self.width).astype(np.uint16)
        return x, y, t_us, p


def event_frame(x: np.ndarray, y: np.ndarray, p: np.ndarray, width: int, height: int) -> Float[np.ndarray, "h w"]:
    """Signed event count image (ON - OFF) of a set of events."""
    img = np.zeros(height * width)
    np.add.at(img, y.astype(np.int64) * width + x.astype(np.int64), np.where(p > 0, 1.0, -1.0))
    return img.reshape(height, width)
