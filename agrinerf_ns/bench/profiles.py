"""Benchmark profiles: scene size, step budget per method, checkpoints per run, rays per batch."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Dict, Optional, Tuple


@dataclass(frozen=True)
class BenchProfile:
    """How big the scenes are and how long each method trains."""

    views: int
    width: int
    height: int
    steps: Dict[str, int]
    """Training steps per method (keys of ``agrinerf_ns.bench.methods.METHODS``): per-method budgets that take
    comparable wall time, so the curves overlap in time."""
    evaluations: int
    """Checkpoints evaluated per run, evenly spaced in steps (each is one point of the quality/time curve)."""
    eval_views: Optional[int] = None
    """Held-out views rendered per checkpoint, evenly spaced (None: all of them)."""
    rays_per_batch: int = 1024
    """The same for every method (the paper's 1024)."""
    scenes: Tuple[str, ...] = ("orchard-dark", "orchard-shadowed")
    """``<scene>-<lighting>`` synthetic captures."""
    extra_args: Dict[str, Tuple[str, ...]] = field(default_factory=dict)
    """Extra ``ns-train`` options per method."""
    eval_every: int = 8
    """Every n-th frame of a scene is held out (``agrinerf-process --eval-every``)."""
    plane_depth: float = float("inf")
    """Depth (m, RGB camera frame) of the plane the thermal and event frames are warped at (``agrinerf-process
    --plane-depth``): objects at that depth land on their RGB pixels, others shift by the parallax of the cameras'
    baseline."""


PROFILES: Dict[str, BenchProfile] = {
    # CPU, 2 cores, both scenes in about 30 minutes (measured 31 min 41 s with ~25% of the CPU stolen by the host):
    # about 2 minutes of training per method and scene (steady state on a quiet 2-core machine, dark orchard:
    # agrinerf-lite 0.22, agrinerf 0.70, tensorf 0.58, nerfacto 2.4 s per step at 1024 rays; budgets of
    # 1200/300/90/90/200 steps took 47 minutes for both scenes).
    "quick": BenchProfile(
        views=16, width=96, height=72,
        steps={"agrinerf-lite": 500, "agrinerf": 150, "nerfacto": 40, "nerfacto-thermal": 40, "tensorf": 160},
        evaluations=3, rays_per_batch=1024,
    ),
    # A GPU at the paper's settings: 30k steps of every method on the default scene size.
    "full": BenchProfile(
        views=40, width=160, height=120,
        steps={"agrinerf-lite": 30000, "agrinerf": 30000, "nerfacto": 30000, "nerfacto-thermal": 30000,
               "tensorf": 30000},
        evaluations=6, rays_per_batch=1024,
    ),
    # Downstream detection on a CPU (agrinerf-detect evaluate --bench): the dark garden at 320x240, so that fruits are
    # about 10 px wide in RGB and 5 px in the 160x128 thermal frames; 5-13 minutes of training per method on the 2-core
    # CPU (docs/detect_results/garden_60views/bench_results.md).
    # 60 views: 24 (21 training frames) left the thermal detector too few images to learn from
    # (docs/detect_results/garden_dark_plane1.57); it now also starts from the RGB detector. Thermal frames are warped
    # at 1.57 m, near the fruit the views show: `python -m agrinerf_ns.process.evaluate` gives visible_fruit_depth_m
    # median 1.48 m (quartiles 1.36-1.56, 804 boxes of >= 30 pixels; 0.7 px of parallax from 1.57 m). At infinity the
    # thermal camera's 7 cm baseline (f = 246 px) put fruit 11 px beside their boxes. Three held-out views per
    # checkpoint: the detection evaluation renders its own views, and Nerfacto takes 2-3.5 min a 320x240 view here.
    "detect": BenchProfile(
        views=60, width=320, height=240,
        steps={"agrinerf-lite": 1500, "agrinerf": 500, "nerfacto": 150, "nerfacto-thermal": 110, "tensorf": 400},
        evaluations=1, eval_views=3, rays_per_batch=1024, scenes=("garden-dark",), plane_depth=1.57,
    ),
    # Table IV in PSNR (modality ablations of AgriNeRF-lite at equal steps), every lighting of both scenes: 32 views
    # with every 4th held out give 8 held-out views per run, enough for paired per-view intervals.
    "ablation": BenchProfile(
        views=32, width=96, height=72,
        steps={"agrinerf-lite": 500, "agrinerf": 150, "nerfacto": 40, "nerfacto-thermal": 40, "tensorf": 160},
        evaluations=1, eval_every=4,
        scenes=tuple(f"{s}-{light}" for s in ("orchard", "garden") for light in ("bright", "shadowed", "dusk", "dark")),
    ),
    # The machinery end to end in a test: minutes on a CPU.
    "tiny": BenchProfile(
        views=8, width=64, height=48,
        steps={"agrinerf-lite": 8, "agrinerf": 4, "nerfacto": 4, "nerfacto-thermal": 4, "tensorf": 4},
        evaluations=2, rays_per_batch=128, scenes=("orchard-dark",),
    ),
}  # fmt: skip
