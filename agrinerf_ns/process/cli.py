"""``agrinerf-process --raw RAW --out DATASET [options]``: raw capture folder -> tri-modal dataset."""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import tyro

from agrinerf_ns.process.capture_to_dataset import CONSOLE, ProcessConfig, process_capture
from agrinerf_ns.process.errors import RawInputError


@dataclass
class ProcessArgs:
    """Turn a raw capture folder (docs/formats.md) into a dataset for Nerfstudio and AgriNeRF."""

    raw: Path
    """Raw capture folder (read only)."""
    out: Path
    """Dataset folder to write (written to a temporary sibling, then renamed into place)."""
    config: Annotated[ProcessConfig, tyro.conf.arg(name="")] = field(default_factory=ProcessConfig)
    """Processing options."""


def main(args: ProcessArgs) -> Path:
    try:
        return process_capture(args.raw, args.out, args.config)
    except (RawInputError, FileExistsError, ValueError) as err:
        CONSOLE.print(f"[bold red]Error:[/bold red] {err}", soft_wrap=True)  # never break a path across lines
        sys.exit(2)


def entrypoint() -> None:
    """Console script entry point."""
    tyro.extras.set_accent_color("bright_yellow")
    main(tyro.cli(ProcessArgs))


if __name__ == "__main__":
    entrypoint()
