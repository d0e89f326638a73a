"""Benchmark results: an append-only CSV (a crashed run loses only itself), a Markdown table and a trade-off plot."""

from __future__ import annotations

import csv
import math
import os
from pathlib import Path
from typing import Dict, Iterable, List, Sequence, Set, Tuple

COLUMNS = (
    "scene", "method", "label", "step", "wall_s", "s_per_step", "peak_rss_mb", "device",
    "psnr", "ssim", "lpips", "psnr_clean", "ssim_clean", "thermal_psnr", "thermal_ssim", "eval_views",
    "thermal_camera_psnr", "psnr_clean_per_view", "temperature_mae", "fine_region_weight", "voxel_size_m",
    "voxel_size_final_m", "psnr_fruit",
)  # fmt: skip
"""One row per evaluated checkpoint."""

Row = Dict[str, str]


def append_rows(csv_path: Path, rows: Iterable[Dict[str, object]]) -> None:
    """Append rows (and the header if the file is new), flushed to disk before returning."""
    csv_path.parent.mkdir(parents=True, exist_ok=True)
    new = not csv_path.exists() or csv_path.stat().st_size == 0
    if not new:
        with open(csv_path, newline="") as handle:
            header = next(csv.reader(handle), [])
        if tuple(header) != COLUMNS:  # written before a column was added: rewrite it with today's columns
            old_rows = read_rows(csv_path)
            tmp = csv_path.with_suffix(".csv.tmp")
            with open(tmp, "w", newline="") as handle:
                writer = csv.DictWriter(handle, fieldnames=COLUMNS, extrasaction="ignore")
                writer.writeheader()
                writer.writerows({k: row.get(k, "") for k in COLUMNS} for row in old_rows)
            os.replace(tmp, csv_path)
    with open(csv_path, "a", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=COLUMNS, extrasaction="ignore")
        if new:
            writer.writeheader()
        for row in rows:
            writer.writerow({k: _fmt(row.get(k, "")) for k in COLUMNS})
        handle.flush()
        os.fsync(handle.fileno())


def _fmt(value: object) -> str:
    if isinstance(value, float):
        return "nan" if math.isnan(value) else f"{value:.6g}"
    return str(value)


def read_rows(csv_path: Path) -> List[Row]:
    """All rows of a results file (empty if it does not exist)."""
    if not csv_path.exists():
        return []
    with open(csv_path, newline="") as handle:
        return list(csv.DictReader(handle))


def done_runs(rows: Sequence[Row]) -> Set[Tuple[str, str]]:
    """(scene, method) pairs that already have results: a resumed benchmark skips them."""
    return {(r["scene"], r["method"]) for r in rows}


def as_float(row: Row, key: str) -> float:
    try:
        return float(row.get(key, "nan") or "nan")
    except ValueError:
        return math.nan


def pareto_front(points: Sequence[Tuple[float, float]]) -> List[int]:
    """Indices of points not dominated by another (less time and higher quality), by increasing time."""
    order = sorted((i for i, (t, q) in enumerate(points) if math.isfinite(t) and math.isfinite(q)),
                   key=lambda i: (points[i][0], -points[i][1]))  # fmt: skip
    front, best = [], -math.inf
    for i in order:
        if points[i][1] > best:
            front.append(i)
            best = points[i][1]
    return front


def quality_key(rows: Sequence[Row]) -> str:
    """The quality figure to plot: PSNR against clean truth where the scene has it, else against captured frames."""
    return "psnr_clean" if any(math.isfinite(as_float(r, "psnr_clean")) for r in rows) else "psnr"


def psnr_at_time(rows: Sequence[Row], method: str, scene: str, wall_s: float, key: str) -> float:
    """A method's quality at ``wall_s``: the best checkpoint reached by then (NaN if none had been saved)."""
    reached = [as_float(r, key) for r in rows if r["method"] == method and r["scene"] == scene
               and as_float(r, "wall_s") <= wall_s + 1e-9]  # fmt: skip
    reached = [q for q in reached if math.isfinite(q)]
    return max(reached) if reached else math.nan


def psnr_at_step(rows: Sequence[Row], method: str, scene: str, step: int, key: str) -> float:
    """A method's quality at ``step``: the best checkpoint at or before it (NaN if none had been saved)."""
    reached = [as_float(r, key) for r in rows if r["method"] == method and r["scene"] == scene
               and int(r["step"]) <= step]  # fmt: skip
    reached = [q for q in reached if math.isfinite(q)]
    return max(reached) if reached else math.nan


FLAT_DB = 0.1
"""A run whose quality moves less than this between its first and best checkpoint has not learnt at its budget: a
margin over it is the budget's, not the method's (`is_flat`)."""


def is_flat(rows: Sequence[Row], method: str, scene: str, key: str) -> bool:
    """Whether a run's quality moved less than `FLAT_DB` over its checkpoints (a constant output)."""
    ordered = sorted((r for r in rows if r["method"] == method and r["scene"] == scene), key=lambda r: int(r["step"]))
    values = [as_float(r, key) for r in ordered]
    values = [v for v in values if math.isfinite(v)]
    return len(values) >= 2 and max(values) - values[0] < FLAT_DB


