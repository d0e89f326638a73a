"""``agrinerf-survey --captures FOLDER --out OUT [--ray local|auto|ADDRESS]``: every raw capture of a farm processed,
trained and counted; one table.

Each sub-folder of FOLDER is a raw capture (docs/formats.md). For each, three jobs in order (process, train with the
chosen preset, count), run in this process one after another or as Ray tasks that hold the CPUs and GPUs they ask
for; captures run side by side. A capture that fails is reported with its error and the others finish. Running the
same command again resumes: finished steps are skipped (:mod:`agrinerf_ns.survey.stages`). Out: ``OUT/survey.md`` and
``OUT/survey.csv`` (fruit per capture with intervals, mean fruit temperature, against the truth of a synthetic capture,
status and wall time), ``OUT/failures.md`` and every capture's own outputs under ``OUT/captures/``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List

import tyro
from rich.console import Console

from agrinerf_ns.orchestrate.executors import executor_for
from agrinerf_ns.orchestrate.jobs import (
    FolderInUse,
    Job,
    driver_lock,
    failures_markdown,
    run_jobs,
    write_failures,
)
from agrinerf_ns.survey import stages, table

CONSOLE = Console()


@dataclass
class SurveyArgs(stages.JobOptions):
    """Process, train and count every raw capture of a folder; writes OUT/survey.md and OUT/survey.csv."""

    captures: Path
    """Folder of raw captures, one sub-folder each (read only)."""
    out: Path
    """Survey folder (outside --captures)."""


class SurveyInputError(ValueError):
    """The captures folder or the output folder cannot be used (said before any work starts)."""


def list_captures(captures: Path, out: Path) -> List[str]:
    """The capture folders' names, sorted; raises :class:`SurveyInputError` naming the folder when there are none or
    when OUT lies inside the captures folder (it is never written to)."""
    captures = Path(captures)
    if not captures.is_dir():
        raise SurveyInputError(f"{captures}: captures folder does not exist")
    if Path(out).resolve().is_relative_to(captures.resolve()):
        raise SurveyInputError(f"{out}: the survey folder lies inside the captures folder {captures} (read only)")
    names = sorted(p.name for p in captures.iterdir() if p.is_dir() and not p.name.startswith("."))
    if not names:
        raise SurveyInputError(f"{captures}: no capture folders in it (one sub-folder per raw capture)")
    return names


def survey_jobs(args: SurveyArgs, names: List[str], settings: stages.SurveySettings) -> List[Job]:
    """Per capture, the steps without a record, each after the one before it."""
    light, heavy = args.resources()
    jobs: List[Job] = []
    for name in names:
        raw, folders = args.captures / name, stages.capture_folders(args.out, name)
        steps: Dict[str, stages.Step] = {
            "process": (stages.process_step, (raw, folders, settings), light, None),
            "train": (stages.train_step, (folders, settings), heavy, folders.train_log(settings.method)),
            "count": (stages.count_step, (raw, folders, settings), heavy, None),
        }
        jobs += stages.chained_jobs(name, folders, steps, stages.STAGES, args.retries)
    return jobs


def main(args: SurveyArgs) -> List[Dict[str, Any]]:
    names = list_captures(args.captures, args.out)
    settings = args.settings()
    jobs = survey_jobs(args, names, settings)
    errors: Dict[str, str] = {}
    if jobs:
        with (
            driver_lock(args.out),
            executor_for(args.ray, **args.executor_options()) as executor,
        ):
            report = run_jobs(jobs, executor, lambda job, result: None, "survey steps", CONSOLE)
        errors = {key.rsplit(":", 1)[0]: failure.error for key, failure in report.failed.items()}
        write_failures(args.out / "failures.md", failures_markdown(report, "Survey steps that failed"))
    rows = table.survey_rows(names, {n: stages.capture_folders(args.out, n) for n in names}, errors)
    from agrinerf_ns.machine import machine_note

    header = (
        f"# Survey of {args.captures}\n\nCommand: `agrinerf-survey {' '.join(sys.argv[1:])}`\n\n{machine_note()}\n\n"
        f"Each capture: `{args.method}`, {args.steps} steps; fruit counted by `agrinerf-count` "
        f"({args.count.detect.detector} on {args.count.detect.source}); the interval is a delete-a-group jackknife over "
        f"{args.jackknife_groups} interleaved groups of views, the temperature's Student's t over the counted fruit; "
        "against the truth where the capture has one (synthetic captures). Wall time: each step's own.\n"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    table.write_csv(args.out / "survey.csv", rows)
    tmp = args.out / "survey.md.tmp"
    tmp.write_text(table.markdown(rows, header))
    tmp.replace(args.out / "survey.md")
    CONSOLE.print(f"survey: {args.out / 'survey.md'}, {args.out / 'survey.csv'}")
    return rows


def entrypoint() -> None:
    """Console script ``agrinerf-survey``."""
    tyro.extras.set_accent_color("bright_yellow")
    try:
        rows = main(tyro.cli(SurveyArgs))
    except SurveyInputError as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)
        sys.exit(2)
    except FolderInUse as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)
        sys.exit(1)
    if any(r["status"] != "done" for r in rows):
        sys.exit(1)


if __name__ == "__main__":
    entrypoint()
