"""SfM wall time against sequence length: pycolmap with exhaustive vs sequential matching on synthetic bright orchards.

    python benchmarks/bench_sfm_scaling.py --out results/sfm-scaling [--sizes 40 160 640] [--exhaustive-max 160]

For each size N: ``agrinerf-synth --scene orchard --lighting bright --views N`` (cached under ``--work``), then
``poses.run_sfm`` on its RGB frames (the RGB camera's calibration, as ``agrinerf-process --poses sfm-rgb`` does),
once per matching mode (exhaustive only up to ``--exhaustive-max`` frames). Reported per run: wall time (feature
extraction + matching + mapping), registered fraction, and the pose error of the registered frames against the
truth (``poses.pose_errors``: rotation after the best common rotation, translation after a similarity, as a fraction
of the path length). Results are appended to ``results.jsonl`` after every run (a rerun skips what is there), then
``results.md`` (table, command, machine) and ``scaling.png`` (log-log wall time with a linear reference) are written.
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import tyro


@dataclass
class Args:
    out: Path = Path("results/sfm-scaling")
    """Folder for results.jsonl, results.md, scaling.png."""
    work: Path = Path("/tmp/agrinerf_bench_sfm")
    """Scratch folder (synthetic captures, SfM work folders)."""
    sizes: Tuple[int, ...] = (40, 160, 640)
    """Sequence lengths (frames)."""
    modes: Tuple[str, ...] = ("sequential", "exhaustive")
    """Matching modes to time."""
    exhaustive_max: int = 160
    """Skip exhaustive matching above this many frames."""
    mapper: str = "incremental"
    """incremental or global."""
    width: int = 96
    height: int = 72
    seed: int = 0
    sfm_overrides: Dict[str, int] = field(default_factory=dict)
    """Extra SfmConfig fields (e.g. sequential_overlap)."""


def capture(args: Args, n: int) -> Path:
    from agrinerf_ns.synth import SynthConfig, generate_capture

    raw = args.work / f"orchard-bright-{n}-{args.width}x{args.height}-s{args.seed}"
    if not (raw / "rgb" / "timestamps.txt").is_file():
        cfg = SynthConfig(
            scene="orchard",
            lighting="bright",
            views=n,
            width=args.width,
            height=args.height,
            heldout=2,
            event_substeps=1,
            seed=args.seed,
        )
        generate_capture(cfg, raw)
    return raw


def run_one(args: Args, n: int, mode: str) -> Dict:
    from agrinerf_ns.process import poses, readers
    from agrinerf_ns.trajectory import read_tum

    raw = capture(args, n)
    calib = readers.read_calibration(raw / "calib.yaml")
    frames = readers.read_timestamps(raw / "rgb")
    images = [readers.read_rgb(p) for p in frames.paths]
    cfg = poses.SfmConfig(matching=mode, mapper=args.mapper, **args.sfm_overrides)
    work = args.work / f"sfm-{n}-{mode}-{args.mapper}"
    t0 = time.perf_counter()
    res = poses.run_sfm(images, calib.rgb.K, work, cfg, "sfm-rgb")
    wall = time.perf_counter() - t0
    t_true, c2w_true = read_tum(raw / "truth" / "poses.txt")
    idx = poses.match_times(frames.times, t_true, 1e-6)
    ok = res.registered & (idx >= 0)
    path_len = float(np.linalg.norm(np.diff(c2w_true[:, :3, 3], axis=0), axis=1).sum())
    row = {
        "frames": n,
        "matching": mode,
        "mapper": args.mapper,
        "wall_s": round(wall, 1),
        "registered": int(res.num_registered),
        "registered_frac": round(res.num_registered / n, 3),
    }
    if ok.sum() >= 3:
        err = poses.pose_errors(res.c2w[ok], c2w_true[idx[ok]])
        row.update(
            rotation_deg_mean=round(err["rotation_deg_mean"], 3),
            translation_mean_frac=round(err["translation_mean"] / path_len, 4),
        )
    return row


def machine() -> str:
    cpu = next(
        (
            ln.split(":", 1)[1].strip()
            for ln in Path("/proc/cpuinfo").read_text().splitlines()
            if ln.startswith("model name")
        ),
        "unknown CPU",
    )
    return f"{cpu}, {len(os.sched_getaffinity(0))} cores"


def write_report(args: Args, rows: List[Dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cols = [
        "frames",
        "matching",
        "mapper",
        "wall_s",
        "registered",
        "registered_frac",
        "rotation_deg_mean",
        "translation_mean_frac",
    ]
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r.get(c, "-")) for c in cols) + " |" for r in rows]
    growth = []
    runs = sorted({(r["matching"], r["mapper"]) for r in rows})
    for mode, mapper in runs:
        by_n = {r["frames"]: r["wall_s"] for r in rows if (r["matching"], r["mapper"]) == (mode, mapper)}
        ns = sorted(by_n)
        for a, b in zip(ns[:-1], ns[1:], strict=True):
            growth.append(
                f"- {mode} / {mapper}: {a} -> {b} frames ({b / a:.0f}x): wall time x{by_n[b] / max(by_n[a], 1e-9):.2f}"
            )
    text = (
        "# SfM wall time against sequence length\n\n"
        f"Command: `python benchmarks/bench_sfm_scaling.py {' '.join(sys.argv[1:])}`\n\n"
        f"Machine: {machine()}; pycolmap {__import__('pycolmap').__version__}, 1 thread (SfmConfig.num_threads). "
        f"Synthetic bright orchard, {args.width}x{args.height} RGB at 10 fps, 0.75 m/s; wall time = feature extraction "
        "+ matching + mapping; rotation error after the best common rotation, translation error after a "
        "similarity, as a fraction of the path length.\n\n"
        + "\n".join(lines)
        + "\n\nGrowth:\n"
        + "\n".join(growth)
        + "\n"
    )
    (args.out / "results.md").write_text(text)
    fig, ax = plt.subplots(figsize=(5, 3.5))
    for mode, mapper in runs:
        rs = sorted((r["frames"], r["wall_s"]) for r in rows if (r["matching"], r["mapper"]) == (mode, mapper))
        ax.loglog([r[0] for r in rs], [r[1] for r in rs], "o-", label=f"{mode} / {mapper}")
    ref = ("sequential", "incremental") if ("sequential", "incremental") in runs else runs[0]
    seq = sorted((r["frames"], r["wall_s"]) for r in rows if (r["matching"], r["mapper"]) == ref)
    if len(seq) > 1:
        n0, t0 = seq[-2]
        ns = np.array([r[0] for r in seq])
        ax.loglog(ns, t0 * ns / n0, "k:", label=f"linear through {ref[0]} / {ref[1]} at {n0}")
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    ax.set_xticks(sorted({r["frames"] for r in rows}))
    ax.xaxis.set_major_formatter(ScalarFormatter())
    ax.xaxis.set_minor_formatter(NullFormatter())
    ax.set_xlabel("frames")
    ax.set_ylabel("SfM wall time (s)")
    ax.legend(loc="upper left", fontsize=8)
    fig.tight_layout()
    fig.savefig(args.out / "scaling.png", dpi=120)


def main(args: Args) -> List[Dict]:
    args.out.mkdir(parents=True, exist_ok=True)
    log = args.out / "results.jsonl"
    rows = [json.loads(ln) for ln in log.read_text().splitlines()] if log.is_file() else []
    for n in args.sizes:
        for mode in args.modes:
            if mode == "exhaustive" and n > args.exhaustive_max:
                continue
            if any(r["frames"] == n and r["matching"] == mode and r["mapper"] == args.mapper for r in rows):
                continue
            row = run_one(args, n, mode)
            print(json.dumps(row), flush=True)
            rows.append(row)
            with open(log, "a") as fh:
                fh.write(json.dumps(row) + "\n")
    write_report(args, rows)
    return rows


if __name__ == "__main__":
    main(tyro.cli(Args))
