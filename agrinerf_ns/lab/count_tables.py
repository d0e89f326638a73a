"""The counting tables of ``agrinerf-bench --profile count``: ``count.csv`` (a row per run, path and source) and
``count.md`` (those rows, and per lighting, path and source the mean over runs with a bootstrap 95% interval that
resamples the runs: scenes x seeds).

``python -m agrinerf_ns.lab.count_tables OUT_SEED0/count.csv OUT_SEED1/count.csv ... --out DIR`` pools the rows of
several benchmark folders (one per seed) into ``DIR/count.csv`` and ``DIR/count.md``.
"""

from __future__ import annotations

import csv
import math
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Iterable, List, Mapping, Sequence, Tuple

import numpy as np
import tyro

from agrinerf_ns.detect.bootstrap import BOOTSTRAP_RESAMPLES, BOOTSTRAP_SEED, CONFIDENCE, Interval

COLUMNS = (
    "scene", "lighting", "seed", "method", "step", "path", "source", "counted", "visible", "count_error",
    "precision", "recall", "f1", "mean_match_error", "mean_temperature_error", "seconds",
)  # fmt: skip
"""One row per (run, path, source); ``path``: ``field`` (3D, the sampled field), ``views`` (detected in the rendered
views and lifted), ``views-rays`` (the same detections placed by their rays, ``agrinerf-count --triangulate``) or
``oracle`` (the capture's own frames with the true depth and true temperature: the ceiling)."""
Row = Dict[str, str]
SUMMARY = ("f1", "precision", "recall", "count_error", "mean_temperature_error")


def read_rows(path: Path) -> List[Row]:
    """The rows of a ``count.csv`` (none when it does not exist)."""
    if not Path(path).is_file():
        return []
    with open(path, newline="") as handle:
        return list(csv.DictReader(handle))


def append_rows(path: Path, rows: Iterable[Mapping[str, object]]) -> None:
    """Append rows to ``count.csv`` (header first when new)."""
    path = Path(path)
    new = not path.is_file()
    with open(path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS)
        if new:
            writer.writeheader()
        for row in rows:
            writer.writerow({key: _fmt(row.get(key, "")) for key in COLUMNS})


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.4f}"
    return str(value)


def _float(row: Row, key: str) -> float:
    try:
        return float(row[key])
    except (KeyError, ValueError):
        return float("nan")


def bootstrap_mean(
    values: Sequence[float], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = BOOTSTRAP_SEED
) -> Interval:
    """The mean of the finite ``values`` and its percentile bootstrap interval (resampling the values)."""
    finite = np.asarray([v for v in values if math.isfinite(v)], np.float64)
    if finite.size == 0:
        return Interval(float("nan"), float("nan"), float("nan"))
    draws = np.random.default_rng(seed).integers(0, finite.size, size=(resamples, finite.size))
    means = finite[draws].mean(axis=1)
    tail = 100 * (1 - CONFIDENCE) / 2
    low, high = np.percentile(means, [tail, 100 - tail])
    return Interval(float(finite.mean()), float(low), float(high))


def summary_rows(
    rows: Sequence[Row], by: str = "lighting"
) -> List[Tuple[Tuple[str, str, str, str], int, Dict[str, Interval]]]:
    """Per (`by`: ``lighting`` or ``scene``, method, path, source): the number of runs and each :data:`SUMMARY`
    measure's mean with its interval."""
    groups: Dict[Tuple[str, str, str, str], List[Row]] = defaultdict(list)
    for row in rows:
        groups[(row[by], row["method"], row["path"], row["source"])].append(row)
    order = {name: i for i, name in enumerate(("bright", "shadowed", "dusk", "dark"))}
    lighting = {row[by]: row["lighting"] for row in rows}
    out = []
    for key in sorted(groups, key=lambda k: (order.get(lighting[k[0]], 9), k[0], k[1], k[2], k[3])):
        members = groups[key]
        out.append((key, len(members), {m: bootstrap_mean([_float(r, m) for r in members]) for m in SUMMARY}))
    return out


