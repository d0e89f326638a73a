"""``agrinerf-synth``: write a synthetic tri-modal raw capture (and optionally its contact sheet)."""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import tyro
from typing_extensions import Annotated

from agrinerf_ns.synth.config import SynthConfig, SynthConfigError, views_for_row


@dataclass
class SynthCommand:
    """Generate a synthetic orchard/garden capture: RGB cam0, thermal cam1, event cam2, calibration, odometry, truth.

    The tiny test scene is ``--views 8 --width 64 --height 48 --heldout 2 --event-substeps 4``.
    """

    out: Path
    """Output folder (must be absent or empty); written atomically."""
    config: Annotated[SynthConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=SynthConfig)
    row_length_m: Optional[float] = None
    """Drive this many metres of row instead of ``--views`` frames: the frames it takes at ``--speed`` and ``--fps``
    (the same plants, seeded by their place along the row, and the same truth files; docs/synth.md, Long rows)."""
    preview: bool = False
    """Also write a contact sheet PNG (RGB / RGB truth / thermal / events for a few frames)."""
    preview_path: Optional[Path] = None
    """Where the contact sheet goes; default OUT/preview.png."""
    preview_rows: int = 4
    """Frames shown in the contact sheet."""


def run(cmd: SynthCommand) -> Path:
    """Generate the capture of ``cmd`` (and its preview); returns the capture folder."""
    from rich.console import Console

    from agrinerf_ns.synth.capture import generate_capture
    from agrinerf_ns.synth.preview import contact_sheet

    console = Console(stderr=True)
    start = time.perf_counter()
    config = cmd.config
    if cmd.row_length_m is not None:
        config = config.replace(views=views_for_row(cmd.row_length_m, config.speed, config.fps))
    out = generate_capture(config, cmd.out, progress=True)
    console.print(f"[green]wrote[/green] {out} in {time.perf_counter() - start:.1f} s")
    if cmd.preview:
        sheet = contact_sheet(out, cmd.preview_path or out / "preview.png", rows=cmd.preview_rows)
        console.print(f"[green]preview[/green] {sheet}")
    return out


def entrypoint() -> None:
    """Console script entry point."""
    try:
        run(tyro.cli(SynthCommand))
    except SynthConfigError as err:
        print(f"agrinerf-synth: error: {err}", file=sys.stderr)
        sys.exit(2)


if __name__ == "__main__":
    entrypoint()
