"""Render time and peak memory of a trained run against ``eval_num_rays_per_chunk``.

    python benchmarks/bench_render_chunks.py --config outputs/<name>/<method>/<time>/config.yml \
        --out outputs/render-chunks [--chunks 4096 32768] [--views 1] [--rounds 2]

A full view is rendered in chunks of rays (``Model.get_outputs_for_camera``); the chunk size is the run config's
``eval_num_rays_per_chunk`` (Nerfacto 32768, AgriNeRF 8192) unless the caller overrides it, as ``ns-eval``,
``agrinerf-bench`` and ``agrinerf-detect`` can. Each (round, chunk size) is a fresh process, so its peak resident set
size (``ru_maxrss``) is that chunk size's own; the chunk sizes take turns within a round and the order rotates every
round, so the time ratios are paired. Every process saves its renders; the table reports the largest difference to
the first chunk size's (chunking must not change the image). Writes ``OUT/render_chunks.csv`` (every process) and
``OUT/render_chunks.md`` (medians, paired time ratio to the first chunk size).
"""

from __future__ import annotations

import csv
import json
import resource
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import numpy as np
import tyro

from agrinerf_ns.run_order import rotated


@dataclass
class Args:
    config: Path
    """A trained run's ``config.yml``."""
    out: Path = Path("outputs/render-chunks")
    """Where ``render_chunks.csv``, ``render_chunks.md`` and the renders go."""
    chunks: Tuple[int, ...] = (4096, 32768)
    """Rays per chunk to compare; ratios are to the first."""
    views: int = 1
    """Held-out views rendered per process (evenly spaced)."""
    rounds: int = 2
    """Processes per chunk size."""
    child: Optional[int] = None
    """Internal: render with this chunk size in this process, save the renders to ``out`` (.npz), print one JSON
    line."""


def render_in_process(config: Path, chunk: int, views: int, out: Path) -> Dict[str, float]:
    """Load the run with ``chunk`` rays per chunk, render ``views`` held-out views (all outputs), save them to ``out``
    (``.npz``); returns seconds spent rendering and peak RSS (MiB) after loading and after rendering."""
    from agrinerf_ns.run_loading import load_run, render_camera
    from agrinerf_ns.views import evenly_spaced

    run = load_run(config, eval_num_rays_per_chunk=chunk)
    loaded_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    dataset = run.pipeline.datamanager.eval_dataset
    arrays: Dict[str, np.ndarray] = {}
    pixels = 0
    start = time.perf_counter()
    for index in evenly_spaced(len(dataset), views):
        for name, value in render_camera(run, dataset, index).items():
            arrays[f"{index}_{name}"] = value.detach().float().cpu().numpy()
        pixels += int(dataset.cameras.height[index]) * int(dataset.cameras.width[index])
    seconds = time.perf_counter() - start
    peak_mib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, **arrays)
    return {"seconds": seconds, "loaded_mib": loaded_mib, "peak_mib": peak_mib, "pixels": pixels}


def max_difference(a: Path, b: Path) -> float:
    """Largest absolute difference over the outputs both render files hold; equal values (NaN and NaN, inf and inf)
    differ by 0, a NaN against anything else by inf."""
    with np.load(a) as x, np.load(b) as y:
        common = sorted(set(x.files) & set(y.files))
        if not common:
            raise ValueError(f"{a} and {b} share no rendered output")
        return max(_difference(x[k], y[k]) for k in common)


def _difference(a: np.ndarray, b: np.ndarray) -> float:
    with np.errstate(invalid="ignore"):
        diff = np.abs(a - b)
    diff[(a == b) | (np.isnan(a) & np.isnan(b))] = 0.0
    return float(np.nan_to_num(diff, nan=np.inf).max())


def _run_child(args: Args, chunk: int, round_index: int) -> Dict[str, object]:
    npz = args.out / "renders" / f"chunk{chunk}_round{round_index}.npz"
    cmd = [sys.executable, str(Path(__file__).resolve()), "--config", str(args.config), "--out", str(npz),
           "--views", str(args.views), "--child", str(chunk)]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"render with {chunk} rays per chunk failed:\n{done.stderr[-3000:]}")
    return {**json.loads(done.stdout.strip().splitlines()[-1]), "npz": str(npz)}


def main(args: Args) -> List[Dict[str, object]]:
    """Run every (round, chunk size) process; write the CSV and the Markdown table; return the rows."""
    from agrinerf_ns.machine import device_name

    if args.child is not None:
        print(json.dumps(render_in_process(args.config, args.child, args.views, args.out)))
        return []
    if not args.config.is_file():
        raise FileNotFoundError(f"{args.config}: no such run config")
    rows: List[Dict[str, object]] = []
    for r in range(args.rounds):
        for chunk in rotated(args.chunks, r):
            result = _run_child(args, chunk, r)
            rows.append({"round": r, "chunk": chunk, **result})
            print(f"round {r} chunk {chunk}: {result['seconds']:.1f} s, peak {result['peak_mib']:.0f} MiB")
    first = args.chunks[0]
    reference = next(Path(str(row["npz"])) for row in rows if row["chunk"] == first)
    for row in rows:
        row["max_abs_diff"] = max_difference(reference, Path(str(row["npz"])))
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "render_chunks.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=["round", "chunk", "seconds", "loaded_mib", "peak_mib", "pixels",
                                                    "max_abs_diff", "npz"])  # fmt: skip
        writer.writeheader()
        writer.writerows(rows)
    by_round = {(row["round"], row["chunk"]): float(row["seconds"]) for row in rows}  # type: ignore[arg-type]
    lines = [
        f"Rendering {args.views} held-out view(s) of `{args.config}` per process, {args.rounds} round(s), "
        f"on {device_name()}.",
        "",
        f"Command: `python benchmarks/bench_render_chunks.py --config {args.config} --out {args.out} --chunks "
        f"{' '.join(map(str, args.chunks))} --views {args.views} --rounds {args.rounds}`",
        "",
        f"| rays per chunk | render s (median) | time ratio to {first} (paired median) | peak RSS MiB (median) | "
        "RSS after load MiB | max abs diff to first |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for chunk in args.chunks:
        mine = [row for row in rows if row["chunk"] == chunk]
        ratios = [by_round[(r, chunk)] / by_round[(r, first)] for r in range(args.rounds)]
        lines.append(
            f"| {chunk} | {statistics.median(float(m['seconds']) for m in mine):.1f} | "  # type: ignore[arg-type]
            f"{statistics.median(ratios):.3f} | {statistics.median(float(m['peak_mib']) for m in mine):.0f} | "  # type: ignore[arg-type]
            f"{statistics.median(float(m['loaded_mib']) for m in mine):.0f} | "  # type: ignore[arg-type]
            f"{max(float(m['max_abs_diff']) for m in mine):.2e} |"  # type: ignore[arg-type]
        )
    (args.out / "render_chunks.md").write_text("\n".join(lines) + "\n")
    return rows


if __name__ == "__main__":
    main(tyro.cli(Args))
