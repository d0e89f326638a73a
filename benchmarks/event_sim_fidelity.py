"""How faithfully the synthetic event camera counts the truth: C (N_on - N_off) against the truth log-intensity change
of the same pixels over random windows, for several ways of simulating it (the simulator alone: no dataset, no model).

    python benchmarks/event_sim_fidelity.py --out results/event-sim

Each row simulates the event camera along a dusk orchard's path (rig at 2 m/s, RGB 128x96, so the event camera is
102x57) with one setting changed: renders per frame interval (``event_substeps``, the image motion between renders
in brackets), rays per pixel per axis (``event_supersample``), and the sensor (the default realistic camera: 1 ms
refractory period, threshold spread 0.03; or an ideal one: neither). The truth is the log of the pixel's
area-integrated luminance at the window's ends, as the simulator's pixels see it. Writes ``OUT/fidelity.md``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Tuple

import tyro

from agrinerf_ns.machine import device_name
from agrinerf_ns.synth import SynthConfig
from agrinerf_ns.synth.capture import event_substeps, make_scene
from agrinerf_ns.synth.event_fidelity import EventFidelity, event_fidelity


@dataclass
class Args:
    out: Path = Path("results/event-sim")
    views: int = 6
    """Frames of the path (the windows lie inside it)."""
    windows: int = 10
    """Random windows of 25-100 ms per row."""
    seed: int = 0


SETTINGS: Tuple[Tuple[str, int, int, bool], ...] = (
    ("ideal camera, point pixels, 6 renders per frame (before)", 6, 1, True),
    ("ideal camera, point pixels, 61 renders per frame", 61, 1, True),
    ("ideal camera, 3x3 area pixels, 6 renders per frame", 6, 3, True),
    ("ideal camera, 3x3 area pixels, 24 renders per frame", 24, 3, True),
    ("ideal camera, 3x3 area pixels, 61 renders per frame", 61, 3, True),
    ("realistic camera, point pixels, 6 renders per frame (before)", 6, 1, False),
    ("realistic camera, point pixels, 61 renders per frame", 61, 1, False),
    ("realistic camera, 2x2 area pixels, 61 renders per frame", 61, 2, False),
    ("realistic camera, 3x3 area pixels, 24 renders per frame (default)", 24, 3, False),
    ("realistic camera, 3x3 area pixels, 61 renders per frame (deblur profiles)", 61, 3, False),
)
"""Row label, renders per frame interval, rays per pixel per axis, ideal sensor."""


def fidelity(args: Args, substeps: int, supersample: int, ideal: bool) -> EventFidelity:
    """One row's camera, simulated and scored (``agrinerf_ns.synth.event_fidelity``)."""
    config = SynthConfig(scene="orchard", lighting="dusk", views=args.views, width=128, height=96, speed=2.0,
                         seed=args.seed, event_substeps=substeps, event_supersample=supersample)  # fmt: skip
    if ideal:
        config = config.replace(event_refractory_us=0, event_noise_hz=0.0, event_threshold_sigma=0.0)
    return event_fidelity(config, windows=args.windows, min_window_s=0.025)


def main(args: Args) -> None:
    base = SynthConfig(scene="orchard", lighting="dusk", views=args.views, width=128, height=96, speed=2.0)
    scene, rig = make_scene(base)
    _, motion_per_render = event_substeps(base.replace(event_substeps=1), scene, rig)  # motion per frame interval
    lines = ["| simulation | image motion between renders (px) | squared residual | 'no change' | correlation | gain "
             "| events |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for label, substeps, supersample, ideal in SETTINGS:
        f = fidelity(args, substeps, supersample, ideal)
        lines.append(f"| {label} | {motion_per_render / substeps:.2f} | {f.squared_residual:.3f} | {f.no_change:.3f} | "
                     f"{f.correlation:.3f} | {f.gain:.2f} | {f.events} |")  # fmt: skip
        print(lines[-1], flush=True)
    text = (
        "# The synthetic event camera against the truth\n\n"
        f"Command: `python benchmarks/event_sim_fidelity.py {' '.join(sys.argv[1:])}`\n\n"
        f"Machine: {device_name()}. Dusk orchard, rig at 2 m/s, {args.views} frames, event camera 102x57; "
        f"{args.windows} random windows of 25-100 ms. Squared residual: mean over pixels and windows of (truth log "
        "change - C (N_on - N_off))^2; 'no change': the same for a prediction of 0; gain: the least-squares factor "
        "from the truth change to the target (1 = counts the whole change).\n\n" + "\n".join(lines) + "\n"
    )
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "fidelity.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main(tyro.cli(Args))
