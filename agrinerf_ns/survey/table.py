"""The survey table: one row per capture (fruit with its interval, mean fruit temperature, against the truth where
the capture has one, status, wall time per step), as ``survey.csv`` and ``survey.md``."""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import Any, Dict, List, Mapping, Optional, Sequence

from agrinerf_ns.survey.stages import STAGES, CaptureFolders, read_record

COLUMNS = (
    "capture", "status", "fruit", "fruit_low", "fruit_high", "temperature_c", "temperature_half_c", "truth_visible",
    "count_error", "precision", "recall", "f1", "process_s", "train_s", "count_s", "wall_s", "error",
)  # fmt: skip


def capture_row(capture: str, folders: CaptureFolders, error: Optional[str]) -> Dict[str, Any]:
    """A capture's row from its step records; ``error``: why it did not finish (None: it did, or has not run)."""
    records = {stage: read_record(folders, stage) for stage in STAGES}
    row: Dict[str, Any] = {"capture": capture}
    for stage in STAGES:
        record = records[stage]
        row[f"{stage}_s"] = record["wall_s"] if record else None
    finished = [r["wall_s"] for r in records.values() if r]
    row["wall_s"] = sum(finished) if finished else None
    count = records["count"]
    if count is not None:
        row["status"] = "done"
        row["fruit"] = count["fruit"]
        row["fruit_low"], row["fruit_high"] = count["fruit_interval"]
        row["temperature_c"], row["temperature_half_c"] = count["temperature_c"], count["temperature_half_c"]
        score = count.get("score")
        if score:
            row["truth_visible"] = score["visible"]
            for key in ("count_error", "precision", "recall", "f1"):
                row[key] = score[key]
    else:
        stage = next(s for s in STAGES if records[s] is None)
        row["status"] = f"failed at {stage}" if error is not None else f"not run ({stage})"
        row["error"] = _first_line(error) if error is not None else None
    return row


def _first_line(error: str) -> str:
    """The last line of a traceback that says what went wrong (its exception line)."""
    lines = [line.strip() for line in error.strip().splitlines() if line.strip()]
    named = [line for line in lines if "Error" in line.split(":")[0] or "Exception" in line.split(":")[0]]
    return (named or lines or [""])[-1][:300]


def write_csv(path: Path, rows: Sequence[Mapping[str, Any]]) -> None:
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        for row in rows:
            writer.writerow({k: "" if row.get(k) is None else _fmt(row[k]) for k in COLUMNS})
    tmp.replace(path)


def _fmt(value: Any) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def _num(value: Any, digits: int = 0, signed: bool = False) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"


def markdown(rows: Sequence[Mapping[str, Any]], header: str) -> str:
    """``header``, the table, and the errors of the captures that failed."""
    lines = [
        header,
        "| capture | status | fruit (95% interval) | mean fruit temperature (°C) | visible true fruit | count error | "
        "F1 | process / train / count (s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        fruit = (
            "-" if r.get("fruit") is None else f"{r['fruit']} ({_num(r['fruit_low'], 1)} to {_num(r['fruit_high'], 1)})"
        )
        temp = _num(r.get("temperature_c"), 1)
        if r.get("temperature_half_c") is not None:
            temp += f" ± {_num(r['temperature_half_c'], 1)}"
        error = _num(100 * r["count_error"], 0, signed=True) + "%" if r.get("count_error") is not None else "-"
        times = " / ".join(_num(r.get(f"{s}_s")) for s in STAGES)
        lines.append(f"| {r['capture']} | {r['status']} | {fruit} | {temp} | {_num(r.get('truth_visible'))} | "
                     f"{error} | {_num(r.get('f1'), 2)} | {times} |")  # fmt: skip
    failed = [r for r in rows if r.get("error")]
    if failed:
        lines.append("\nErrors (full text and logs: failures.md):\n")
        lines += [f"- {r['capture']}: {r['error']}" for r in failed]
    return "\n".join(lines) + "\n"


def survey_rows(
    captures: Sequence[str], folders: Mapping[str, CaptureFolders], errors: Mapping[str, str]
) -> List[Dict]:
    """One row per capture, in order."""
    return [capture_row(c, folders[c], errors.get(c)) for c in captures]
