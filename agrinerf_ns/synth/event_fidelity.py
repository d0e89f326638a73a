"""How faithfully the synthetic event camera counts its own truth: C (N_on - N_off) of each pixel over random windows
against the truth log-intensity change of the same pixel (the simulator alone: no dataset, no model). Used by the
synth tests and ``benchmarks/event_sim_fidelity.py``."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from agrinerf_ns.synth.capture import event_log_luminance, event_substeps, event_times, make_scene, simulate_events
from agrinerf_ns.synth.config import SynthConfig
from agrinerf_ns.synth.scene import LIGHTING_PRESETS


@dataclass(frozen=True)
class EventFidelity:
    """Means over the windows (each a mean over the event pixels)."""

    squared_residual: float
    """(truth log change - C (N_on - N_off))^2."""
    no_change: float
    """(C (N_on - N_off))^2: the squared residual of predicting no change."""
    correlation: float
    """Pearson correlation of the truth change and the target."""
    gain: float
    """Least-squares factor from the truth change to the target (1: the camera counts the whole change)."""
    substeps: int
    """Event renders per frame interval the capture used."""
    events: int


def event_fidelity(config: SynthConfig, windows: int, min_window_s: float, max_window_s: float = 0.1) -> EventFidelity:
    """Simulate ``config``'s event camera along its path and score its counts over ``windows`` random windows (start
    uniform inside the path, length uniform in [``min_window_s``, ``max_window_s``]; a fixed window seed)."""
    scene, rig = make_scene(config)
    light, cam = LIGHTING_PRESETS[config.lighting], rig.cams["event"]
    substeps, _ = event_substeps(config, scene, rig)
    x, y, t, p = simulate_events(config, scene, rig, light, substeps)
    times = event_times(config, substeps)
    pixel = y.astype(np.int64) * cam.width + x
    rng = np.random.default_rng(1)
    stats = []
    for _ in range(windows):
        a = float(rng.uniform(times[1], times[-2]))
        b = min(a + float(rng.uniform(min_window_s, max_window_s)), float(times[-1]))
        m = (t >= round(a * 1e6)) & (t < round(b * 1e6))
        target = config.event_threshold * np.bincount(pixel[m], np.where(p[m] > 0, 1.0, -1.0),
                                                      minlength=cam.width * cam.height)  # fmt: skip
        change = event_log_luminance(config, scene, rig, light, b) - event_log_luminance(config, scene, rig, light, a)
        stats.append((np.mean((change - target) ** 2), np.mean(target**2), np.corrcoef(change, target)[0, 1],
                      change @ target / (change @ change)))  # fmt: skip
    mean = np.mean(np.array(stats, dtype=np.float64), axis=0)
    return EventFidelity(float(mean[0]), float(mean[1]), float(mean[2]), float(mean[3]), substeps, int(t.size))