def time_to_quality(rows: Sequence[Row], method: str, scene: str, target: float, key: str) -> float:
    """Wall seconds of a method's first checkpoint at or above ``target`` (NaN if never reached)."""
    times = [as_float(r, "wall_s") for r in rows if r["method"] == method and r["scene"] == scene
             and as_float(r, key) >= target]  # fmt: skip
    return min(times) if times else math.nan


def markdown_table(rows: Sequence[Row]) -> str:
    """One line per evaluated checkpoint, grouped by scene and method."""
    header = ("| scene | method | step | wall s | s/step | peak RSS MiB | PSNR | SSIM | LPIPS | PSNR clean | "
              "SSIM clean | thermal PSNR | thermal SSIM | temperature MAE C | views |")  # fmt: skip
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for r in sorted(rows, key=lambda r: (r["scene"], r["method"], int(r["step"]))):
        cells = [r["scene"], r["label"], r["step"]]
        for key, digits in (("wall_s", 0), ("s_per_step", 3), ("peak_rss_mb", 0), ("psnr", 2), ("ssim", 3),
                            ("lpips", 3), ("psnr_clean", 2), ("ssim_clean", 3), ("thermal_psnr", 2),
                            ("thermal_ssim", 3), ("temperature_mae", 2)):  # fmt: skip
            value = as_float(r, key)
            cells.append("-" if not math.isfinite(value) else f"{value:.{digits}f}")
        cells.append(r.get("eval_views") or "-")  # results written before the column: all held-out views
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def plot(rows: Sequence[Row], path: Path) -> Path:
    """Quality against wall time, one line per method, one panel per scene, Pareto front marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    scenes = sorted({r["scene"] for r in rows})
    key = quality_key(rows)
    fig, axes = plt.subplots(1, len(scenes), figsize=(5.5 * len(scenes), 4.2), squeeze=False)
    for ax, scene in zip(axes[0], scenes, strict=True):
        scene_rows = [r for r in rows if r["scene"] == scene and math.isfinite(as_float(r, key))]
        for method in sorted({r["method"] for r in scene_rows}):
            mine = sorted((r for r in scene_rows if r["method"] == method), key=lambda r: as_float(r, "wall_s"))
            ax.plot(
                [as_float(r, "wall_s") for r in mine], [as_float(r, key) for r in mine], "o-", label=mine[0]["label"]
            )
        points = [(as_float(r, "wall_s"), as_float(r, key)) for r in scene_rows]
        front = pareto_front(points)
        if front:
            ax.plot([points[i][0] for i in front], [points[i][1] for i in front], "k--", lw=1, alpha=0.6,
                    label="Pareto front")  # fmt: skip
        ax.set_title(scene)
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("PSNR vs clean truth (dB)" if key == "psnr_clean" else "PSNR vs held-out frames (dB)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def per_view(row: Row, key: str = "psnr_clean_per_view") -> List[float]:
    """A row's per-view figures (empty for rows written before the column)."""
    text = row.get(key) or ""
    return [float(v) for v in text.split(";") if v]


def paired_difference(mine: Sequence[float], base: Sequence[float], confidence: float = 0.95) -> Tuple[float, float]:
    """Mean of the per-view differences ``mine - base`` and the half-width of its confidence interval (scipy's paired
    t-test, ``ttest_rel``).

    Views are paired (the same held-out view rendered by both runs), so view-to-view variation in difficulty cancels;
    the interval is NaN with fewer than two views.
    """
    from scipy import stats

    if len(mine) != len(base):
        raise ValueError(f"paired views differ in number: {len(mine)} and {len(base)}")
    if not mine:
        return math.nan, math.nan
    mean = sum(a - b for a, b in zip(mine, base, strict=True)) / len(mine)
    if len(mine) < 2:
        return mean, math.nan
    low, high = stats.ttest_rel(mine, base).confidence_interval(confidence)
    return mean, float(high - low) / 2.0


def final_rows(rows: Sequence[Row]) -> Dict[Tuple[str, str], Row]:
    """The last evaluated checkpoint of every (scene, method)."""
    last: Dict[Tuple[str, str], Row] = {}
    for r in rows:
        key = (r["scene"], r["method"])
        if key not in last or int(r["step"]) > int(last[key]["step"]):
            last[key] = r
    return last


def run_spread(rows: Sequence[Row], replicates: Sequence[str]) -> Tuple[float, int]:
    """Run-to-run standard deviation of the final ``psnr_clean`` and its degrees of freedom, pooled over scenes.

    ``replicates`` are methods that train the same model with other random streams (in each scene, the runs of those
    present form one group; runs with the very same per-view results drew the same stream and count once). A paired
    per-view interval covers the held-out views, not this spread: two runs that draw other random rays differ by it
    even when nothing else differs. NaN with no group of two.
    """
    last = final_rows(rows)
    groups = []
    for scene in {scene for scene, _ in last}:
        runs = {tuple(per_view(last[(scene, m)])) or m: last[(scene, m)] for m in replicates if (scene, m) in last}
        groups.append([as_float(row, "psnr_clean") for row in runs.values()])
    return pooled_sd(groups)


