"""Markdown + CSV writers for the paper's Table III (methods x lighting) and Table IV (modality ablations).

Rows that carry their matched detections (:class:`~agrinerf_ns.detect.bootstrap.MatchedImages`) get bootstrap 95%
intervals for mAP50 and mAP50-95 ("17.3 [12.1, 22.0]"), and each scene's rows a list of paired differences, marked
where the interval excludes 0.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

from agrinerf_ns.detect.bootstrap import (
    BOOTSTRAP_RESAMPLES,
    BOOTSTRAP_SEED,
    BootstrapMaps,
    Interval,
    MatchedImages,
    bootstrap_maps,
)
from agrinerf_ns.detect.box_metrics import DetectionMetrics, metrics_table_row

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
    matched: Optional[MatchedImages] = None
    """Its detections matched per image (None: no intervals, e.g. a metrics.json written before they existed)."""

    def bootstrap(self) -> Optional[BootstrapMaps]:
        """mAPs of the resampled images (seeded: rows scored on the same frames are paired)."""
        return None if self.matched is None else bootstrap_maps(self.matched)


INTERVALS_NOTE = (
    f"In brackets: 95% bootstrap intervals (percentile; {BOOTSTRAP_RESAMPLES} resamples of the held-out images with "
    f"replacement, seed {BOOTSTRAP_SEED}, the same resamples for every row of a scene)."
)


def _csv_fields(row: ResultRow, maps: Optional[BootstrapMaps] = None) -> Dict[str, object]:
    m = row.metrics
    ci50, ci50_95 = maps.intervals() if maps is not None else (None, None)
    return {
        "scene": row.scene,
        "lighting": row.lighting,
        "method": row.method,
        "map50": f"{m.map50:.6f}",
        "map50_low": "" if ci50 is None else f"{ci50.low:.6f}",
        "map50_high": "" if ci50 is None else f"{ci50.high:.6f}",
        "map50_95": f"{m.map50_95:.6f}",
        "map50_95_low": "" if ci50_95 is None else f"{ci50_95.low:.6f}",
        "map50_95_high": "" if ci50_95 is None else f"{ci50_95.high:.6f}",
        "precision": f"{m.precision:.6f}",
        "recall": f"{m.recall:.6f}",
        "f1": f"{m.f1:.6f}",
        "conf_threshold": m.conf_threshold,
        "num_images": m.num_images,
        "num_true": m.num_true,
        "num_pred": m.num_pred,
        "step": "" if row.step is None else row.step,
    }


Bootstraps = Sequence[Optional[BootstrapMaps]]
"""Each row's :meth:`ResultRow.bootstrap`, in the order of the rows."""


def bootstraps(rows: Sequence[ResultRow]) -> List[Optional[BootstrapMaps]]:
    return [row.bootstrap() for row in rows]


def write_csv(rows: Sequence[ResultRow], path: Path, maps: Optional[Bootstraps] = None) -> Path:
    """All numbers unrounded (mAPs as fractions, with their interval where known), one line per (scene, method)."""
    if not rows:
        raise ValueError(f"{path}: no results to write")
    maps = bootstraps(rows) if maps is None else maps
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(_csv_fields(rows[0], maps[0])))
        writer.writeheader()
        writer.writerows(_csv_fields(r, m) for r, m in zip(rows, maps, strict=True))
    return path


def _bold_best(cells: List[List[str]], values: List[List[float]]) -> None:
    """Bold the best value of each metric column (ties for best all bold; NaN ignored; nothing when all are equal).
    Only the point estimate is bold, not its interval."""
    for col in range(len(METRIC_HEADERS)):
        column = [v[col] for v in values]
        finite = [v for v in column if v == v]
        if len(set(finite)) < 2:
            continue
        best = max(finite)
        for row_cells, value in zip(cells, column, strict=True):
            if value == best:
                point, _, interval = row_cells[col].partition(" ")
                row_cells[col] = f"**{point}**" + (f" {interval}" if interval else "")


def _metric_values(m: DetectionMetrics) -> List[float]:
    """The values as printed (so that "best" is judged on what the reader sees)."""
    return [
        round(100 * m.map50, 1),
        round(100 * m.map50_95, 1),
        round(m.precision, 3),
        round(m.recall, 3),
        round(m.f1, 3),
    ]


def _cells(row: ResultRow, maps: Optional[BootstrapMaps]) -> List[str]:
    """The printed metrics; mAPs with their interval where known."""
    cells = metrics_table_row(row.metrics)
    if maps is not None:
        cells[0], cells[1] = (interval.format() for interval in maps.intervals())
    return cells


def paired_differences(rows: Sequence[ResultRow], maps: Bootstraps) -> List[str]:
    """One line per pair of rows of a scene scored on the same frames, higher mAP50 first: the paired bootstrap
    difference of mAP50 and of mAP50-95 (x100) with its 95% interval, "*" where it excludes 0."""
    lines = []
    ranked = sorted(
        ((r, m) for r, m in zip(rows, maps, strict=True) if m is not None), key=lambda rm: -rm[0].metrics.map50
    )
    for i, (a, maps_a) in enumerate(ranked):
        for b, maps_b in ranked[i + 1 :]:
            if maps_a.frames != maps_b.frames:
                lines.append(f"- {a.method} - {b.method}: not paired (scored on different views)")
                continue
            d50, d50_95 = maps_a.minus(maps_b)
            lines.append(f"- {a.method} - {b.method}: mAP50 {_difference(d50)}, mAP50-95 {_difference(d50_95)}")
    return lines


