"""The jobs of a row and where each writes.

::

    OUT/plan.json                         the segments (frames of each), fixed once the row is cut
    OUT/capture/data/                     the whole capture processed once (with --raw; one world frame)
    OUT/capture/process.json              its record
    OUT/segments/<segNN>/data/            the segment's dataset (:func:`agrinerf_ns.row.segments.cut_segment`)
    OUT/segments/<segNN>/train/, count/   its training run and count, as a survey capture's
    OUT/segments/<segNN>/<stage>.json     a finished step's record (cut, train, count)
    OUT/row/                              the joined row (written by the driver only: :mod:`agrinerf_ns.row.report`)

Each segment's steps are the survey's (:mod:`agrinerf_ns.survey.stages`) after a ``cut`` step: the same records,
retries and resume (a step with a record is not run again).
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any, Dict, List

from agrinerf_ns.row.segments import RowInputError, Segment, cut_segment
from agrinerf_ns.survey.stages import CaptureFolders, count_record, write_record

SEGMENT_STAGES = ("cut", "train", "count")
PLAN = "plan.json"


def capture_folders(out: Path) -> CaptureFolders:
    """``OUT/capture``: the whole capture's processing (with --raw)."""
    return CaptureFolders(Path(out) / "capture")


def segment_folders(out: Path, segment: Segment) -> CaptureFolders:
    """``OUT/segments/<segNN>``."""
    return CaptureFolders(Path(out) / "segments" / segment.name)


def cut_step(dataset: Path, segment: Segment, folders: CaptureFolders, *_: Any) -> Dict[str, Any]:
    """Job: cut ``segment`` out of ``dataset`` into the segment's ``data/``."""
    start = time.perf_counter()
    record = cut_segment(dataset, segment, folders.data)
    return write_record(folders, "cut", record | {"wall_s": time.perf_counter() - start})


def check_plan(out: Path, plan: Dict[str, Any]) -> None:
    """Record ``plan`` in ``OUT/plan.json``, or check that the row there was cut the same way (a resumed row keeps
    its segments); raises :class:`RowInputError` when it was not."""
    path = Path(out) / PLAN
    if path.is_file():
        old = json.loads(path.read_text())
        if old != plan:
            raise RowInputError(
                f"{path}: this row was cut differently ({old['segments']} of {old['frames']} frames, "
                f"--segment-frames {old['segment_frames']} --overlap-frames {old['overlap_frames']}); use another "
                "--out, or the same settings to resume it"
            )
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(plan, indent=1) + "\n")
    tmp.replace(path)


def plan_record(
    dataset: Path, frames: int, size: int, overlap: int, segments: List[Segment], count_from: str = "field"
) -> Dict[str, Any]:
    return {"dataset": str(Path(dataset).resolve()), "frames": frames, "segment_frames": size,
            "overlap_frames": overlap, "segments": [[s.start, s.stop] for s in segments],
            "count_from": count_from}  # fmt: skip


def bodies_count_step(raw: Path, folders: CaptureFolders, settings: Any, *_: Any) -> Dict[str, Any]:
    """Job: count the segment's fruit bodies (``agrinerf-count --path bodies``: no training), scored against
    ``raw``'s truth where it has one."""
    from agrinerf_ns.count.body_count import run_body_count
    from agrinerf_ns.count.fruit_score import FRUITS_JSON

    start = time.perf_counter()
    truth = raw if (Path(raw) / FRUITS_JSON).is_file() else None
    result = run_body_count(folders.data, folders.count, settings.count, truth, overwrite=True)
    record = count_record(result, start, (float("nan"), float("nan")))  # no jackknife: the bodies are not views
    return write_record(folders, "count", record)
