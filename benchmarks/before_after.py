"""Two ``agrinerf-bench`` results files side by side: quality against wall time before and after a change.

    python benchmarks/before_after.py --before OUT_BEFORE/results.csv --after OUT_AFTER/results.csv --out OUT

Writes ``OUT/before_after.md`` (per scene and method: every checkpoint's step, wall time, PSNR against the clean truth,
thermal-camera PSNR, temperature error and the grid diagnostics, before and after) and ``OUT/before_after.png`` (PSNR
against wall time, one panel per scene, before dashed, after solid). Wall times compare only where both runs shared the
machine alike (run side by side, or each alone on a quiet machine); the table says how they were run via ``--note``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import tyro  # noqa: E402

from agrinerf_ns.bench import results  # noqa: E402

COLUMNS: Tuple[Tuple[str, str, int], ...] = (
    ("psnr_clean", "PSNR clean (dB)", 2),
    ("ssim_clean", "SSIM clean", 3),
    ("psnr_fruit", "PSNR fruit (dB)", 2),
    ("thermal_camera_psnr", "thermal-camera PSNR (dB)", 2),
    ("temperature_mae", "temperature MAE (C)", 3),
    ("fine_region_weight", "weight in box", 3),
    ("voxel_size_m", "voxel (m)", 4),
    ("voxel_size_final_m", "voxel at final grids (m)", 4),
)


@dataclass
class Args:
    before: Path
    """results.csv of the runs before the change."""
    after: Path
    """results.csv of the runs after it."""
    out: Path
    """Where before_after.md and before_after.png go."""
    note: str = ""
    """How the runs were made (machine, threads, side by side or not): printed under the table."""


def _fmt(row: results.Row, key: str, digits: int) -> str:
    value = results.as_float(row, key)
    return "-" if value != value else f"{value:.{digits}f}"  # NaN: not measured


def main(args: Args) -> None:
    runs: Dict[str, List[results.Row]] = {
        "before": results.read_rows(args.before),
        "after": results.read_rows(args.after),
    }
    keys = sorted({(r["scene"], r["method"]) for rows in runs.values() for r in rows})
    args.out.mkdir(parents=True, exist_ok=True)
    lines = ["# Before and after", "", f"Before: `{args.before}`; after: `{args.after}`. {args.note}", ""]
    head = "| scene | method | run | step | wall s | " + " | ".join(label for _, label, _ in COLUMNS) + " |"
    lines += [head, "|" + "---|" * (5 + len(COLUMNS))]
    scenes = sorted({scene for scene, _ in keys})
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4), squeeze=False)
    for scene, method in keys:
        for name, rows in runs.items():
            mine = sorted(
                (r for r in rows if r["scene"] == scene and r["method"] == method), key=lambda r: int(r["step"])
            )
            for r in mine:
                cells = " | ".join(_fmt(r, key, digits) for key, _, digits in COLUMNS)
                lines.append(f"| {scene} | {method} | {name} | {r['step']} | {float(r['wall_s']):.0f} | {cells} |")
            if mine:
                ax = axes[0, scenes.index(scene)]
                ax.plot([float(r["wall_s"]) for r in mine], [results.as_float(r, "psnr_clean") for r in mine],
                        "--o" if name == "before" else "-o", label=f"{method} ({name})")  # fmt: skip
    for ax, scene in zip(axes[0], scenes, strict=True):
        ax.set_title(scene)
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("PSNR vs clean truth (dB)")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(args.out / "before_after.png", dpi=110)
    (args.out / "before_after.md").write_text("\n".join(lines) + "\n")
    print((args.out / "before_after.md").read_text())


if __name__ == "__main__":
    main(tyro.cli(Args))
