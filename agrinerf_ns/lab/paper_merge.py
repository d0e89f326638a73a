"""One Table III (or IV) from several evaluations' ``metrics.json`` (e.g. one lighting at a time)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

from agrinerf_ns.detect.bootstrap import MatchedImages
from agrinerf_ns.detect.box_metrics import DetectionMetrics
from agrinerf_ns.lab.paper_tables import ResultRow, machine_note, write_tables

MERGE_FREE_SETTINGS = ("reuse", "detectors_from", "rays_per_chunk")
"""Settings that may differ between evaluations merged into one table (they change where results come from or how
fast, not how they are scored)."""


def result_row(record: Dict[str, Any]) -> ResultRow:
    """A row of ``metrics.json``'s "results" (its matched detections, where written, give the intervals)."""
    fields = {k: record[k] for k in DetectionMetrics.__dataclass_fields__}
    images = record.get("images")
    matched = None if images is None else MatchedImages.from_json(images)
    return ResultRow(
        record["scene"], record["lighting"], record["method"], DetectionMetrics(**fields), record.get("step"), matched
    )


def merge_evaluations(metrics_files: List[Path], out: Path, table: str, command: str) -> Tuple[Path, Path]:
    """One Table III (or IV) from several evaluations' ``metrics.json`` (e.g. one per lighting, run at different
    times): refused when they were scored with different settings or give the same (scene, lighting, method) twice.
    The footer lists each evaluation's command."""
    rows: List[ResultRow] = []
    reference: Optional[Dict[str, object]] = None
    commands = []
    for path in metrics_files:
        data = json.loads(Path(path).read_text())
        settings = {k: v for k, v in data["settings"].items() if k not in MERGE_FREE_SETTINGS}
        if reference is None:
            reference = settings
        elif settings != reference:
            changed = sorted(k for k in set(settings) | set(reference) if settings.get(k) != reference.get(k))
            raise ValueError(f"{path}: scored with other settings than {metrics_files[0]} ({', '.join(changed)})")
        commands.append(f"`{data['command']}`")
        rows += [result_row(r) for r in data["results"]]
    keys = [(r.scene, r.lighting, r.method) for r in rows]
    repeated = sorted({k for k in keys if keys.count(k) > 1})
    if repeated:
        raise ValueError(f"the evaluations give these rows more than once: {repeated}")
    footer = machine_note(command) + "  \nMerged from: " + "; ".join(commands) + "."
    return write_tables(rows, out, table, f"table_{table.lower()}", footer=footer)
