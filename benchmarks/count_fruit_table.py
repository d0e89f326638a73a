"""Count scores of trained runs and their oracles, pooled over runs with bootstrap 95% intervals (#49).

``python benchmarks/count_fruit_table.py --counts LABEL=COUNT_DIR... --out results/NAME`` reads each
``agrinerf-count`` folder's ``count.json`` (written with ``--truth``), takes the scene, lighting and seed from the truth's
``truth/scene.json`` and writes ``counts.csv`` (one row per folder), ``summary.csv`` and ``counts.md``: per lighting and row kind the
mean over the runs of the reporting seeds (``--reporting-from``: seeds at or above it; the others are tuning seeds,
listed apart and never pooled) with an interval that resamples the runs. ``LABEL`` names the row's kind (the
trained configuration, or an oracle: ``python -m agrinerf_ns.lab.count_oracle``, the counting on perfect renders);
folders of one label and lighting are pooled.
"""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Sequence

import tyro

from agrinerf_ns.lab.count_tables import bootstrap_mean

TIERS = ("visible", "countable", "well_seen")
"""The tiers of truth (``agrinerf_ns.count.fruit_score.TIERS``)."""
LOOSE = ("0.1", "0.15")
"""The looser match distances (metres) of count.json's ``tiers``, beside the count's own 0.05 m."""
MEASURES = ("f1", "precision", "recall", "count_error", "f1_countable", "recall_countable", "count_error_countable",
            "f1_well_seen", "recall_well_seen", "count_error_well_seen", "mean_temperature_error",
            *(f"f1{'' if t == 'visible' else '_' + t}@{d}" for t in TIERS for d in LOOSE))  # fmt: skip
COLUMNS = ("scene", "lighting", "seed", "role", "label", "counted", "visible", "countable", "well_seen", *MEASURES,
           "folder")  # fmt: skip


@dataclass
class TableArgs:
    counts: List[str]
    """LABEL=FOLDER: agrinerf-count output folders (each with count.json written against a truth) and their row's
    label."""
    out: Path
    """Folder for counts.csv and counts.md."""
    reporting_from: int = 100
    """Seeds at or above this are reporting seeds; the others tuning seeds."""


def read_row(label: str, folder: Path, reporting_from: int) -> Dict[str, object]:
    """One table row from an agrinerf-count folder; ValueError naming the file when it has no score."""
    path = folder / "count.json"
    report = json.loads(path.read_text())
    if "score" not in report or "truth" not in report:
        raise ValueError(f"{path}: no score; count with --truth RAW")
    truth = Path(report["truth"])
    if not truth.is_absolute():  # counts written before count.json resolved it: relative to where they ran
        truth = folder.resolve().parent / truth
    scene = json.loads((truth / "truth" / "scene.json").read_text())["config"]
    score = dict(report["score"])
    for tier in TIERS:  # the looser match distances (counts written before the tiers: NaN)
        for distance in LOOSE:
            entry = report.get("tiers", {}).get(tier, {}).get(distance, {})
            score[f"f1{'' if tier == 'visible' else '_' + tier}@{distance}"] = entry.get("f1", float("nan"))
    return {
        "scene": scene["scene"],
        "lighting": scene["lighting"],
        "seed": int(scene["seed"]),
        "role": "reporting" if int(scene["seed"]) >= reporting_from else "tuning",
        "label": label,
        **{k: score.get(k, float("nan")) for k in ("counted", "visible", "countable", "well_seen", *MEASURES)},
        "folder": str(folder),
    }


ANCHORS = (
    "Published anchors, each at its own match rule and on trees seen from all sides (this rig sees one side of a "
    "row): FruitNeRF (Meyer et al. 2024) F1 0.95 on synthetic trees with true masks and 0.88 with SAM masks, a "
    "counted fruit matched within 0.15 of Nerfstudio's normalised units (tens of centimetres on its trees); "
    "FruitNeRF++ 0.93 synthetic and 0.77 on a real apple row; Fuji-SfM 0.88. Compare them with the 0.15 m columns."
)
"""The field's published counts, beside every table (their figures as their papers give them)."""


def _fmt(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


SHOWN = ("f1_countable", "f1_countable@0.1", "f1_countable@0.15", "count_error_countable", "f1", "f1_well_seen",
         "count_error", "count_error_well_seen", "mean_temperature_error")  # fmt: skip
"""The pooled table's columns: the countable tier (the targets') at 0.05, 0.10 and 0.15 m first."""


def _groups(rows: Sequence[Dict[str, object]]) -> Dict[tuple, List[Dict[str, object]]]:
    groups: Dict[tuple, List[Dict[str, object]]] = defaultdict(list)
    for row in rows:
        groups[(row["lighting"], row["role"], row["label"])].append(row)
    return dict(sorted(groups.items(), key=lambda kv: [str(k) for k in kv[0]]))


def summary(rows: Sequence[Dict[str, object]]) -> List[Dict[str, object]]:
    """Per lighting, role and label: the runs, and each measure's mean over them with its bootstrap interval."""
    out: List[Dict[str, object]] = []
    for (lighting, role, label), members in _groups(rows).items():
        row: Dict[str, object] = {"lighting": lighting, "role": role, "label": label, "runs": len(members)}
        for measure in MEASURES:
            interval = bootstrap_mean([float(m[measure]) for m in members])  # type: ignore[arg-type]
            row |= {measure: interval.value, f"{measure}_low": interval.low, f"{measure}_high": interval.high}
        out.append(row)
    return out


def markdown(rows: Sequence[Dict[str, object]]) -> str:
    """Per lighting, role and kind: the mean of each measure over the runs and its bootstrap interval; then all rows."""
    shown = SHOWN
    lines = ["| lighting | seeds | row | runs (scene:seed) | " + " | ".join(shown) + " |",
             "|---|---|---|---|" + "---|" * len(shown)]  # fmt: skip
    for (lighting, role, label), members in _groups(rows).items():
        cells = []
        for measure in shown:
            interval = bootstrap_mean([float(m[measure]) for m in members])  # type: ignore[arg-type]
            cells.append("-" if math.isnan(interval.value) else
                         f"{interval.value:.2f} [{interval.low:.2f}, {interval.high:.2f}]")  # fmt: skip
        runs = ", ".join(f"{m['scene']}:{m['seed']}" for m in members)
        lines.append(f"| {lighting} | {role} | {label} | {runs} | " + " | ".join(cells) + " |")
    lines += ["", ANCHORS, "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(_fmt(row[c]) for c in COLUMNS) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def main(args: TableArgs) -> List[Dict[str, object]]:
    pairs = [item.split("=", 1) for item in args.counts]
    bad = [item for item, pair in zip(args.counts, pairs, strict=True) if len(pair) != 2]
    if bad:
        raise SystemExit(f"--counts takes LABEL=FOLDER, got {bad}")
    rows = [read_row(label, Path(folder), args.reporting_from) for label, folder in pairs]
    args.out.mkdir(parents=True, exist_ok=True)
    with (args.out / "counts.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    pooled = summary(rows)
    with (args.out / "summary.csv").open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(pooled[0]))
        writer.writeheader()
        writer.writerows({k: _fmt(v) for k, v in row.items()} for row in pooled)
    (args.out / "counts.md").write_text(markdown(rows))
    print((args.out / "counts.md").read_text())
    return rows


if __name__ == "__main__":
    main(tyro.cli(TableArgs))
