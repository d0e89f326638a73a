"""Count scores of trained runs and their oracles, pooled over runs with bootstrap 95% intervals (#49).

``python benchmarks/count_fruit_table.py --counts LABEL=COUNT_DIR... --out results/NAME`` reads each
``agrinerf-count`` folder's ``count.json`` (written with ``--truth``), takes the scene, lighting and seed from the truth's
``truth/scene.json`` and writes ``counts.csv`` (one row per folder), ``summary.csv`` and ``counts.md``: per lighting and row kind the
mean over the runs of the reporting seeds (``--reporting-from``: seeds at or above it; the others are tuning seeds,
listed apart and never pooled) with an interval that resamples the runs. ``LABEL`` names the row's kind (the
trained configuration, or an oracle: ``python -m agrinerf_ns.lab.count_oracle``, the counting on perfect renders);
folders of one label and lighting are pooled.

``python benchmarks/count_fruit_table.py --bench OUT`` writes the seeds-by-lightings table of an ``agrinerf-bench
--profile count`` folder again (``OUT/counts.csv``, ``summary.csv``, ``counts.md``: what the bench writes at its end)
from the row counts under it, without training or counting anything.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Optional, Sequence

import tyro

from agrinerf_ns.lab.count_row_tables import COLUMNS, MEASURES, Row, fmt, pooled_markdown, read_row
from agrinerf_ns.lab.count_tables import bootstrap_mean


@dataclass
class TableArgs:
    counts: List[str] = field(default_factory=list)
    """LABEL=FOLDER: agrinerf-count output folders (each with count.json written against a truth) and their row's
    label."""
    out: Optional[Path] = None
    """Folder for counts.csv, summary.csv and counts.md (required with --counts)."""
    reporting_from: int = 100
    """Seeds at or above this are reporting seeds; the others tuning seeds."""
    bench: Optional[Path] = None
    """Instead of --counts: an agrinerf-bench --profile count folder, whose seeds-by-lightings table is written again
    into it."""


SHOWN = ("f1_countable", "f1_countable@0.1", "f1_countable@0.15", "count_error_countable", "f1", "f1_well_seen",
         "count_error", "count_error_well_seen", "mean_temperature_error")  # fmt: skip
"""The pooled table's columns: the countable tier (the targets') at 0.05, 0.10 and 0.15 m first."""


def summary(rows: Sequence[Row]) -> List[Dict[str, object]]:
    """Per lighting, role and label: the runs, and each measure's mean over them with its bootstrap interval."""
    groups: Dict[tuple, List[Row]] = {}
    for row in rows:
        groups.setdefault((row["lighting"], row["role"], row["label"]), []).append(row)
    out: List[Dict[str, object]] = []
    for (lighting, role, label), members in sorted(groups.items(), key=lambda kv: [str(k) for k in kv[0]]):
        row: Dict[str, object] = {"lighting": lighting, "role": role, "label": label, "runs": len(members)}
        for measure in MEASURES:
            interval = bootstrap_mean([float(m[measure]) for m in members])  # type: ignore[arg-type]
            row |= {measure: interval.value, f"{measure}_low": interval.low, f"{measure}_high": interval.high}
        out.append(row)
    return out


def main(args: TableArgs) -> List[Row]:
    if args.bench is not None:
        from agrinerf_ns.lab.count_bench import run_note
        from agrinerf_ns.lab.count_row_bench import write_bench_tables

        note = run_note(f"python benchmarks/count_fruit_table.py --bench {args.bench}")
        rows = write_bench_tables(args.bench, note, args.reporting_from)
        print((args.bench / "counts.md").read_text())
        return rows
    pairs = [item.split("=", 1) for item in args.counts]
    bad = [item for item, pair in zip(args.counts, pairs, strict=True) if len(pair) != 2]
    if bad or not args.counts or args.out is None:
        raise SystemExit(f"--counts takes LABEL=FOLDER and needs --out (or give --bench OUT), got {bad or args.counts}")
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
        writer.writerows({k: fmt(v) for k, v in row.items()} for row in pooled)
    (args.out / "counts.md").write_text(pooled_markdown(rows, SHOWN))
    print((args.out / "counts.md").read_text())
    return rows


if __name__ == "__main__":
    main(tyro.cli(TableArgs))
