"""Each method against the baselines (Nerfacto (RGB), TensoRF) at equal wall time and at equal steps.

Equal wall time is the CPU user's question (what a minute of training buys); equal steps is the paper's (the same
number of 1024-ray batches). Each pair is read at the shorter of the two runs, so that neither has trained longer
than the other, from the best checkpoint reached by then. A baseline whose quality did not move over its
checkpoints (`results.is_flat`) has not learnt at its budget: its rows say so, and the difference is not a margin.
"""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Dict, List, Sequence

from agrinerf_ns.lab import results
from agrinerf_ns.lab.methods import METHODS

BASELINES = ("nerfacto", "tensorf")
"""Nerfstudio's own methods the presets are compared against (keys of ``METHODS``)."""
FIELDS = ("scene", "method", "baseline", "basis", "at", "quality", "baseline_quality", "difference", "baseline_flat")


def margins(rows: Sequence[results.Row], key: str) -> List[Dict[str, object]]:
    """One row per scene, method, baseline and basis (``wall_s`` or ``steps``), for the RGB methods that are not
    baselines; ``at`` is the wall seconds or steps both runs reached."""
    out: List[Dict[str, object]] = []
    for scene in sorted({r["scene"] for r in rows}):
        scene_rows = [r for r in rows if r["scene"] == scene]
        rgb = sorted({r["method"] for r in scene_rows if METHODS[results.seed_base(r["method"])].supervision == "rgb"})
        for baseline in (b for b in BASELINES if b in rgb):
            flat = results.is_flat(scene_rows, baseline, scene, key)
            for method in (m for m in rgb if m not in BASELINES):
                for basis in ("wall_s", "steps"):
                    final = {m: max(_progress(r, basis) for r in scene_rows if r["method"] == m)
                             for m in (method, baseline)}  # fmt: skip
                    at = min(final.values())
                    mine, base = (_quality(scene_rows, m, scene, basis, at, key) for m in (method, baseline))
                    out.append({
                        "scene": scene, "method": method, "baseline": baseline, "basis": basis,
                        "at": round(at, 1), "quality": mine, "baseline_quality": base,
                        "difference": mine - base if math.isfinite(mine) and math.isfinite(base) else math.nan,
                        "baseline_flat": flat,
                    })  # fmt: skip
    return out


def _progress(row: results.Row, basis: str) -> float:
    return results.as_float(row, "wall_s") if basis == "wall_s" else float(int(row["step"]))


def _quality(rows: Sequence[results.Row], method: str, scene: str, basis: str, at: float, key: str) -> float:
    if basis == "wall_s":
        return results.psnr_at_time(rows, method, scene, at, key)
    return results.psnr_at_step(rows, method, scene, int(at), key)


def summary_lines(table: Sequence[Dict[str, object]]) -> List[str]:
    """Markdown bullets of `margins`' rows."""
    lines = []
    for row in table:
        method, baseline = (METHODS[results.seed_base(str(row[k]))].label for k in ("method", "baseline"))
        basis = f"equal wall time {row['at']:.0f} s" if row["basis"] == "wall_s" else f"equal steps {row['at']:.0f}"
        difference = float(row["difference"])  # type: ignore[arg-type]
        if not math.isfinite(difference):
            lines.append(f"- {method} vs {baseline} at {basis}: no checkpoint of both by then")
            continue
        flat = " (the baseline did not learn at this budget: its output is flat, so this is not a margin)"
        lines.append(f"- {method} minus {baseline} at {basis}: {float(row['quality']):.2f} - "  # type: ignore[arg-type]
                     f"{float(row['baseline_quality']):.2f} = {difference:+.2f} dB"  # type: ignore[arg-type]
                     f"{flat if row['baseline_flat'] else ''}")  # fmt: skip
    return lines


def write_margins(table: Sequence[Dict[str, object]], path: Path) -> Path:
    """``margins.csv``, written to a temporary sibling and renamed into place."""
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=FIELDS)
        writer.writeheader()
        for row in table:
            writer.writerow({k: (f"{v:.4f}" if isinstance(v, float) else v) for k, v in row.items()})
    os.replace(tmp, path)
    return path