def pooled_sd(groups: Iterable[Sequence[float]]) -> Tuple[float, int]:
    """Pooled standard deviation of groups of values about their own means, and its degrees of freedom (non-finite
    values dropped; a group of one adds nothing). NaN with no group of two."""
    sum_sq, dof = 0.0, 0
    for group in groups:
        values = [v for v in group if math.isfinite(v)]
        if len(values) >= 2:
            mean = sum(values) / len(values)
            sum_sq += sum((v - mean) ** 2 for v in values)
            dof += len(values) - 1
    return (math.sqrt(sum_sq / dof), dof) if dof else (math.nan, 0)


def seed_key(method: str, seed: int) -> str:
    """Result key of ``method`` trained with random stream ``seed`` (0: the key itself)."""
    return method if seed == 0 else f"{method}@s{seed}"


def seed_base(key: str) -> str:
    """The method of a :func:`seed_key` result key."""
    return key.split("@s", 1)[0]


def difference_spread(
    rows: Sequence[Row], methods: Sequence[str], baseline: str, seeds: Sequence[int]
) -> Tuple[float, int]:
    """Standard deviation between random streams of each method's final ``psnr_clean`` difference to ``baseline``
    (both trained with the same stream, :func:`seed_key`), pooled over scenes and methods, and its degrees of freedom.

    With common random numbers (the same stream for a method and its baseline) a method that sends the shared model
    the same gradient trains the very same model: every stream gives a difference of exactly 0, and such methods
    (identical per-view results in every stream) are left out. NaN with no method seen in two streams.
    """
    last = final_rows(rows)
    groups = []
    for scene in {scene for scene, _ in last}:
        for method in methods:
            pairs = [
                (last[(scene, seed_key(method, s))], last[(scene, seed_key(baseline, s))])
                for s in seeds
                if (scene, seed_key(method, s)) in last and (scene, seed_key(baseline, s)) in last
            ]
            if all(per_view(m) and per_view(m) == per_view(b) for m, b in pairs):
                continue
            groups.append([as_float(m, "psnr_clean") - as_float(b, "psnr_clean") for m, b in pairs])
    return pooled_sd(groups)


def difference_interval(
    view_half: float, run_sd: float, run_dof: int, confidence: float = 0.95, runs_factor: float = math.sqrt(2.0)
) -> float:
    """Half-width of the interval of a difference between two single runs: the paired per-view half-width and the
    run-to-run part, independent sources added in quadrature. ``runs_factor``: sqrt(2) where ``run_sd`` is one run's
    spread (:func:`run_spread`, two independent runs), 1 where it is the difference's own (:func:`difference_spread`)."""
    from scipy import stats

    if not (math.isfinite(run_sd) and run_dof > 0):
        return view_half
    run_half = float(stats.t.ppf(0.5 + confidence / 2, run_dof)) * runs_factor * run_sd
    return math.hypot(view_half, run_half) if math.isfinite(view_half) else run_half


def difference_text(mean: float, half: float) -> str:
    """A paired difference and its interval's half-width as ``+0.12 ± 0.34``, marked * where the interval excludes 0."""
    mark = "*" if math.isfinite(half) and abs(mean) > half else ""
    return f"{mean:+.2f} ± {half:.2f}{mark}"


def ablation_table(
    rows: Sequence[Row],
    methods: Sequence[str],
    baseline: str,
    labels: Dict[str, str],
    run_sd: Tuple[float, int] = (math.nan, 0),
    runs_factor: float = math.sqrt(2.0),
) -> str:
    """Scenes down, methods across: each cell the final ``psnr_clean`` and, for the non-baseline methods, the paired
    per-view difference to ``baseline`` with its 95% interval (a difference whose interval excludes 0 is marked *;
    "identical" where every view is the same). With ``run_sd`` the interval also covers the run-to-run spread
    (:func:`difference_interval`, ``runs_factor``)."""
    last = final_rows(rows)
    scenes = sorted({scene for scene, _ in last})
    header = "| scene | " + " | ".join(labels.get(m, m) for m in methods) + " |"
    lines = [header, "|" + "---|" * (len(methods) + 1)]
    for scene in scenes:
        cells = [scene]
        base = last.get((scene, baseline))
        for method in methods:
            row = last.get((scene, method))
            if row is None:
                cells.append("-")
                continue
            cell = f"{as_float(row, 'psnr_clean'):.2f}"
            mine, theirs = per_view(row), (per_view(base) if base is not None else [])
            if method != baseline and mine and theirs:
                if mine == theirs:
                    cell += " (identical)"
                else:
                    mean, half = paired_difference(mine, theirs)
                    half = difference_interval(half, *run_sd, runs_factor=runs_factor)
                    cell += f" ({difference_text(mean, half)})"
            cells.append(cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
