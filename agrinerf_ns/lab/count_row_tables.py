"""The count tables read from ``agrinerf-count`` folders (each ``count.json`` written with ``--truth``): one row per
folder, its scene, lighting and seed from the truth's ``truth/scene.json``, and the tiers of truth at 0.05, 0.10 and
0.15 m. ``benchmarks/count_fruit_table.py`` pools any such folders per lighting; ``agrinerf-bench --profile count``
writes the seeds-by-lightings table of its row counts (:func:`write_bench_tables`, ``OUT/counts.md``)."""

from __future__ import annotations

import csv
import json
import math
from collections import defaultdict
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

import numpy as np

from agrinerf_ns.lab.count_tables import bootstrap_mean

TIERS = ("visible", "countable", "well_seen")
"""The tiers of truth (``agrinerf_ns.count.fruit_score.TIERS``)."""
LOOSE = ("0.1", "0.15")
"""The looser match distances (metres) of count.json's ``tiers``, beside the count's own 0.05 m."""
MEASURES = ("f1", "precision", "recall", "count_error", "f1_countable", "recall_countable", "count_error_countable",
            "f1_well_seen", "recall_well_seen", "count_error_well_seen", "mean_temperature_error",
            *(f"f1{'' if t == 'visible' else '_' + t}@{d}" for t in TIERS for d in LOOSE))  # fmt: skip
COLUMNS = ("scene", "lighting", "seed", "role", "label", "max_range", "counted", "visible", "countable", "well_seen",
           *MEASURES, "folder")  # fmt: skip
Row = Dict[str, object]

ANCHORS = (
    "Published anchors, each at its own match rule and on trees seen from all sides (this rig sees one side of a "
    "row): FruitNeRF (Meyer et al. 2024) F1 0.95 on synthetic trees with true masks and 0.88 with SAM masks, a "
    "counted fruit matched within 0.15 of Nerfstudio's normalised units (tens of centimetres on its trees); "
    "FruitNeRF++ (Meyer et al. 2025) 0.93 on synthetic trees and 0.77 on a real apple row (the Fuji-SfM row and its "
    "annotated fruit), by its paper's own match rule, not restated here (not yet checked against the paper); "
    "Fuji-SfM 0.88. Compare them with the 0.15 m columns."
)
"""The field's published counts, beside every table (their figures as their papers give them)."""


def read_row(label: str, folder: Path, reporting_from: int, truth: Optional[Path] = None) -> Row:
    """One table row from an agrinerf-count folder; ValueError naming the file when it has no score. ``truth``: the
    raw capture it was scored against (None: the one count.json names)."""
    path = folder / "count.json"
    report = json.loads(path.read_text())
    if "score" not in report or "truth" not in report:
        raise ValueError(f"{path}: no score; count with --truth RAW")
    if truth is None:
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
        "max_range": "-" if report.get("max_range") is None else float(report["max_range"]),
        **{k: score.get(k, float("nan")) for k in ("counted", "visible", "countable", "well_seen", *MEASURES)},
        "folder": str(folder),
    }


def fmt(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)


