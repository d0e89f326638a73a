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
from typing import List, Tuple

import numpy as np
import tyro

from agrinerf_ns.machine import device_name


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


def fidelity(args: Args, substeps: int, supersample: int, ideal: bool) -> Tuple[float, float, float, float, int]:
    """(squared residual, 'no change' squared target, correlation, least-squares gain of the target onto the truth
    change, events) averaged over the windows."""
    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.capture import (
        EVENT_EPS,
        event_substeps,
        event_times,
        make_scene,
        render_radiance,
        simulate_events,
    )
    from agrinerf_ns.synth.scene import LIGHTING_PRESETS, rec709_luminance

    config = SynthConfig(scene="orchard", lighting="dusk", views=args.views, width=128, height=96, speed=2.0,
                         seed=args.seed, event_substeps=substeps, event_supersample=supersample)  # fmt: skip
    if ideal:
        config = config.replace(event_refractory_us=0, event_noise_hz=0.0, event_threshold_sigma=0.0)
    scene, rig = make_scene(config)
    light, cam = LIGHTING_PRESETS[config.lighting], rig.cams["event"]
    steps, _ = event_substeps(config, scene, rig)
    x, y, t, p = simulate_events(config, scene, rig, light, steps)
    times = event_times(config, steps)

    def log_lum(tt: float) -> np.ndarray:
        rad, _ = render_radiance(scene, cam, rig.pose(tt, "event"), light, supersample)
        return np.log(rec709_luminance(rad.reshape(-1, 3)) + EVENT_EPS)

    pixel = y.astype(np.int64) * cam.width + x
    rng = np.random.default_rng(1)
    stats: List[Tuple[float, float, float, float]] = []
    for _ in range(args.windows):
        a = float(rng.uniform(times[1], times[-2]))
        b = min(a + float(rng.uniform(0.025, 0.1)), float(times[-1]))
        m = (t >= round(a * 1e6)) & (t < round(b * 1e6))
        target = config.event_threshold * np.bincount(pixel[m], np.where(p[m] > 0, 1.0, -1.0),
                                                      minlength=cam.width * cam.height)  # fmt: skip
        change = log_lum(b) - log_lum(a)
        stats.append((float(np.mean((change - target) ** 2)), float(np.mean(target**2)),
                      float(np.corrcoef(change, target)[0, 1]), float(change @ target / (change @ change))))  # fmt: skip
    mean = np.mean(np.array(stats), axis=0)
    return float(mean[0]), float(mean[1]), float(mean[2]), float(mean[3]), int(t.size)


def main(args: Args) -> None:
    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.capture import event_substeps, make_scene

    base = SynthConfig(scene="orchard", lighting="dusk", views=args.views, width=128, height=96, speed=2.0)
    scene, rig = make_scene(base)
    _, motion_per_render = event_substeps(base.replace(event_substeps=1), scene, rig)  # motion per frame interval
    lines = ["| simulation | image motion between renders (px) | squared residual | 'no change' | correlation | gain "
             "| events |", "|---|---|---|---|---|---|---|"]  # fmt: skip
    for label, substeps, supersample, ideal in SETTINGS:
        sq, none, corr, gain, n = fidelity(args, substeps, supersample, ideal)
        lines.append(f"| {label} | {motion_per_render / substeps:.2f} | {sq:.3f} | {none:.3f} | {corr:.3f} | "
                     f"{gain:.2f} | {n} |")  # fmt: skip
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
