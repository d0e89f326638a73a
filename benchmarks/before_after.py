"""Two ``agrinerf-bench`` results files side by side: quality against wall time before and after a change.

    python benchmarks/before_after.py --before OUT_BEFORE/results.csv --after OUT_AFTER/results.csv --out OUT

Writes ``OUT/before_after.md`` (per scene and method: every checkpoint's step, wall time, PSNR against the clean truth,
thermal-camera PSNR, temperature error and the grid diagnostics, before and after; then the wall time after takes to
reach before's last RGB, thermal-camera and fruit-pixel PSNR, and after against before at equal wall time) and
``OUT/before_after.png`` (RGB PSNR, top, and thermal-camera PSNR, bottom, against wall time, one column per scene,
before dashed, after solid). Wall times compare only where both runs shared the machine alike (run side by side, or
each alone on a quiet machine); the table says how they were run via ``--note``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import tyro  # noqa: E402

from agrinerf_ns.lab import results  # noqa: E402

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


Curve = List[Tuple[float, float]]
"""(wall seconds, value) of a run's checkpoints, in order of time."""


def curve(rows: List[results.Row], key: str) -> Curve:
    points = [(float(r["wall_s"]), results.as_float(r, key)) for r in rows]
    return sorted((t, v) for t, v in points if v == v)


def time_to_reach(points: Curve, target: float) -> float:
    """Wall seconds at which a curve first reaches `target`, linear between checkpoints (from 0 s at its first
    checkpoint's value); NaN if it never does."""
    last_t, last_v = 0.0, float("-inf")
    for t, v in points:
        if v >= target:
            if last_v == float("-inf"):
                return t
            return last_t + (t - last_t) * (target - last_v) / (v - last_v)
        last_t, last_v = t, v
    return float("nan")


def value_at(points: Curve, t: float) -> float:
    """A curve's value at wall time `t`, linear between checkpoints; NaN outside its checkpoints' span."""
    for (t0, v0), (t1, v1) in zip(points[:-1], points[1:], strict=True):
        if t0 <= t <= t1:
            return v0 if t1 == t0 else v0 + (v1 - v0) * (t - t0) / (t1 - t0)
    return points[0][1] if len(points) == 1 and points[0][0] == t else float("nan")


def comparison(before: List[results.Row], after: List[results.Row], key: str) -> str:
    """Cells: before's last value and wall time, after's time to reach it (and its share of before's), and the least
    and mean of after minus before at after's checkpoints that before's span covers."""
    b, a = curve(before, key), curve(after, key)
    if not b or not a:
        return "- | - | - | -"
    target, end = b[-1][1], b[-1][0]
    reach = time_to_reach(a, target)
    diffs = [v - value_at(b, t) for t, v in a if value_at(b, t) == value_at(b, t)]
    reached = f"{reach:.0f} s ({reach / end:.2f}x)" if reach == reach else "not reached"
    spread = f"{min(diffs):+.2f} / {sum(diffs) / len(diffs):+.2f}" if diffs else "-"
    return f"{target:.2f} at {end:.0f} s | {reached} | {spread} | {len(diffs)}"


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
    panels = (("psnr_clean", "RGB PSNR vs clean truth (dB)"), ("thermal_camera_psnr", "thermal-camera PSNR (dB)"))
    fig, axes = plt.subplots(len(panels), len(scenes), figsize=(5 * len(scenes), 4 * len(panels)), squeeze=False)
    for scene, method in keys:
        for name, rows in runs.items():
            mine = sorted(
                (r for r in rows if r["scene"] == scene and r["method"] == method), key=lambda r: int(r["step"])
            )
            for r in mine:
                cells = " | ".join(_fmt(r, key, digits) for key, _, digits in COLUMNS)
                lines.append(f"| {scene} | {method} | {name} | {r['step']} | {float(r['wall_s']):.0f} | {cells} |")
            for row, (key, _) in enumerate(panels):
                points = curve(mine, key)
                if points:
                    times, values = [t for t, _ in points], [v for _, v in points]
                    axes[row, scenes.index(scene)].plot(times, values, "--o" if name == "before" else "-o",
                                                        label=f"{method} ({name})")  # fmt: skip
    for row, (_, label) in enumerate(panels):
        for ax, scene in zip(axes[row], scenes, strict=True):
            ax.set_title(scene)
            ax.set_xlabel("wall time (s)")
            ax.set_ylabel(label)
            ax.legend(fontsize=7)
    lines += ["", "## At equal wall time", "",
              "Before's last checkpoint, the wall time after takes to reach its value (linear between checkpoints; "
              "the share of before's time), and after minus before at after's checkpoints within before's span "
              "(before linear between its checkpoints): least / mean, and how many.", "",
              "| scene | method | measure | before's last | after reaches it at | after - before, least / mean | n |",
              "|---|---|---|---|---|---|---|"]  # fmt: skip
    for scene, method in keys:
        pair = [[r for r in runs[name] if r["scene"] == scene and r["method"] == method] for name in runs]
        for key, label in (*panels, ("psnr_fruit", "PSNR on the truth's fruit pixels (dB)")):
            lines.append(f"| {scene} | {method} | {label} | {comparison(pair[0], pair[1], key)} |")
    fig.tight_layout()
    fig.savefig(args.out / "before_after.png", dpi=110)
    (args.out / "before_after.md").write_text("\n".join(lines) + "\n")
    print((args.out / "before_after.md").read_text())


if __name__ == "__main__":
    main(tyro.cli(Args))
