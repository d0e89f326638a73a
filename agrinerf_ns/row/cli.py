"""``agrinerf-row --data DATASET | --raw CAPTURE --out OUT [--ray local|auto|ADDRESS]``: a whole row's yield map.

A long capture is cut into segments of ``--segment-frames`` frames, neighbours sharing ``--overlap-frames``, all in
the capture's world frame (a raw capture is processed once, as a whole, first); each segment is trained and counted as
a survey capture is (jobs with retries and resume, in this process or on Ray), then the driver joins the segments'
fruit across their borders and writes the row folder ``OUT/row`` (:mod:`agrinerf_ns.row.report`).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Dict, List, Literal, Optional

import tyro
from rich.console import Console

from agrinerf_ns.count.fruit_score import FRUITS_JSON
from agrinerf_ns.dataset_format import FRUIT_BODIES
from agrinerf_ns.orchestrate.executors import executor_for
from agrinerf_ns.orchestrate.jobs import (
    FolderInUse,
    Job,
    JobsReport,
    driver_lock,
    failures_markdown,
    run_jobs,
    write_failures,
)
from agrinerf_ns.row import segment_steps
from agrinerf_ns.row.join import JOIN_DISTANCE
from agrinerf_ns.row.report import RowSettings, assemble_row
from agrinerf_ns.row.segments import RowInputError, Segment, plan_segments, read_transforms
from agrinerf_ns.survey import stages as survey_stages

CONSOLE = Console()


@dataclass
class RowArgs(survey_stages.JobOptions):
    """Cut a long capture into overlapping segments, train and count each, and join them into one row's yield map."""

    out: Path
    """Row folder (outside --data and --raw, which are only read)."""
    data: Optional[Path] = None
    """A processed dataset of the whole capture (agrinerf-process), cut as it is."""
    raw: Optional[Path] = None
    """Instead of --data: a raw capture, processed once as a whole (one world frame for all segments) and then cut."""
    truth: Optional[Path] = None
    """A synthetic raw capture whose truth scores the row and its segments (default: --raw when it has a truth)."""
    segment_frames: int = 48
    """Frames per segment: 48, the views of the count profiles the count was measured on (docs/bench_profiles.md;
    3.6 m of row at the synthetic rig's 0.75 m/s and 10 frames/s)."""
    overlap_frames: int = 16
    """Frames neighbouring segments share (at least; the segments are spread evenly): a fruit in the overlap is
    seen by both from a third of a segment, and joined (--join-distance)."""
    join_distance: float = JOIN_DISTANCE
    """Two segments' fruit within this distance in their overlap are one fruit (metres; measured against the
    placement error of the tuning seeds: agrinerf_ns/row/join.py, results/row/README.md)."""
    bin_m: float = 1.0
    """Length of the bins of row_yield.csv (metres along the driven path)."""
    count_from: Literal["field", "bodies"] = "field"
    """``field``: each segment is trained and its run counted (``agrinerf-count --path auto``); ``bodies``: each
    segment's fruit bodies are counted with no training (``--path bodies``: the lit masks' fruit and the thermal
    bodies the data stage placed with the poses; seconds per segment, results/fruit-count-lit). With --raw and
    ``bodies`` the capture is processed with ``--fruit-mask-maker auto`` unless another maker is set."""


def _raw_frames(raw: Path) -> int:
    path = Path(raw) / "rgb" / "timestamps.txt"
    if not path.is_file():
        raise RowInputError(f"{path}: missing; --raw must be a raw capture folder (docs/formats.md)")
    return sum(1 for line in path.read_text().splitlines() if line.strip())


def check_inputs(args: RowArgs) -> Path:
    """The input folder (--data or --raw), checked before any work starts; raises :class:`RowInputError`."""
    if (args.data is None) == (args.raw is None):
        raise RowInputError("give exactly one of --data DATASET and --raw CAPTURE")
    source = Path(args.data if args.data is not None else args.raw)  # type: ignore[arg-type]
    if not source.is_dir():
        raise RowInputError(f"{source}: folder does not exist")
    if Path(args.out).resolve().is_relative_to(source.resolve()):
        raise RowInputError(f"{args.out}: the row folder lies inside the input {source} (read only)")
    if args.truth is not None and not (Path(args.truth) / FRUITS_JSON).is_file():
        raise RowInputError(f"{Path(args.truth) / FRUITS_JSON}: missing; --truth must be a synthetic capture")
    if not args.join_distance > 0 or not args.bin_m > 0:
        raise RowInputError(f"--join-distance and --bin-m must be positive, got {args.join_distance}, {args.bin_m}")
    if args.count_from == "bodies" and args.data is not None and not (source / FRUIT_BODIES).is_file():
        raise RowInputError(
            f"{source / FRUIT_BODIES}: missing; --count-from bodies counts the fruit bodies the data stage placed "
            "(agrinerf-process --fruit-mask-maker auto), or give --raw"
        )
    frames = len(read_transforms(source)["frames"]) if args.data is not None else _raw_frames(source)
    plan_segments(frames, args.segment_frames, args.overlap_frames)  # refuses a capture too short, before processing
    return source


