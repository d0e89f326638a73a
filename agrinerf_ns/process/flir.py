"""FLIR radiometric JPEGs: the embedded raw counts and the camera's Planck constants, read with flyr.

flyr (EUPL-1.2, pure Python, maintained; optional extra ``[flir]``) parses the FLIR APP1 segments. The MIT
alternative, flirimageextractor, needs the exiftool binary, numpy >= 2 and opencv-python, which clash with the
pinned stack. A thermal frame ``thermal/NNNNNN.jpg`` of a raw capture is read through :func:`read_flir` (see
``readers.read_thermal``), and the dataset records the counts-to-temperature map (:func:`counts_to_kelvin`) with
the constants in ``agrinerf.thermal_radiometric``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict

import numpy as np
from jaxtyping import Float, UInt16

from agrinerf_ns.process.errors import RawInputError

PLANCK_KEYS = ("planck_r1", "planck_r2", "planck_b", "planck_f", "planck_o")
MAP = "kelvin = planck_b / ln(planck_r1 / (planck_r2 * (counts + planck_o)) + planck_f)"
"""Counts to temperature of a black body (emissivity 1, no atmosphere between), FLIR's calibration form."""


@dataclass(frozen=True)
class FlirRadiometric:
    """Raw counts of a radiometric FLIR JPEG and its metadata (Planck constants, emissivity, distances...)."""

    counts: UInt16[np.ndarray, "h w"]
    metadata: Dict[str, float]

    @property
    def planck(self) -> Dict[str, float]:
        return {k: float(self.metadata[k]) for k in PLANCK_KEYS}


def read_flir(path: Path) -> FlirRadiometric:
    """Read the raw counts and metadata; :class:`RawInputError` naming the file when flyr is missing or the JPEG
    holds no radiometric data."""
    try:
        from flyr.records import RecordIndex, extract_flir_app1, parse_flir_records
        from flyr.thermal import parse_camera_info, parse_raw_data
    except ImportError as err:
        raise RawInputError(
            f"{path}: reading FLIR radiometric JPEGs needs flyr: pip install 'agrinerf-ns[flir]' (EUPL-1.2)"
        ) from err
    if not Path(path).is_file():
        raise RawInputError(f"{path}: file does not exist")
    try:
        with open(path, "rb") as fh:
            app1 = extract_flir_app1(fh)
            records = parse_flir_records(app1)
            if RecordIndex.RAW_DATA.value not in records or RecordIndex.CAMERA_INFO.value not in records:
                raise ValueError("no raw-data or camera-info record")
            _, _, counts = parse_raw_data(app1, records[RecordIndex.RAW_DATA.value])
            meta = parse_camera_info(app1, records[RecordIndex.CAMERA_INFO.value])
    except (ValueError, KeyError, OSError, IndexError) as err:
        raise RawInputError(f"{path}: no FLIR radiometric raw data in this JPEG ({err})") from err
    counts = np.asarray(counts)
    if counts.ndim != 2 or counts.size == 0 or counts.min() < 0 or counts.max() > 65535:
        raise RawInputError(f"{path}: FLIR raw data is not a 2-D array of 16-bit counts (shape {counts.shape})")
    return FlirRadiometric(counts.astype(np.uint16), {k: float(v) for k, v in meta.items()})


def counts_to_kelvin(counts: np.ndarray, planck: Dict[str, float]) -> Float[np.ndarray, "*s"]:
    """Black-body temperature (K) of raw counts, :data:`MAP`."""
    c = np.asarray(counts, np.float64)
    return planck["planck_b"] / np.log(
        planck["planck_r1"] / (planck["planck_r2"] * (c + planck["planck_o"])) + planck["planck_f"]
    )