def write_rows(path: Path, rows: Sequence[Row], columns: Sequence[str]) -> None:
    """A CSV of ``rows`` (floats to 3 decimals where ``fmt`` gives them)."""
    with path.open("w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=list(columns))
        writer.writeheader()
        writer.writerows({k: (fmt(v) if isinstance(v, float) else v) for k, v in row.items()} for row in rows)


LIGHTING_ORDER = {name: i for i, name in enumerate(("bright", "shadowed", "dusk", "dark"))}
SEED_COLUMNS: Tuple[Tuple[str, str], ...] = (
    ("countable F1 0.05", "f1_countable"), ("0.10", "f1_countable@0.1"), ("0.15", "f1_countable@0.15"),
    ("countable count error", "count_error_countable"),
    ("visible F1 0.05", "f1"), ("0.10", "f1@0.1"), ("0.15", "f1@0.15"), ("visible count error", "count_error"),
    ("well-seen F1 0.05", "f1_well_seen"), ("0.10", "f1_well_seen@0.1"), ("0.15", "f1_well_seen@0.15"),
    ("well-seen count error", "count_error_well_seen"), ("precision", "precision"),
    ("temperature error (C)", "mean_temperature_error"),
)  # fmt: skip
"""The seeds table's columns (header, measure): the countable tier (the targets') first."""


def seed_of(row: Row) -> int:
    """A row's scene seed."""
    return int(str(row["seed"]))


def seed_groups(rows: Sequence[Row], pool_scenes: bool = False) -> Dict[Tuple[str, str, str, str], List[Row]]:
    """Rows per (scene, lighting, role, label), in the order of the table: scene, lighting, reporting seeds before
    tuning seeds, the trained rows before the oracle's; ``pool_scenes``: every scene of a lighting together (the
    scene named ``all``)."""
    groups: Dict[Tuple[str, str, str, str], List[Row]] = defaultdict(list)
    for row in rows:
        scene = "all" if pool_scenes else str(row["scene"])
        groups[(scene, str(row["lighting"]), str(row["role"]), str(row["label"]))].append(row)

    def order(key: Tuple[str, str, str, str]) -> tuple:
        scene, lighting, role, label = key
        return scene, LIGHTING_ORDER.get(lighting, 9), lighting, role != "reporting", label.startswith("oracle"), label

    return {key: sorted(groups[key], key=lambda r: (seed_of(r), str(r["scene"]))) for key in sorted(groups, key=order)}


def spread(values: Sequence[float]) -> Dict[str, float]:
    """Mean, sample standard deviation (NaN for fewer than two), least and most of the finite ``values``."""
    finite = np.asarray([v for v in values if math.isfinite(v)], np.float64)
    if finite.size == 0:
        return {"mean": float("nan"), "sd": float("nan"), "min": float("nan"), "max": float("nan")}
    sd = float(finite.std(ddof=1)) if finite.size > 1 else float("nan")
    return {"mean": float(finite.mean()), "sd": sd, "min": float(finite.min()), "max": float(finite.max())}


def seed_summary(rows: Sequence[Row], pool_scenes: bool = False) -> List[Row]:
    """Per scene (``pool_scenes``: all of them), lighting, role and label: the seeds, and each measure's mean,
    standard deviation, least and most over the runs."""
    out: List[Row] = []
    for (scene, lighting, role, label), members in seed_groups(rows, pool_scenes).items():
        seeds = " ".join(dict.fromkeys(str(m["seed"]) for m in members))
        row: Row = {"scene": scene, "lighting": lighting, "role": role, "label": label, "runs": len(members),
                    "seeds": seeds}  # fmt: skip
        for measure in MEASURES:
            stats = spread([float(m[measure]) for m in members])  # type: ignore[arg-type]
            row |= {measure: stats["mean"], **{f"{measure}_{k}": v for k, v in stats.items() if k != "mean"}}
        out.append(row)
    return out


def _cell(stats: Row, measure: str) -> str:
    mean, sd = float(stats[measure]), float(stats[f"{measure}_sd"])  # type: ignore[arg-type]
    if not math.isfinite(mean):
        return "-"
    percent = measure.startswith("count_error")
    text = f"{100 * mean:+.0f}%" if percent else f"{mean:.2f}"
    if math.isfinite(sd):
        text += f" ± {100 * sd:.0f}" if percent else f" ± {sd:.2f}"
    return text


def _summary_lines(summary: Sequence[Row]) -> List[str]:
    lines = ["| scene | lighting | seeds | row | runs | " + " | ".join(h for h, _ in SEED_COLUMNS) + " |",
             "|---|---|---|---|---|" + "---|" * len(SEED_COLUMNS)]  # fmt: skip
    for stats in summary:
        cells = [_cell(stats, measure) for _, measure in SEED_COLUMNS]
        lines.append(f"| {stats['scene']} | {stats['lighting']} | {stats['role']} {stats['seeds']} | {stats['label']} "
                     f"| {stats['runs']} | " + " | ".join(cells) + " |")  # fmt: skip
    return lines


def seed_table(rows: Sequence[Row], header: str, reporting_from: int) -> str:
    """The seeds-by-lightings table (markdown): per scene, lighting and seed role the trained runs' row counts and
    the oracle's beside them, each measure's mean ± standard deviation over the seeds; the anchors under it; then
    every run."""
    seeds = {role: sorted({seed_of(r) for r in rows if r["role"] == role}) for role in ("tuning", "reporting")}
    named = {role: ", ".join(map(str, s)) or "none" for role, s in seeds.items()}
    ranges = sorted({(str(r["scene"]), f"{r['max_range']:g}") for r in rows if isinstance(r["max_range"], float)})
    lines = [
        "# Fruit counted on the row the rig drove, over seeds and lightings",
        "",
        header,
        "",
        f"**Seeds.** Tuning seeds (below {reporting_from}; the project chooses its settings on 0-2): {named['tuning']}. "
        f"Reporting seeds ({reporting_from} and up, never tuned on): {named['reporting']}. The two are never pooled.",
        "",
        "Each cell: the mean over the seeds (one run per seed) ± their standard deviation (none for one seed), from "
        "each run's `count.json` (`counts.csv` lists them). F1 at a match distance of 0.05, 0.10 and 0.15 m; count "
        "error (counted - truth) / truth; precision at 0.05 m; temperature error: mean |counted - true| over the "
        "matched fruit. The row's truth (true fruit within the row range of the capture's cameras: "
        + (", ".join(f"{scene} {distance} m" for scene, distance in ranges) or "none given")
        + ") in tiers: countable (a quarter of the fruit's disc in at least one training frame, the fruit an "
        "annotator would mark), visible (3 pixels in one training view), well seen (a quarter of the disc in two). "
        "Rows: the trained runs (`agrinerf-count --path views --source fruit`, then `--max-range`), and beside them "
        "`oracle`: the capture's true fruit pixels and true depth counted the same way (the counter's ceiling).",
        "",
    ]
    lines += _summary_lines(seed_summary(rows))
    if len({r["scene"] for r in rows}) > 1:  # the targets are per lighting over both scenes
        lines += ["", "Per lighting, the scenes pooled (each cell over every run of the lighting: scenes x seeds):", "",
                  *_summary_lines(seed_summary(rows, pool_scenes=True))]  # fmt: skip
    lines += ["", ANCHORS, "", "## Every run", "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(fmt(row[c]) for c in COLUMNS) + " |" for row in rows]
    return "\n".join(lines) + "\n"


def pooled_markdown(rows: Sequence[Row], shown: Sequence[str]) -> str:
    """Per lighting, role and label (scenes pooled): each measure's mean over the runs and its bootstrap interval;
    the anchors; then every row."""
    groups: Dict[tuple, List[Row]] = defaultdict(list)
    for row in rows:
        groups[(row["lighting"], row["role"], row["label"])].append(row)
    lines = ["| lighting | seeds | row | runs (scene:seed) | " + " | ".join(shown) + " |",
             "|---|---|---|---|" + "---|" * len(shown)]  # fmt: skip
    for (lighting, role, label), members in sorted(groups.items(), key=lambda kv: [str(k) for k in kv[0]]):
        cells = []
        for measure in shown:
            interval = bootstrap_mean([float(m[measure]) for m in members])  # type: ignore[arg-type]
            cells.append("-" if math.isnan(interval.value) else
                         f"{interval.value:.2f} [{interval.low:.2f}, {interval.high:.2f}]")  # fmt: skip
        runs = ", ".join(f"{m['scene']}:{m['seed']}" for m in members)
        lines.append(f"| {lighting} | {role} | {label} | {runs} | " + " | ".join(cells) + " |")
    lines += ["", ANCHORS, "", "| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(fmt(row[c]) for c in COLUMNS) + " |" for row in rows]
    return "\n".join(lines) + "\n"
