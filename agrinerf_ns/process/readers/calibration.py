"""Reader of the rig calibration ``calib.yaml`` (a Kalibr camchain with a ``modality`` per camera)."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, Optional

import numpy as np
import yaml
from jaxtyping import Float

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.radiometric import RadiometricCalibration, parse_calibration


@dataclass(frozen=True)
class CameraCalib:
    """One camera of the rig. ``T_cam_rgb`` maps points from the RGB camera's frame into this camera's frame."""

    name: str
    modality: str
    K: Float[np.ndarray, "3 3"]
    dist: Float[np.ndarray, "4"]
    width: int
    height: int
    T_cam_rgb: Float[np.ndarray, "4 4"] = field(default_factory=lambda: np.eye(4))
    radiometric: Optional[RadiometricCalibration] = None
    """Counts-to-temperature map (a thermal camera's ``radiometric`` entry in calib.yaml), or None."""

    def as_dict(self) -> Dict:
        extra = {"radiometric": self.radiometric.as_dict()} if self.radiometric is not None else {}
        return {
            "name": self.name,
            "modality": self.modality,
            "intrinsics": [float(self.K[0, 0]), float(self.K[1, 1]), float(self.K[0, 2]), float(self.K[1, 2])],
            "distortion_coeffs": [float(x) for x in self.dist],
            "resolution": [self.width, self.height],
            "T_cam_rgb": self.T_cam_rgb.tolist(),
            **extra,
        }


@dataclass(frozen=True)
class RigCalib:
    """Calibration by modality; ``rgb`` is always present."""

    rgb: CameraCalib
    thermal: Optional[CameraCalib] = None
    event: Optional[CameraCalib] = None


def read_calibration(path: Path) -> RigCalib:
    """Read a Kalibr camchain YAML (cam0 = RGB; each camera has ``modality``; ``T_cn_cnm1`` chains the rest)."""
    if not path.is_file():
        raise RawInputError(f"{path}: calibration file missing")
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as err:
        raise RawInputError(f"{path}: not valid YAML ({err})") from err
    if not isinstance(doc, dict):
        raise RawInputError(f"{path}: expected a mapping of cameras cam0, cam1, ...")
    names = sorted((k for k in doc if k.startswith("cam") and k[3:].isdigit()), key=lambda k: int(k[3:]))
    if not names or names[0] != "cam0":
        raise RawInputError(f"{path}: camera cam0 (RGB) missing")
    cams: Dict[str, CameraCalib] = {}
    T_prev_rgb = np.eye(4)
    for idx, name in enumerate(names):
        if name != f"cam{idx}":
            raise RawInputError(f"{path}: camera cam{idx} missing (found {name} after it)")
        entry = doc[name]
        if not isinstance(entry, dict):
            raise RawInputError(f"{path}: {name} is not a mapping")
        T = np.eye(4)
        if idx > 0:
            if "T_cn_cnm1" not in entry:
                raise RawInputError(f"{path}: {name} lacks T_cn_cnm1")
            T = np.asarray(entry["T_cn_cnm1"], dtype=np.float64)
            if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
                raise RawInputError(f"{path}: {name}.T_cn_cnm1 must be a 4x4 rigid transform")
        T_cam_rgb = T @ T_prev_rgb
        T_prev_rgb = T_cam_rgb
        cam = _parse_camera(path, name, entry, T_cam_rgb)
        if cam.modality in cams:
            raise RawInputError(f"{path}: two cameras with modality {cam.modality!r}")
        cams[cam.modality] = cam
    if "rgb" not in cams or cams["rgb"].name != "cam0":
        raise RawInputError(f"{path}: cam0 must be the RGB camera (modality: rgb)")
    return RigCalib(rgb=cams["rgb"], thermal=cams.get("thermal"), event=cams.get("event"))


def _parse_camera(path: Path, name: str, entry: Dict, T_cam_rgb: np.ndarray) -> CameraCalib:
    for key in ("intrinsics", "resolution", "modality"):
        if key not in entry:
            raise RawInputError(f"{path}: {name} lacks '{key}'")
    modality = str(entry["modality"])
    if modality not in ("rgb", "thermal", "event"):
        raise RawInputError(f"{path}: {name}.modality must be rgb, thermal or event, got {modality!r}")
    model = entry.get("camera_model", "pinhole")
    if model != "pinhole":
        raise RawInputError(f"{path}: {name}.camera_model {model!r} unsupported (pinhole only)")
    dmodel = entry.get("distortion_model", "radtan")
    if dmodel not in ("radtan", "none"):
        raise RawInputError(f"{path}: {name}.distortion_model {dmodel!r} unsupported (radtan only)")
    intr = np.asarray(entry["intrinsics"], dtype=np.float64)
    if intr.shape != (4,) or np.any(intr[:2] <= 0):
        raise RawInputError(f"{path}: {name}.intrinsics must be [fu, fv, pu, pv] with positive focal lengths")
    dist = np.asarray(entry.get("distortion_coeffs", [0, 0, 0, 0]), dtype=np.float64)
    if dist.shape != (4,):
        raise RawInputError(f"{path}: {name}.distortion_coeffs must be [k1, k2, p1, p2]")
    res = entry["resolution"]
    if len(res) != 2 or int(res[0]) <= 0 or int(res[1]) <= 0:
        raise RawInputError(f"{path}: {name}.resolution must be [width, height]")
    K = np.array([[intr[0], 0, intr[2]], [0, intr[1], intr[3]], [0, 0, 1]], dtype=np.float64)
    radiometric = None
    if "radiometric" in entry:
        if modality != "thermal":
            raise RawInputError(f"{path}: {name}.radiometric is given, but {name} is not the thermal camera")
        radiometric = parse_calibration(entry["radiometric"], path, name)
    return CameraCalib(name, modality, K, dist, int(res[0]), int(res[1]), T_cam_rgb, radiometric)
