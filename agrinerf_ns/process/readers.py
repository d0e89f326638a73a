"""Readers for a raw capture folder (layout in docs/formats.md).

Every reader raises :class:`RawInputError` naming the file and the problem; none writes anything.
Event files are read in chunks (:func:`iter_event_chunks`) so that memory does not grow with the file.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Dict, Iterator, List, Optional, Tuple

import cv2
import numpy as np
import yaml
from jaxtyping import Float, Int64, UInt8, UInt16

if TYPE_CHECKING:
    from agrinerf_ns.process.radiometric import RadiometricCalibration


class RawInputError(ValueError):
    """A raw capture file is missing, unreadable or inconsistent. The message names the file."""


# ----------------------------------------------------------------------------------------------------------------
# frames and timestamps


@dataclass(frozen=True)
class FrameList:
    """Frames of one sensor: file paths and times in seconds, sorted by time."""

    paths: List[Path]
    times: Float[np.ndarray, " n"]

    def __len__(self) -> int:
        return len(self.paths)


def read_timestamps(folder: Path) -> FrameList:
    """Read ``folder/timestamps.txt`` ("<file name> <time in seconds>" per line)."""
    ts_file = folder / "timestamps.txt"
    if not ts_file.is_file():
        raise RawInputError(f"{ts_file}: missing timestamps file")
    paths: List[Path] = []
    times: List[float] = []
    for lineno, line in enumerate(ts_file.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != 2:
            raise RawInputError(f"{ts_file}:{lineno}: expected '<file name> <time>', got {line!r}")
        try:
            t = float(parts[1])
        except ValueError as err:
            raise RawInputError(f"{ts_file}:{lineno}: time {parts[1]!r} is not a number") from err
        if not np.isfinite(t):
            raise RawInputError(f"{ts_file}:{lineno}: time {parts[1]!r} is not finite")
        frame = folder / parts[0]
        if not frame.is_file():
            raise RawInputError(f"{ts_file}:{lineno}: frame file {frame} does not exist")
        paths.append(frame)
        times.append(t)
    if not paths:
        raise RawInputError(f"{ts_file}: no frames listed")
    t_arr = np.asarray(times, dtype=np.float64)
    if np.any(np.diff(t_arr) <= 0):
        bad = int(np.argmax(np.diff(t_arr) <= 0)) + 1
        raise RawInputError(f"{ts_file}: times must increase strictly (frame {paths[bad].name} at {t_arr[bad]})")
    return FrameList(paths=paths, times=t_arr)


def read_rgb(path: Path) -> UInt8[np.ndarray, "h w 3"]:
    """Read an 8-bit RGB frame (returned in RGB channel order)."""
    img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.dtype != np.uint8:
        raise RawInputError(f"{path}: RGB frame must be 8-bit, got {img.dtype}")
    if img.ndim == 2:
        img = np.repeat(img[:, :, None], 3, axis=2)
    elif img.shape[2] == 4:
        img = img[:, :, :3]
    if img.shape[2] != 3:
        raise RawInputError(f"{path}: RGB frame must have 3 channels, got shape {img.shape}")
    return np.ascontiguousarray(img[:, :, ::-1])


def read_thermal(path: Path, expected_hw: Optional[Tuple[int, int]] = None) -> UInt16[np.ndarray, "h w"]:
    """Read a raw single-channel thermal frame (16-bit counts; 8-bit is widened). PNG or TIFF, by content; a
    ``.jpg`` is a FLIR radiometric JPEG (its embedded raw counts, :mod:`agrinerf_ns.process.flir`)."""
    if Path(path).suffix.lower() in (".jpg", ".jpeg"):
        from agrinerf_ns.process.flir import read_flir

        img = read_flir(path).counts
    else:
        img = _imread(path, cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        if img.shape[2] == 1 or np.all(img == img[:, :, :1]):
            img = img[:, :, 0]
        else:
            raise RawInputError(f"{path}: thermal frame must be single-channel, got shape {img.shape}")
    if img.dtype == np.uint8:
        img = img.astype(np.uint16)
    if img.dtype != np.uint16:
        raise RawInputError(f"{path}: thermal frame must be 16-bit unsigned counts, got {img.dtype}")
    if expected_hw is not None and tuple(img.shape) != tuple(expected_hw):
        raise RawInputError(
            f"{path}: thermal frame is {img.shape[1]}x{img.shape[0]} (w x h) but calibration says "
            f"{expected_hw[1]}x{expected_hw[0]}"
        )
    return img


def _imread(path: Path, flags: int) -> np.ndarray:
    if not Path(path).is_file():
        raise RawInputError(f"{path}: file does not exist")
    data = np.fromfile(str(path), dtype=np.uint8)
    img = cv2.imdecode(data, flags) if data.size else None
    if img is None:
        raise RawInputError(f"{path}: cannot decode image (corrupt or not an image file)")
    return img


# ----------------------------------------------------------------------------------------------------------------
# calibration


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
    radiometric: Optional["RadiometricCalibration"] = None
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
        from agrinerf_ns.process.radiometric import parse_calibration

        radiometric = parse_calibration(entry["radiometric"], path, name)
    return CameraCalib(name, modality, K, dist, int(res[0]), int(res[1]), T_cam_rgb, radiometric)


# ----------------------------------------------------------------------------------------------------------------
# events


@dataclass
class EventChunk:
    """A slice of the event stream: pixel coordinates, time in microseconds, polarity 0 = OFF, 1 = ON."""

    x: UInt16[np.ndarray, " n"]
    y: UInt16[np.ndarray, " n"]
    t: Int64[np.ndarray, " n"]
    p: UInt8[np.ndarray, " n"]

    def __len__(self) -> int:
        return int(self.t.shape[0])


EVENT_FILE_NAMES = ("events.h5", "events.hdf5", "events.raw", "events.npz", "events.txt")


def find_event_file(events_dir: Path) -> Optional[Path]:
    """Return the first of :data:`EVENT_FILE_NAMES` present, else None."""
    for name in EVENT_FILE_NAMES:
        if (events_dir / name).is_file():
            return events_dir / name
    return None


def iter_event_chunks(
    path: Path, chunk_size: int = 2_000_000, sensor_wh: Optional[Tuple[int, int]] = None
) -> Iterator[EventChunk]:
    """Stream events in chunks of at most ``chunk_size``, validating as they go.

    Checks: non-negative, non-decreasing timestamps (also across chunk boundaries); coordinates inside
    ``sensor_wh`` (width, height) when given; polarity in {0, 1}. Errors name the file and the event index.
    """
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5"):
        raw = _iter_h5(path, chunk_size)
    elif suffix == ".npz":
        raw = _iter_npz(path, chunk_size)
    elif suffix == ".txt":
        raw = _iter_txt(path, chunk_size)
    elif suffix == ".raw":
        raw = _iter_raw(path, chunk_size)
    else:
        raise RawInputError(f"{path}: unknown event file type (expected .h5, .raw, .npz or .txt)")
    last_t = 0
    start = 0
    for x, y, t, p in raw:
        n = t.shape[0]
        if not (x.shape[0] == y.shape[0] == p.shape[0] == n):
            raise RawInputError(f"{path}: event arrays x, y, t, p have different lengths")
        if n == 0:
            continue
        x, y, t, p = _as_event_dtypes(path, x, y, t, p, start)
        if t[0] < last_t or np.any(t[1:] < t[:-1]):
            bad = 0 if t[0] < last_t else int(np.argmax(t[1:] < t[:-1])) + 1
            if t[bad] < 0:
                raise RawInputError(f"{path}: negative timestamp at event {start + bad} (t = {t[bad]} us)")
            raise RawInputError(f"{path}: timestamps not sorted at event {start + bad} (t = {t[bad]} us)")
        if t[0] < 0:
            raise RawInputError(f"{path}: negative timestamp at event {start} (t = {t[0]} us)")
        if sensor_wh is not None:
            outside = (x >= sensor_wh[0]) | (y >= sensor_wh[1])
            if np.any(outside):
                bad = int(np.argmax(outside))
                raise RawInputError(
                    f"{path}: event {start + bad} at (x={x[bad]}, y={y[bad]}) is outside the "
                    f"{sensor_wh[0]}x{sensor_wh[1]} sensor"
                )
        if np.any(p > 1):
            bad = int(np.argmax(p > 1))
            raise RawInputError(f"{path}: polarity must be 0 or 1, got {p[bad]} at event {start + bad}")
        last_t = int(t[-1])
        start += n
        yield EventChunk(x, y, t, p)


def _as_event_dtypes(path: Path, x, y, t, p, start: int):
    for name, arr in (("x", x), ("y", y)):
        if np.issubdtype(arr.dtype, np.floating) and np.any(arr != np.round(arr)):
            raise RawInputError(f"{path}: event coordinate {name} must be integral")
        if np.any(arr < 0) or np.any(arr > 65535):
            bad = int(np.argmax((arr < 0) | (arr > 65535)))
            raise RawInputError(f"{path}: event {start + bad} has coordinate {name}={arr[bad]} outside the sensor")
    p = np.asarray(p)
    if np.issubdtype(p.dtype, np.signedinteger) or np.issubdtype(p.dtype, np.floating):
        p = np.where(p < 0, 0, p)  # accept -1/+1 polarity as used by some recorders
    return (
        np.asarray(x).astype(np.uint16, copy=False),
        np.asarray(y).astype(np.uint16, copy=False),
        np.asarray(t).astype(np.int64, copy=False),
        p.astype(np.uint8, copy=False),
    )


def _iter_h5(path: Path, chunk_size: int):
    import h5py

    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise RawInputError(f"{path}: cannot open HDF5 file ({err})") from err
    with f:
        grp = f["events"] if "events" in f else f
        for key in ("x", "y", "t", "p"):
            if key not in grp:
                raise RawInputError(f"{path}: dataset events/{key} missing")
        n = grp["t"].shape[0]
        for s in range(0, n, chunk_size):
            e = min(n, s + chunk_size)
            yield grp["x"][s:e], grp["y"][s:e], grp["t"][s:e], grp["p"][s:e]


def _npy_header(fh, version: Tuple[int, int]) -> Tuple[Tuple[int, ...], bool, np.dtype]:
    """(shape, Fortran order, dtype) from an open .npy file after its magic: numpy's reader for every format version,
    which numpy keeps private (its public readers each take one version)."""
    return np.lib.format._read_array_header(fh, version)  # type: ignore[attr-defined]  # noqa: SLF001


def _iter_npz(path: Path, chunk_size: int):
    """Read each array of an .npz member by member, ``chunk_size`` entries at a time (no full load)."""
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, OSError) as err:
        raise RawInputError(f"{path}: not a valid .npz file ({err})") from err
    with zf:
        members = {}
        for key in ("x", "y", "t", "p"):
            if f"{key}.npy" not in zf.namelist():
                raise RawInputError(f"{path}: array '{key}' missing")
            fh = zf.open(f"{key}.npy")
            version = np.lib.format.read_magic(fh)
            shape, fortran, dtype = _npy_header(fh, version)
            if len(shape) != 1:
                raise RawInputError(f"{path}: array '{key}' must be 1-D, got shape {shape}")
            members[key] = (fh, int(shape[0]), dtype)
        n = members["t"][1]
        if any(m[1] != n for m in members.values()):
            raise RawInputError(f"{path}: event arrays x, y, t, p have different lengths")
        for s in range(0, n, chunk_size):
            m = min(chunk_size, n - s)
            out = []
            for key in ("x", "y", "t", "p"):
                fh, _, dtype = members[key]
                buf = fh.read(m * dtype.itemsize)
                if len(buf) != m * dtype.itemsize:
                    raise RawInputError(f"{path}: array '{key}' is truncated")
                out.append(np.frombuffer(buf, dtype=dtype))
            yield tuple(out)


def _iter_txt(path: Path, chunk_size: int):
    """Text events "t x y p" per line, t in seconds (converted to integer microseconds)."""
    from itertools import islice

    with open(path, "r") as fh:
        while True:
            raw_lines = list(islice(fh, chunk_size))
            if not raw_lines:
                return
            lines = [ln for ln in raw_lines if ln.strip() and not ln.lstrip().startswith("#")]
            if not lines:
                continue
            try:
                block = np.loadtxt(lines, ndmin=2, dtype=np.float64)
            except ValueError as err:
                raise RawInputError(f"{path}: malformed event line ({err})") from err
            if block.shape[1] != 4:
                raise RawInputError(f"{path}: expected 't x y p' per line, got {block.shape[1]} columns")
            t_us = np.round(block[:, 0] * 1e6).astype(np.int64)
            yield block[:, 1], block[:, 2], t_us, block[:, 3]


def _iter_raw(path: Path, chunk_size: int):
    """Prophesee ``.raw`` (EVT 2.0 / 3.0): CD events, decoded ``chunk_size`` words at a time and re-sliced to at most
    ``chunk_size`` events (external-trigger events: :func:`read_triggers`)."""
    from agrinerf_ns.process.event_codecs import iter_raw

    for d in iter_raw(path, chunk_size):
        for s in range(0, len(d.t), chunk_size):
            yield d.x[s : s + chunk_size], d.y[s : s + chunk_size], d.t[s : s + chunk_size], d.p[s : s + chunk_size]


@dataclass(frozen=True)
class TriggerEvents:
    """External-trigger events of an event camera: time (microseconds), edge (1 rising, 0 falling), channel id."""

    t: Int64[np.ndarray, " n"]
    p: UInt8[np.ndarray, " n"]
    id: UInt8[np.ndarray, " n"]

    def __len__(self) -> int:
        return int(self.t.shape[0])


def read_triggers(path: Path) -> TriggerEvents:
    """External-trigger events of an event file: the ``triggers`` group (t, p, id) of an ``.h5`` file, or the
    EXT_TRIGGER words of a ``.raw`` file; other formats have none (empty result)."""
    suffix = path.suffix.lower()
    empty = TriggerEvents(np.zeros(0, np.int64), np.zeros(0, np.uint8), np.zeros(0, np.uint8))
    if suffix == ".raw":
        from agrinerf_ns.process.event_codecs import iter_raw

        parts = [(d.trig_t, d.trig_p, d.trig_id) for d in iter_raw(path)]
        if not parts:
            return empty
        return TriggerEvents(*(np.concatenate([q[i] for q in parts]) for i in range(3)))
    if suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "r") as f:
            if "triggers" not in f:
                return empty
            g = f["triggers"]
            for key in ("t", "p"):
                if key not in g:
                    raise RawInputError(f"{path}: dataset triggers/{key} missing")
            ids = g["id"][:] if "id" in g else np.zeros(g["t"].shape[0], np.uint8)
            return TriggerEvents(g["t"][:].astype(np.int64), g["p"][:].astype(np.uint8), ids.astype(np.uint8))
    return empty


def count_events(path: Path) -> int:
    """Number of events in a file, without reading them (text files are counted by lines, ``.raw`` words by
    type)."""
    suffix = path.suffix.lower()
    if suffix == ".raw":
        from agrinerf_ns.process.event_codecs import count_raw

        return count_raw(path)
    if suffix in (".h5", ".hdf5"):
        import h5py

        with h5py.File(path, "r") as f:
            grp = f["events"] if "events" in f else f
            return int(grp["t"].shape[0]) if "t" in grp else 0
    if suffix == ".npz":
        with zipfile.ZipFile(path) as zf:
            fh = zf.open("t.npy")
            version = np.lib.format.read_magic(fh)
            shape, _, _ = _npy_header(fh, version)
            return int(shape[0])
    with open(path, "rb") as fh:
        return sum(1 for line in fh if line.strip() and not line.startswith(b"#"))


# ----------------------------------------------------------------------------------------------------------------
# odometry


def read_tum(path: Path) -> Tuple[Float[np.ndarray, " n"], Float[np.ndarray, "n 4 4"]]:
    """Read a TUM trajectory "t tx ty tz qx qy qz qw" -> (times, 4x4 camera-to-world matrices)."""
    if not path.is_file():
        raise RawInputError(f"{path}: pose file missing")
    rows = []
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise RawInputError(f"{path}:{lineno}: non-numeric value in {line!r}") from err
        if len(vals) != 8:
            raise RawInputError(f"{path}:{lineno}: expected 8 values 't tx ty tz qx qy qz qw', got {len(vals)}")
        rows.append(vals)
    if not rows:
        raise RawInputError(f"{path}: no poses")
    arr = np.asarray(rows, dtype=np.float64)
    q = arr[:, 4:8]
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < 1e-8):
        raise RawInputError(f"{path}: zero quaternion at line {int(np.argmin(norm)) + 1}")
    q = q / norm[:, None]
    c2w = np.tile(np.eye(4), (arr.shape[0], 1, 1))
    c2w[:, :3, :3] = quat_xyzw_to_rotmat(q)
    c2w[:, :3, 3] = arr[:, 1:4]
    return arr[:, 0], c2w


def quat_xyzw_to_rotmat(q: Float[np.ndarray, "n 4"]) -> Float[np.ndarray, "n 3 3"]:
    """Unit quaternions (x, y, z, w) to rotation matrices."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )
