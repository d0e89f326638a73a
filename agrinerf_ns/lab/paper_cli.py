"""``agrinerf-detect``: downstream fruit detection on rendered views (paper Tables III and IV).

Subcommands: ``evaluate`` (the whole benchmark from a plan file), ``render`` (held-out views of one run), ``train``
(a detector on a scene's truth), ``score`` (a folder of renders against the true boxes) and ``table`` (one table from
several evaluations). ``render``, ``train``, ``score`` and ``fruit`` are the detector's own (:mod:`agrinerf_ns.detect.cli`);
``evaluate`` and ``table`` are the paper tables' harness, here. Needs the optional ``[detect]`` extra (Ultralytics,
AGPL-3.0) for everything but ``render`` and ``fruit``.
"""

from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import List, Literal, Optional

import tyro
from typing_extensions import Annotated

from agrinerf_ns.detect import cli as detect_cli
from agrinerf_ns.detect.settings import EvalSettings


@dataclass
class EvaluateCommand:
    """Render, train detectors, detect and score every method of every scene in a plan; write the tables + picture.

    Plan (JSON): {"scenes": [{"name": "orchard", "lighting": "dark", "raw": RAW, "dataset": DATASET,
    "methods": [{"label": "Nerfacto (RGB)", "config": ".../config.yml", "output": "rgb"},
    {"label": "Nerfacto (Thermal)", "config": ..., "output": "rgb", "detector": "thermal"},
    {"label": "Ours (Cross-Spectral)", "config": ..., "output": "thermal"}]}]}. A method may give "renders" (a folder of
    <frame>.png held-out views) instead of "config".
    """

    out: Path
    """Output folder: table_<iii|iv>.md/.csv, metrics.json, detections.png, work/ (renders, YOLO sets, detectors)."""
    plan: Optional[Path] = None
    """Plan JSON (see above)."""
    bench: Optional[Path] = None
    """Or: an agrinerf-bench output folder (all its finished runs; agrinerf gives an RGB and a cross-spectral row)."""
    table: Literal["III", "IV"] = "III"
    """Table III (methods x lighting) or IV (modality ablations of one scene)."""
    settings: Annotated[EvalSettings, tyro.conf.arg(name="")] = field(default_factory=EvalSettings)
    """Evaluation settings (agrinerf_ns.detect.settings.EvalSettings)."""

    def main(self) -> None:
        from rich.console import Console

        from agrinerf_ns.lab.paper_eval import evaluate_plan
        from agrinerf_ns.lab.paper_plan import load_plan, plan_from_bench

        if (self.plan is None) == (self.bench is None):
            raise ValueError("give exactly one of --plan PLAN.json or --bench AGRINERF_BENCH_OUT")
        if self.plan is not None:
            scenes = load_plan(self.plan)
        else:
            scenes = plan_from_bench(self.bench, self.table)  # type: ignore[arg-type]
        command = "agrinerf-detect " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        written = evaluate_plan(scenes, self.out, self.settings, self.table, command)
        console = Console()
        console.print(written["markdown"].read_text())
        for kind, path in written.items():
            console.print(f"[green]wrote[/green] {kind}: {path}")


@dataclass
class TableCommand:
    """One table from several evaluations (e.g. one per lighting): their metrics.json files, scored alike."""

    metrics: List[Path]
    """metrics.json files written by agrinerf-detect evaluate."""
    out: Path
    """Output folder for table_<iii|iv>.md/.csv."""
    table: Literal["III", "IV"] = "III"

    def main(self) -> None:
        from agrinerf_ns.lab.paper_merge import merge_evaluations

        command = "agrinerf-detect " + " ".join(shlex.quote(a) for a in sys.argv[1:])
        md, csv_path = merge_evaluations(self.metrics, self.out, self.table, command)
        print(md.read_text())
        print(f"wrote {md} and {csv_path}")


COMMANDS = {
    "evaluate": EvaluateCommand,
    **detect_cli.COMMANDS,
    "table": TableCommand,
}


def entrypoint(args: Optional[List[str]] = None) -> None:
    """Console script entry point: errors in the input are reported in one line, exit status 2."""
    detect_cli.entrypoint(args, COMMANDS, __doc__)


if __name__ == "__main__":
    entrypoint()
