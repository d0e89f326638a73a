"""RGB exposure intervals: from the capture's ``rgb/exposures.txt``, or from an exposure time given as an option.

Each RGB frame integrates light over ``[exposure_start, exposure_end]`` (seconds, the timestamps' clock). A blur
model renders sub-poses across that interval; a zero-length interval is an instantaneous (sharp) frame.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Dict, Literal, Optional, Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.readers import FrameList, read_time_list

EXPOSURES_FILE = "exposures.txt"
TimestampAt = Literal["middle", "start", "end"]


def read_exposures(rgb_dir: Path, frames: FrameList) -> Optional[Float[np.ndarray, "n 2"]]:
    """(start, end) per RGB frame from ``rgb_dir/exposures.txt`` ("<file name> <start s> <end s>" per line, the
    frames of timestamps.txt); None when the file is absent."""
    path = Path(rgb_dir) / EXPOSURES_FILE
    if not path.is_file():
        return None
    by_name: Dict[str, Tuple[float, float]] = {}
    columns = ("file name", "exposure start", "exposure end")
    for row in read_time_list(path, columns, what="exposure times"):
        start, end = row.times
        if end < start:
            raise RawInputError(f"{path}:{row.lineno}: exposure end {end} must be finite and >= its start {start}")
        if row.name in by_name:
            raise RawInputError(f"{path}:{row.lineno}: frame {row.name} is listed twice")
        by_name[row.name] = (start, end)
    missing = [p.name for p in frames.paths if p.name not in by_name]
    if missing:
        raise RawInputError(
            f"{path}: no exposure for {len(missing)} of the {len(frames)} frames of timestamps.txt ({missing[:3]}"
            f"{' ...' if len(missing) > 3 else ''})"
        )
    return np.array([by_name[p.name] for p in frames.paths], dtype=np.float64)


def exposures_from_time(
    times: Float[np.ndarray, " n"], exposure_time: float, timestamp_at: TimestampAt
) -> Float[np.ndarray, "n 2"]:
    """(start, end) per frame of a fixed exposure time, the timestamps lying at the exposure's middle/start/end."""
    if not (np.isfinite(exposure_time) and exposure_time >= 0):
        raise ValueError(f"--exposure-time must be a non-negative number of seconds, got {exposure_time}")
    lead = {"middle": 0.5, "start": 0.0, "end": 1.0}[timestamp_at] * exposure_time
    start = np.asarray(times, dtype=np.float64) - lead
    return np.stack([start, start + exposure_time], -1)


def frame_exposures(
    raw: Path, frames: FrameList, exposure_time: Optional[float], timestamp_at: TimestampAt
) -> Tuple[Optional[Float[np.ndarray, "n 2"]], Dict]:
    """The RGB frames' exposure intervals (None when unknown) and the dataset's ``agrinerf.exposure`` record:
    ``exposure_time`` (the --exposure-time option) when given, else rgb/exposures.txt when present."""
    from_file = read_exposures(Path(raw) / "rgb", frames)
    if exposure_time is not None:
        exp = exposures_from_time(frames.times, exposure_time, timestamp_at)
        meta: Dict[str, Any] = {"source": "--exposure-time", "timestamp_at": timestamp_at}
        if from_file is not None:
            meta["overrides"] = f"rgb/{EXPOSURES_FILE}"
    elif from_file is not None:
        exp, meta = from_file, {"source": f"rgb/{EXPOSURES_FILE}"}
    else:
        return None, {"source": "none"}
    dur = exp[:, 1] - exp[:, 0]
    meta.update(
        {k: round(float(v), 9) for k, v in (("median_s", np.median(dur)), ("min_s", dur.min()), ("max_s", dur.max()))}
    )
    return exp, meta
