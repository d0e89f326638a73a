"""A thermal camera's radiometric calibration: raw counts -> degrees Celsius.

Two forms, as rigs give them (docs/formats.md, "Radiometric calibration"):

- ``linear`` (calib.yaml, the thermal camera's ``radiometric`` entry: ``counts_at_0c``, ``counts_per_kelvin``), the
  map of a camera in a linear radiometric mode or of a user's two-point calibration:
  ``T = (counts - counts_at_0c) / counts_per_kelvin``;
- ``planck`` (calib.yaml with ``planck_r1, planck_r2, planck_b, planck_f, planck_o``, or a FLIR radiometric JPEG's
  camera-info record, :mod:`agrinerf_ns.process.flir`): ``kelvin = B / ln(R1 / (R2 (counts + O)) + F)``, a black
  body seen through no atmosphere.

Counts the map cannot take (a Planck logarithm of a non-positive number) give NaN, which the dataset writes as "no
value". Written by hand: a two-line map per form, which no maintained library of the field exposes on its own.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Mapping, Optional

import numpy as np
from jaxtyping import Float

from agrinerf_ns.process import flir
from agrinerf_ns.process.errors import RawInputError

LINEAR_KEYS = ("counts_at_0c", "counts_per_kelvin")


@dataclass(frozen=True)
class RadiometricCalibration:
    """Counts-to-temperature map of one thermal camera (``model``: linear or planck; ``params``; where it came from)."""

    model: str
    params: Dict[str, float]
    source: str

    def celsius(self, counts: np.ndarray) -> Float[np.ndarray, "*s"]:
        """Degrees C (float64) of raw counts; NaN where the map is undefined."""
        c = np.asarray(counts, np.float64)
        if self.model == "linear":
            return (c - self.params["counts_at_0c"]) / self.params["counts_per_kelvin"]
        with np.errstate(divide="ignore", invalid="ignore"):
            kelvin = flir.counts_to_kelvin(c, self.params)
        kelvin = np.where(np.isfinite(kelvin) & (kelvin > 0), kelvin, np.nan)
        return kelvin - 273.15

    def as_dict(self) -> Dict[str, Any]:
        """The dataset's record (``agrinerf.thermal_radiometric``)."""
        formula = (
            "celsius = (counts - counts_at_0c) / counts_per_kelvin"
            if self.model == "linear"
            else flir.MAP + " - 273.15"
        )
        return {"model": self.model, "source": self.source, **self.params, "counts_to_celsius": formula}


def parse_calibration(entry: Any, path: Path, camera: str) -> RadiometricCalibration:
    """The ``radiometric`` entry of a camera in calib.yaml; :class:`RawInputError` naming the file and the key."""
    where = f"{path}: {camera}.radiometric"
    if not isinstance(entry, Mapping):
        raise RawInputError(f"{where} must be a mapping (model: linear with {', '.join(LINEAR_KEYS)}, or planck)")
    model = str(entry.get("model", "linear"))
    keys = {"linear": LINEAR_KEYS, "planck": flir.PLANCK_KEYS}.get(model)
    if keys is None:
        raise RawInputError(f"{where}.model must be linear or planck, got {model!r}")
    params: Dict[str, float] = {}
    for key in keys:
        if key not in entry:
            raise RawInputError(f"{where} lacks '{key}' (model {model} needs {', '.join(keys)})")
        try:
            params[key] = float(entry[key])
        except (TypeError, ValueError) as err:
            raise RawInputError(f"{where}.{key} must be a number, got {entry[key]!r}") from err
        if not math.isfinite(params[key]):
            raise RawInputError(f"{where}.{key} must be finite, got {entry[key]!r}")
    if model == "linear" and params["counts_per_kelvin"] == 0:
        raise RawInputError(f"{where}.counts_per_kelvin must not be 0")
    if model == "planck" and (params["planck_b"] == 0 or params["planck_r2"] == 0):
        raise RawInputError(f"{where}: planck_b and planck_r2 must not be 0")
    return RadiometricCalibration(model, params, f"calib.yaml {camera}.radiometric")


def capture_calibration(
    calib_entry: Optional[RadiometricCalibration], first_frame: Path
) -> Optional[RadiometricCalibration]:
    """The calibration a capture's temperatures use: calib.yaml's (a user's calibration wins), else the Planck
    constants of a FLIR radiometric JPEG (its first frame's camera info), else None (no temperatures)."""
    if calib_entry is not None:
        return calib_entry
    if first_frame.suffix.lower() in (".jpg", ".jpeg"):
        meta = flir.read_flir(first_frame).metadata
        return RadiometricCalibration("planck", {k: float(meta[k]) for k in flir.PLANCK_KEYS},
                                      "FLIR radiometric JPEG (first frame's camera info)")  # fmt: skip
    return None