def _difference(interval: Interval) -> str:
    return interval.format(signed=True) + ("*" if interval.significant() else "")


def _differences_block(groups: List[Tuple[str, List[ResultRow], List[Optional[BootstrapMaps]]]]) -> List[str]:
    """The notes under a table: what the brackets are, and each scene's paired differences."""
    if not any(m is not None for _, _, maps in groups for m in maps):
        return []
    lines = ["", INTERVALS_NOTE, "", "Paired differences (x100; * where the 95% interval excludes 0):"]
    for title, rows, maps in groups:
        pairs = paired_differences(rows, maps)
        if pairs:
            lines += ["", f"{title}:", *pairs]
    return lines


def table_iii_markdown(
    rows: Sequence[ResultRow], footer: Optional[str] = None, maps: Optional[Bootstraps] = None
) -> str:
    """Table III: per scene (lighting), each method's mAP50, mAP50-95 (x100), precision, recall, F1; best in bold;
    bootstrap intervals and paired differences where the rows carry their matched detections."""
    maps = bootstraps(rows) if maps is None else maps
    lines = [
        "| Scene | Method | " + " | ".join(METRIC_HEADERS) + " | Lighting |",
        "|---|---|" + "---:|" * len(METRIC_HEADERS) + "---|",
    ]
    groups = []
    for scene, members in _group(list(zip(rows, maps, strict=True)), lambda rm: (rm[0].scene, rm[0].lighting)):
        group = [r for r, _ in members]
        group_maps = [m for _, m in members]
        cells = [_cells(r, m) for r, m in members]
        _bold_best(cells, [_metric_values(r.metrics) for r in group])
        for i, (row, row_cells) in enumerate(zip(group, cells, strict=True)):
            first = i == 0
            lines.append(
                f"| {scene[0] if first else ''} | {row.method} | "
                + " | ".join(row_cells)
                + f" | {scene[1] if first else ''} |"
            )
        groups.append((f"{scene[0]} ({scene[1]})", group, group_maps))
    lines += _differences_block(groups)
    if footer:
        lines += ["", footer]
    return "\n".join(lines) + "\n"


def table_iv_markdown(
    rows: Sequence[ResultRow], footer: Optional[str] = None, maps: Optional[Bootstraps] = None
) -> str:
    """Table IV: modality ablations of one scene, in the paper's row order; best in bold; intervals and paired
    differences as in Table III."""
    scenes = {(r.scene, r.lighting) for r in rows}
    if len(scenes) != 1:
        raise ValueError(f"Table IV is one scene's ablation; got {len(scenes)} scenes: {sorted(scenes)}")
    maps = bootstraps(rows) if maps is None else maps
    order = {label: i for i, label in enumerate(TABLE_IV_ORDER)}
    ordered = sorted(zip(rows, maps, strict=True), key=lambda rm: order.get(rm[0].method, len(order)))
    cells = [_cells(r, m) for r, m in ordered]
    _bold_best(cells, [_metric_values(r.metrics) for r, _ in ordered])
    scene, lighting = next(iter(scenes))
    lines = [
        f"Scene: {scene} ({lighting})",
        "",
        "| Method | " + " | ".join(METRIC_HEADERS) + " |",
        "|---|" + "---:|" * len(METRIC_HEADERS),
    ]
    lines += [f"| {r.method} | " + " | ".join(c) + " |" for (r, _), c in zip(ordered, cells, strict=True)]
    lines += _differences_block([(f"{scene} ({lighting})", [r for r, _ in ordered], [m for _, m in ordered])])
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
    maps = bootstraps(rows)
    markdown = table_iii_markdown(rows, footer, maps) if kind == "III" else table_iv_markdown(rows, footer, maps)
    md_path = out_dir / f"{stem}.md"
    md_path.write_text(markdown)
    return md_path, write_csv(rows, out_dir / f"{stem}.csv", maps)


def machine_note(command: str) -> str:
    """Footer for the tables: the command and the machine (:func:`agrinerf_ns.machine.machine_note`)."""
    from agrinerf_ns.machine import machine_note as machine

    try:
        import ultralytics

        yolo = ultralytics.__version__
    except ImportError:  # pragma: no cover - the detector needs it anyway
        yolo = "absent"
    return (
        f"Command: `{command}`  \n{machine()}, ultralytics {yolo}. "
        "mAPs x100, COCO 101-point interpolation; precision/recall/F1 at IoU 0.5."
    )


def _group(rows: Sequence, key) -> List[Tuple[Tuple[str, str], List]]:
    groups: Dict[Tuple[str, str], List] = {}
    for row in rows:
        groups.setdefault(key(row), []).append(row)
    return list(groups.items())