def markdown(rows: Sequence[Row], header: str = "") -> str:
    """``count.md``: the summary per lighting, path and source (and per scene where a lighting holds several), then
    every row."""
    lines = [
        "# Fruit counted from trained runs",
        "",
        header,
        "",
        "F1, precision and recall at a match distance of 0.05 m against the fruit visible from the training views; "
        "count error (counted - visible) / visible; temperature error: mean |counted - true| over the matched fruit "
        f"(degrees C). In brackets: {CONFIDENCE:.0%} bootstrap intervals ({BOOTSTRAP_RESAMPLES} resamples of the runs, "
        "scenes x seeds, of a lighting). path: field (3D, the sampled field), views (detected in rendered views and "
        "lifted), views-rays (the same detections placed by their rays), oracle (the capture's frames with the true "
        "depth and temperature: the ceiling).",
        "",
        "## Per lighting",
        "",
    ]
    lines += _summary_lines(rows, "lighting")
    if len({r["scene"] for r in rows}) > len({r["lighting"] for r in rows}):  # several scenes in a lighting
        lines += ["", "## Per scene", "", *_summary_lines(rows, "scene")]
    lines += [
        "",
        "## Every run",
        "",
        "| scene | seed | method | step | path | source | counted | visible | count error | precision | recall | F1 "
        "| match error (m) | temperature error (C) | seconds |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['scene']} | {r['seed']} | {r['method']} | {r['step']} | {r['path']} | {r['source']} | {r['counted']} "
            f"| {r['visible']} | {_pct(_float(r, 'count_error'))} | {_num(r, 'precision')} | {_num(r, 'recall')} "
            f"| {_num(r, 'f1')} | {_num(r, 'mean_match_error', 3)} | {_num(r, 'mean_temperature_error')} "
            f"| {_num(r, 'seconds', 0)} |"
        )
    return "\n".join(lines) + "\n"


def _summary_lines(rows: Sequence[Row], by: str) -> List[str]:
    """The summary table per `by` (``lighting``: scenes pooled; ``scene``: each scene and lighting on its own)."""
    lines = [
        f"| {by} | method | path | source | runs | F1 | precision | recall | count error | temperature error (C) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for (group, method, path, source), n, stats in summary_rows(rows, by):
        cells = [_interval(stats[m], percent=m == "count_error") for m in SUMMARY]
        lines.append(f"| {group} | {method} | {path} | {source} | {n} | " + " | ".join(cells) + " |")
    return lines


def _interval(value: Interval, percent: bool = False) -> str:
    if not math.isfinite(value.value):
        return "-"
    if percent:
        return f"{100 * value.value:+.0f}% [{100 * value.low:+.0f}, {100 * value.high:+.0f}]"
    return f"{value.value:.2f} [{value.low:.2f}, {value.high:.2f}]"


def _pct(value: float) -> str:
    return "-" if not math.isfinite(value) else f"{100 * value:+.0f}%"


def _num(row: Row, key: str, digits: int = 2) -> str:
    value = _float(row, key)
    return "-" if not math.isfinite(value) else f"{value:.{digits}f}"


@dataclass
class TablesArgs:
    """Pool the count.csv of several agrinerf-bench folders (one per seed) into one count.csv and count.md."""

    csvs: tyro.conf.Positional[Tuple[Path, ...]]
    """count.csv files (or the benchmark folders that hold them)."""
    out: Path = Path("results/count-3d")
    """Folder for the pooled count.csv and count.md."""
    header: str = ""
    """Text under the title of count.md (command, machine, threads)."""


def main(args: TablesArgs) -> List[Row]:
    rows: List[Row] = []
    for path in args.csvs:
        path = Path(path) / "count.csv" if Path(path).is_dir() else Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no count.csv (agrinerf-bench --profile count writes OUT/count.csv)")
        rows.extend(read_rows(path))
    args.out.mkdir(parents=True, exist_ok=True)
    target = args.out / "count.csv"
    if target.exists():
        target.unlink()
    append_rows(target, rows)
    (args.out / "count.md").write_text(markdown(rows, args.header))
    return rows


if __name__ == "__main__":
    main(tyro.cli(TablesArgs))
