"""Markdown + CSV writers for the paper's Table III (methods x lighting) and Table IV (modality ablations)."""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from agrinerf_ns.detect.scoring import DetectionMetrics, metrics_table_row

METRIC_HEADERS = ["mAP50", "mAP50-95", "Precision", "Recall", "F1-Score"]
TABLE_IV_ORDER = (
    "Ours (RGB)",
    "Ours (RGB+Events)",
    "Ours (RGB+Thermal)",
    "Ours (Thermal)",
    "Ours (Thermal+Events)",
    "Ours (All)",
)
"""Row order of the paper's Table IV (other labels follow in the given order)."""


@dataclass(frozen=True)
class ResultRow:
    """One scored (scene, method) pair."""

    scene: str
    lighting: str
    method: str
    metrics: DetectionMetrics
    step: Optional[int] = None
    """Training step of the rendered checkpoint (None for a folder of renders without renders.json)."""


def _csv_fields(row: ResultRow) -> Dict[str, object]:
    m = row.metrics
    return {
        "scene": row.scene,
        "lighting": row.lighting,
        "method": row.method,
        "map50": f"{m.map50:.6f}",
        "map50_95": f"{m.map50_95:.6f}",
        "precision": f"{m.precision:.6f}",
        "recall": f"{m.recall:.6f}",
        "f1": f"{m.f1:.6f}",
        "conf_threshold": m.conf_threshold,
        "num_images": m.num_images,
        "num_true": m.num_true,
        "num_pred": m.num_pred,
        "step": "" if row.step is None else row.step,
    }


def write_csv(rows: Sequence[ResultRow], path: Path) -> Path:
    """All numbers unrounded (mAPs as fractions), one line per (scene, method)."""
    if not rows:
        raise ValueError(f"{path}: no results to write")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(_csv_fields(rows[0])))
        writer.writeheader()
        writer.writerows(_csv_fields(r) for r in rows)
    return path


def _bold_best(cells: List[List[str]], values: List[List[float]]) -> None:
    """Bold the best value of each metric column (ties for best all bold; NaN ignored; nothing when all are equal)."""
    for col in range(len(METRIC_HEADERS)):
        column = [v[col] for v in values]
        finite = [v for v in column if v == v]
        if len(set(finite)) < 2:
            continue
        best = max(finite)
        for row_cells, value in zip(cells, column, strict=True):
            if value == best:
                row_cells[col] = f"**{row_cells[col]}**"


def _metric_values(m: DetectionMetrics) -> List[float]:
    """The values as printed (so that "best" is judged on what the reader sees)."""
    return [
        round(100 * m.map50, 1),
        round(100 * m.map50_95, 1),
        round(m.precision, 3),
        round(m.recall, 3),
        round(m.f1, 3),
    ]


def table_iii_markdown(rows: Sequence[ResultRow], footer: Optional[str] = None) -> str:
    """Table III: per scene (lighting), each method's mAP50, mAP50-95 (x100), precision, recall, F1; best in bold."""
    lines = [
        "| Scene | Method | " + " | ".join(METRIC_HEADERS) + " | Lighting |",
        "|---|---|" + "---:|" * len(METRIC_HEADERS) + "---|",
    ]
    for scene, group in _group(rows, lambda r: (r.scene, r.lighting)):
        cells = [metrics_table_row(r.metrics) for r in group]
        _bold_best(cells, [_metric_values(r.metrics) for r in group])
        for i, (row, row_cells) in enumerate(zip(group, cells, strict=True)):
            first = i == 0
            lines.append(
                f"| {scene[0] if first else ''} | {row.method} | "
                + " | ".join(row_cells)
                + f" | {scene[1] if first else ''} |"
            )
    if footer:
        lines += ["", footer]
    return "\n".join(lines) + "\n"


def table_iv_markdown(rows: Sequence[ResultRow], footer: Optional[str] = None) -> str:
    """Table IV: modality ablations of one scene, in the paper's row order; best in bold."""
    scenes = {(r.scene, r.lighting) for r in rows}
    if len(scenes) != 1:
        raise ValueError(f"Table IV is one scene's ablation; got {len(scenes)} scenes: {sorted(scenes)}")
    order = {label: i for i, label in enumerate(TABLE_IV_ORDER)}
    ordered = sorted(rows, key=lambda r: order.get(r.method, len(order)))
    cells = [metrics_table_row(r.metrics) for r in ordered]
    _bold_best(cells, [_metric_values(r.metrics) for r in ordered])
    scene, lighting = next(iter(scenes))
    lines = [
        f"Scene: {scene} ({lighting})",
        "",
        "| Method | " + " | ".join(METRIC_HEADERS) + " |",
        "|---|" + "---:|" * len(METRIC_HEADERS),
    ]
    lines += [f"| {r.method} | " + " | ".join(c) + " |" for r, c in zip(ordered, cells, strict=True)]
    if footer:
        lines += ["", footer]
    return "\n".join(lines) + "\n"


def write_tables(
    rows: Sequence[ResultRow], out_dir: Path, kind: str, stem: str, footer: Optional[str] = None
) -> Tuple[Path, Path]:
    """Write ``<stem>.md`` (Table III or IV form, ``kind`` "III"/"IV") and ``<stem>.csv``; returns both paths."""
    if kind not in ("III", "IV"):
        raise ValueError(f"unknown table kind {kind!r}: use 'III' or 'IV'")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    markdown = table_iii_markdown(rows, footer) if kind == "III" else table_iv_markdown(rows, footer)
    md_path = out_dir / f"{stem}.md"
    md_path.write_text(markdown)
    return md_path, write_csv(rows, out_dir / f"{stem}.csv")


def _group(rows: Sequence[ResultRow], key) -> List[Tuple[Tuple[str, str], List[ResultRow]]]:
    groups: Dict[Tuple[str, str], List[ResultRow]] = {}
    for row in rows:
        groups.setdefault(key(row), []).append(row)
    return list(groups.items())
