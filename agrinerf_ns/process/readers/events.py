"""Readers of the capture's event files (``events/events.{h5,hdf5,raw,npz,txt}``) and their external-trigger events.

Event files are read in chunks (:func:`iter_event_chunks`) so that memory does not grow with the file; the
Prophesee ``.raw`` words are decoded by :mod:`agrinerf_ns.process.event_codecs`.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass
from itertools import islice
from pathlib import Path
from typing import Iterator, Optional, Tuple

import numpy as np
from jaxtyping import Int64, UInt8, UInt16

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.event_codecs import count_raw, iter_raw


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
