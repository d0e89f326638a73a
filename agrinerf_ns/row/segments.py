"""A long processed dataset cut into overlapping segments along the trajectory, each a dataset folder of its own.

Every segment keeps the capture's frames as they are: the same poses (the odometry's world with ``--poses given``,
the one SfM model of the whole capture otherwise), so fruit counted in different segments are in one world frame and
can be joined (:mod:`agrinerf_ns.row.join`). A segment's per-frame files are hard links to the dataset's (copies
across filesystems); its ``transforms.json`` and ``transforms_thermal.json`` list only its frames, its split lists
are the dataset's restricted to them, its ``events/stream.h5`` holds the events of its frames' time span only, and its
``fruit_bodies.json`` the sightings of its frames. Written atomically; the dataset is only read.
"""

from __future__ import annotations

import json
import math
import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Sequence

import numpy as np
from jaxtyping import Float

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.dataset_format import (
    BLOCK,
    EVENT_STREAM,
    EXPOSURE_END,
    EXPOSURE_START,
    FRAME_FILES,
    FRUIT_BODIES,
    IMAGE,
    THERMAL_TRANSFORMS,
    TIMESTAMP,
    TRANSFORMS,
)

SPLITS = ("train_filenames", "val_filenames", "test_filenames")
FALLBACK_EVAL_EVERY = 8
"""A segment in which the dataset's split holds no held-out (or no training) frame is split afresh, every 8th frame
held out (``agrinerf-process``'s default ``--eval-every``)."""


class RowInputError(ValueError):
    """A row's input or settings cannot be used (said before any work starts)."""


@dataclass(frozen=True)
class Segment:
    """Frames ``start`` .. ``stop - 1`` of the capture, in trajectory order."""

    index: int
    start: int
    stop: int

    @property
    def name(self) -> str:
        return f"seg{self.index:02d}"

    @property
    def middle(self) -> float:
        """The segment's middle, in frames of the trajectory."""
        return 0.5 * (self.start + self.stop - 1)

    def __contains__(self, frame: int) -> bool:
        return self.start <= frame < self.stop


def plan_segments(frames: int, size: int, overlap: int) -> List[Segment]:
    """Segments of ``size`` frames covering ``frames`` frames, neighbours sharing at least ``overlap`` frames: the
    fewest that do, their starts spread evenly (so the overlaps differ by a frame at most). Raises
    :class:`RowInputError` when the settings make no sense or the capture is too short for two segments."""
    if size < 2:
        raise RowInputError(f"--segment-frames must be at least 2, got {size}")
    if not 1 <= overlap < size:
        raise RowInputError(
            f"--overlap-frames must be at least 1 (fruit are joined across borders in the overlap) and below "
            f"--segment-frames ({size}), got {overlap}"
        )
    needed = 2 * size - overlap
    if frames < needed:
        raise RowInputError(
            f"{frames} frames are too few for two segments of {size} frames overlapping by {overlap} (that needs "
            f"{needed}): lower --segment-frames, or count this capture as one run (agrinerf-count)"
        )
    count = math.ceil((frames - overlap) / (size - overlap))
    starts = [round(i * (frames - size) / (count - 1)) for i in range(count)]
    return [Segment(i, s, s + size) for i, s in enumerate(starts)]


def read_transforms(dataset: Path) -> Dict[str, Any]:
    """The dataset's ``transforms.json``; raises :class:`RowInputError` naming the file when it is unusable."""
    path = Path(dataset) / TRANSFORMS
    try:
        meta = json.loads(path.read_text())
        frames = meta["frames"]
        if not isinstance(frames, list) or not all(isinstance(f, dict) and IMAGE.key in f for f in frames):
            raise TypeError("'frames' must be a list of frames with a file_path")
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as err:
        raise RowInputError(f"{path}: not a processed dataset's transforms.json ({err})") from err
    return meta


def trajectory_order(frames: Sequence[Dict[str, Any]]) -> List[int]:
    """Indices of ``frames`` in the order the rig drove them (by timestamp; as listed where a frame has none)."""
    if all(TIMESTAMP in f for f in frames):
        return sorted(range(len(frames)), key=lambda i: float(frames[i][TIMESTAMP]))
    return list(range(len(frames)))


def camera_centres(frames: Sequence[Dict[str, Any]], order: Sequence[int]) -> Float[np.ndarray, "n 3"]:
    """The camera centres (dataset frame) of ``frames`` in ``order``."""
    return np.array([np.asarray(frames[i]["transform_matrix"], np.float64)[:3, 3] for i in order]).reshape(-1, 3)


