"""What the blur model and the event loss cost per training step: seconds (interleaved in one process) and peak
memory (one process per part), as ratios to the RGB TensoRF alone.

    python benchmarks/bench_event_speed.py --data outputs/deblur/scenes/orchard-dusk/data --out results/event-speed

Every part is AgriNeRF-lite's RGB module on the same dataset with one option changed (``PARTS``). Seconds: the
parts take training steps in turn in one process, the order rotating every round, so a busy machine slows all of
them alike; the ratio is the median of the per-round ratios. Peak memory: each part alone in a child process, its
peak resident set after the steps minus that of the same process before the first step. Writes
``OUT/event_speed.md`` and ``OUT/event_speed.png``.
"""

from __future__ import annotations

import json
import statistics
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Tuple

import torch
import tyro

from agrinerf_ns.lab.stepper import MethodStepper
from agrinerf_ns.machine import device_name
from agrinerf_ns.run_order import rotated

EVENTS: Dict[str, Any] = dict(
    modalities=("rgb", "events"),
    cross_spectral_output=False,
    event_supervision="stream",
    event_loss_weighting="noise",
    low_light_event_loss=True,
)
PARTS: Dict[str, Dict[str, Any]] = {
    "RGB TensoRF": dict(modalities=("rgb",)),
    "blur K=3": dict(modalities=("rgb",), blur_samples=3),
    "blur K=5": dict(modalities=("rgb",), blur_samples=5),
    "events 256": dict(EVENTS, event_rays_per_batch=256),
    "events 1024": dict(EVENTS, event_rays_per_batch=1024),
    "blur K=3 + events 256": dict(EVENTS, blur_samples=3, event_rays_per_batch=256),
    "EvDeblurNeRF as published": dict(
        EVENTS,
        event_loss_weighting="fixed",
        event_supervision="pairs",
        event_rays_per_batch=4096,
        event_crf=True,
        event_crf_start_step=0,
        blur_kernel="learnt",
        blur_samples=10,
        blur_start_step=0,
        edi_prior=True,
    ),  # fmt: skip
}
"""Part -> AgriNeRF-lite model options (the event loss from the stream, noise-balanced; EvDeblurNeRF's recipe with its
kernel and event response on from step 0, as after its step 1200)."""


@dataclass
class Args:
    data: Path
    """A processed dataset with events and exposure intervals (e.g. a ``deblur`` bench scene's ``data``)."""
    out: Path = Path("results/event-speed")
    steps: int = 30
    """Timed rounds (one step of every part per round)."""
    warmup: int = 3
    rays_per_batch: int = 1024
    memory_steps: int = 5
    """Steps per part in the memory child processes."""


def _stepper(data: Path, rays: int, part: str) -> MethodStepper:
    return MethodStepper("agrinerf-lite", data, rays, model_overrides=PARTS[part])


def _status_kib(field: str) -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"no {field} in /proc/self/status")


def peak_memory_child(data: Path, rays: int, part: str, steps: int) -> None:
    """(In a child process) how far the resident set peaks above its level before the steps, printed as JSON in MiB:
    the peak is reset first (Linux: ``5`` into ``/proc/self/clear_refs``), so loading the dataset does not count."""
    stepper = _stepper(data, rays, part)
    Path("/proc/self/clear_refs").write_text("5")
    before = _status_kib("VmRSS")
    for step in range(steps):
        stepper.step(step)
    print(json.dumps({"growth_mib": (_status_kib("VmHWM") - before) / 1024}))


def main(args: Args) -> None:
    torch.manual_seed(0)
    parts = list(PARTS)
    steppers = {part: _stepper(args.data, args.rays_per_batch, part) for part in parts}
    times: Dict[str, List[float]] = {part: [] for part in parts}
    for round_ in range(args.warmup + args.steps):
        for part in rotated(tuple(parts), round_):
            seconds = steppers[part].step(round_)
            if round_ >= args.warmup:
                times[part].append(seconds)
    del steppers
    memory: Dict[str, Dict[str, float]] = {}
    for part in parts:
        code = (
            "import sys, json; from pathlib import Path; sys.path.insert(0, 'benchmarks'); import bench_event_speed as b;"
            f" b.peak_memory_child(Path({str(args.data)!r}), {args.rays_per_batch}, {part!r}, {args.memory_steps})"
        )
        out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
        memory[part] = json.loads(out.strip().splitlines()[-1])
    base = times[parts[0]]
    rows: List[Tuple[str, float, float, float, float]] = []
    for part in parts:
        ratio = statistics.median(t / b for t, b in zip(times[part], base, strict=True))
        growth = memory[part]["growth_mib"] / max(memory[parts[0]]["growth_mib"], 1e-9)
        rows.append((part, statistics.median(times[part]), ratio, memory[part]["growth_mib"], growth))
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# Step time and memory of the blur model and the event loss",
        "",
        f"Command: `python benchmarks/bench_event_speed.py --data {args.data} --out {args.out} --steps {args.steps}`",
        "",
        f"Machine: {device_name()}. AgriNeRF-lite's RGB module, {args.rays_per_batch} RGB rays per batch, the initial "
        f"grid (no upsampling); seconds: {args.steps} interleaved rounds after {args.warmup} untimed; memory: peak "
        f"resident-set growth over {args.memory_steps} steps, each part in its own process.",
        "",
        "| part | median s/step | s/step / RGB's (median per round) | peak RSS growth MiB | / RGB's |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {p} | {s:.3f} | {r:.2f} | {m:.0f} | {g:.2f} |" for p, s, r, m, g in rows]
    (args.out / "event_speed.md").write_text("\n".join(lines) + "\n")
    plot(rows, args.out / "event_speed.png")
    print("\n".join(lines))


def plot(rows, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.barh([r[0] for r in rows][::-1], [r[2] for r in rows][::-1])
    ax.set_xlabel("seconds per step / RGB TensoRF's")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


if __name__ == "__main__":
    main(tyro.cli(Args))