def segment_jobs(args: RowArgs, dataset: Path, truth: Path, segments: List[Segment],
                 settings: survey_stages.SurveySettings) -> List[Job]:  # fmt: skip
    """Per segment, the steps without a record (cut, train, count), each after the one before it."""
    light, heavy = args.resources()
    jobs: List[Job] = []
    for segment in segments:
        folders = segment_steps.segment_folders(args.out, segment)
        steps: Dict[str, survey_stages.Step] = {
            "cut": (segment_steps.cut_step, (dataset, segment, folders), light, None)
        }
        if args.count_from == "bodies":
            steps["count"] = (segment_steps.bodies_count_step, (truth, folders, settings), light, None)
        else:
            steps["train"] = (survey_stages.train_step, (folders, settings), heavy, folders.train_log(settings.method))
            steps["count"] = (survey_stages.count_step, (truth, folders, settings), heavy, None)
        jobs += survey_stages.chained_jobs(segment.name, folders, steps, tuple(steps), args.retries)
    return jobs


def _run(jobs: List[Job], executor: Any, label: str, report: JobsReport) -> None:
    if not jobs:
        return
    part = run_jobs(jobs, executor, lambda job, result: None, label, CONSOLE)
    report.done.update(part.done)
    report.failed.update(part.failed)
    report.skipped.update(part.skipped)


def main(args: RowArgs) -> Optional[Dict[str, Any]]:
    """Run the row; returns its summary (None when a segment failed: see OUT/failures.md)."""
    source = check_inputs(args)
    truth = args.truth if args.truth is not None else (args.raw if args.raw is not None else source)
    process = args.process
    if args.count_from == "bodies" and process.fruit_mask_maker == "none":
        process = replace(process, fruit_mask_maker="auto")
    settings = args.settings(process)
    report = JobsReport()
    start = time.perf_counter()
    wall: Dict[str, float] = {}
    with driver_lock(args.out), executor_for(args.ray, **args.executor_options()) as ex:
        dataset = source
        if args.raw is not None:
            whole = segment_steps.capture_folders(args.out)
            dataset = whole.data
            if survey_stages.read_record(whole, "process") is None:
                light, _ = args.resources()
                job = Job("capture:process", survey_stages.process_step, (args.raw, whole, settings), whole.root,
                          light, (), None, args.retries)  # fmt: skip
                _run([job], ex, "row: process", report)
            record = survey_stages.read_record(whole, "process")
            if record is None:
                write_failures(args.out / "failures.md", failures_markdown(report, "Row steps that failed"))
                return None
            wall["process"] = record["wall_s"]
        frames = len(read_transforms(dataset)["frames"])
        segments = plan_segments(frames, args.segment_frames, args.overlap_frames)
        segment_steps.check_plan(args.out, segment_steps.plan_record(dataset, frames, args.segment_frames, args.overlap_frames,
                                                       segments, args.count_from))  # fmt: skip
        jobs_start = time.perf_counter()
        _run(segment_jobs(args, dataset, truth, segments, settings), ex, f"row: {len(segments)} segments", report)
        wall["segment jobs, this session"] = time.perf_counter() - jobs_start
        write_failures(args.out / "failures.md", failures_markdown(report, "Row steps that failed"))
        if report.failed or report.skipped:
            return None
        for stage in segment_steps.SEGMENT_STAGES if args.count_from == "field" else ("cut", "count"):
            times = [(survey_stages.read_record(segment_steps.segment_folders(args.out, s), stage) or {}).get("wall_s")
                     for s in segments]  # fmt: skip
            wall[f"{stage} (sum)"] = float(sum(t for t in times if t is not None))
        has_truth = (Path(truth) / FRUITS_JSON).is_file()
        row_settings = RowSettings(args.join_distance, args.bin_m, args.count)
        wall["driver before the join, this session"] = time.perf_counter() - start
        summary = assemble_row(args.out, dataset, segments, row_settings, truth if has_truth else None,
                               _header(args, len(segments)), wall)  # fmt: skip
    CONSOLE.print(f"row: {summary['fruit']} fruit -> {args.out / 'row'}", soft_wrap=True)
    return summary


def _header(args: RowArgs, segments: int) -> str:
    from agrinerf_ns.machine import machine_note

    source = args.data if args.data is not None else args.raw
    if args.count_from == "bodies":
        counted = "counted from its fruit bodies with no training (`agrinerf-count --path bodies`)"
    else:
        counted = (f"`{args.method}`, {args.steps} steps, counted by `agrinerf-count` ({args.count.detect.detector} "
                   f"on {args.count.detect.source})")  # fmt: skip
    return (
        f"# Row yield of {source}\n\nCommand: `agrinerf-row {' '.join(sys.argv[1:])}`\n\n{machine_note()}\n\n"
        f"{segments} segments of {args.segment_frames} frames overlapping by at least {args.overlap_frames}; each "
        f"{counted}; fruit joined across borders within {args.join_distance:g} m."
    )


def entrypoint() -> None:
    """Console script ``agrinerf-row``."""
    tyro.extras.set_accent_color("bright_yellow")
    try:
        summary = main(tyro.cli(RowArgs))
    except RowInputError as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)
        sys.exit(2)
    except FolderInUse as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)
        sys.exit(1)
    if summary is None:
        sys.exit(1)


if __name__ == "__main__":
    entrypoint()