def _link(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(src, dst)
    except OSError:  # another filesystem, or links not allowed: a copy
        shutil.copy2(src, dst)


def _split(meta: Dict[str, Any], names: List[str]) -> Dict[str, List[str]]:
    from agrinerf_ns.process.dataset_writer import split_names

    kept = set(names)
    lists = {key: [n for n in meta.get(key, []) if n in kept] for key in SPLITS if key in meta}
    if lists and (not lists.get("train_filenames") or not lists.get("val_filenames")):
        return split_names(names, FALLBACK_EVAL_EVERY)
    return lists


def _event_span(frames: Sequence[Dict[str, Any]], block: Dict[str, Any]) -> tuple:
    """Times (microseconds, the frames' clock) of the events a segment's frames can use: their exposures and event
    windows, with a frame interval of margin each side."""
    times = np.array([float(f[TIMESTAMP]) for f in frames])
    lo = min(float(f.get(EXPOSURE_START, f[TIMESTAMP])) for f in frames)
    hi = max(float(f.get(EXPOSURE_END, f[TIMESTAMP])) for f in frames)
    window = float(block.get("events", {}).get("window_s", 0.0))
    step = float(np.median(np.diff(np.sort(times)))) if len(times) > 1 else 0.0
    return int(math.floor((lo - window - step) * 1e6)), int(math.ceil((hi + window + step) * 1e6))


def _cut_stream(src: Path, dst: Path, span: tuple) -> int:
    """The events of ``src`` (a dataset's stream) inside ``span`` into ``dst``, in the same layout; their number."""
    import h5py

    from agrinerf_ns.process.event_h5 import EventH5Writer

    with h5py.File(src, "r") as f:
        t = np.asarray(f["events"]["t"])
        keep = (t >= span[0]) & (t <= span[1])
        x, y, p = (np.asarray(f["events"][k])[keep] for k in "xyp")
        attrs = dict(f.attrs)
    writer = EventH5Writer(dst.parent, max(1, int(keep.sum())), dst.name)
    writer.add(x, y, t[keep], p)
    writer.close(0, attrs)
    return int(keep.sum())


def cut_segment(dataset: Path, segment: Segment, out: Path) -> Dict[str, Any]:
    """Write ``segment`` of ``dataset`` as a dataset folder at ``out`` (atomically, replacing what is there); returns
    the record of the cut (frames, files, events kept)."""
    dataset = Path(dataset)
    meta = read_transforms(dataset)
    frames = meta["frames"]
    order = trajectory_order(frames)
    if segment.stop > len(order):
        raise RowInputError(f"{dataset / TRANSFORMS}: {len(order)} frames, segment {segment.name} needs {segment.stop}")
    chosen = [order[j] for j in range(segment.start, segment.stop)]
    picked = [frames[i] for i in chosen]
    names = [str(f[IMAGE.key]) for f in picked]
    block = dict(meta.get(BLOCK, {}))
    with atomic_output_dir(Path(out), overwrite=True) as tmp:
        files = 0
        for frame in picked:
            for entry in FRAME_FILES:
                if entry.key in frame:
                    _link(dataset / frame[entry.key], tmp / frame[entry.key])
                    files += 1
        record: Dict[str, Any] = {"source": str(dataset.resolve()), "index": segment.index, "files": files,
                                  "frames": [segment.start, segment.stop], "of": len(order)}  # fmt: skip
        skip = {TRANSFORMS, THERMAL_TRANSFORMS, EVENT_STREAM, FRUIT_BODIES}
        per_frame = {entry.folder for entry in FRAME_FILES}
        for path in sorted(dataset.rglob("*")):
            rel = path.relative_to(dataset).as_posix()
            if path.is_file() and rel not in skip and rel.split("/")[0] not in per_frame:
                _link(path, tmp / rel)  # the trajectory and any other file of the whole capture, as it is
        if (dataset / EVENT_STREAM).is_file() and all(TIMESTAMP in f for f in picked):
            record["events"] = _cut_stream(dataset / EVENT_STREAM, tmp / EVENT_STREAM, _event_span(picked, block))
        if (dataset / FRUIT_BODIES).is_file():
            bodies = json.loads((dataset / FRUIT_BODIES).read_text())
            kept = set(names)
            bodies["sightings"] = [s for s in bodies.get("sightings", []) if s.get("frame") in kept]
            (tmp / FRUIT_BODIES).write_text(json.dumps(bodies, indent=1) + "\n")
        out_meta = {k: v for k, v in meta.items() if k not in ("frames", "ply_file_path", *SPLITS)}
        out_meta.update(_split(meta, names))
        if "ply_file_path" in meta:  # SfM points of the whole row would place a segment's first grid box over all of it
            record["dropped"] = f"ply_file_path {meta['ply_file_path']}"
        out_meta[BLOCK] = block | {"segment": record}
        out_meta["frames"] = picked
        (tmp / TRANSFORMS).write_text(json.dumps(out_meta, indent=1) + "\n")
        thermal_path = dataset / THERMAL_TRANSFORMS
        if thermal_path.is_file():
            thermal = json.loads(thermal_path.read_text())
            if len(thermal.get("frames", [])) != len(frames):
                raise RowInputError(f"{thermal_path}: {len(thermal.get('frames', []))} frames, {TRANSFORMS} has "
                                    f"{len(frames)}; the two list the same frames in the same order")  # fmt: skip
            thermal_meta = {k: v for k, v in thermal.items() if k not in ("frames", *SPLITS)}
            thermal_frames = [thermal["frames"][i] for i in chosen]
            to_thermal = {name: str(f["file_path"]) for name, f in zip(names, thermal_frames, strict=True)}
            thermal_meta.update({k: [to_thermal[n] for n in v] for k, v in out_meta.items() if k in SPLITS})
            thermal_meta["frames"] = thermal_frames
            for frame in thermal_frames:  # the thermal frames' own files where the RGB frames do not name them
                for key in ("file_path", "mask_path"):
                    if key in frame and not (tmp / frame[key]).exists():
                        _link(dataset / frame[key], tmp / frame[key])
            (tmp / THERMAL_TRANSFORMS).write_text(json.dumps(thermal_meta, indent=1) + "\n")
    return record
