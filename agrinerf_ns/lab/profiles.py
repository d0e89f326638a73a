"""Benchmark profiles: scene size, step budget per method, checkpoints per run, rays per batch."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Literal, Optional, Tuple


@dataclass(frozen=True)
class BenchProfile:
    """How big the scenes are and how long each method trains."""

    views: int
    width: int
    height: int
    steps: Dict[str, int]
    """Training steps per method (keys of ``agrinerf_ns.lab.methods.METHODS``): per-method budgets that take
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
    synth: Dict[str, Any] = field(default_factory=dict)
    """Further ``SynthConfig`` fields of the scenes (e.g. ``speed``)."""
    process: Dict[str, Any] = field(default_factory=dict)
    """Further ``ProcessConfig`` fields of the scenes' datasets (e.g. ``fruit_mask_maker``)."""
    count: bool = False
    """Also count the fruit of every finished run (``count_rule`` says how)."""
    count_rule: Literal["paths", "row"] = "paths"
    """``paths``: every path and source of every run, beside the oracle's ceilings (``OUT/count.csv``,
    ``OUT/count.md``: ``agrinerf_ns.lab.count_bench``); ``row``: the fruit channel in the views, on the whole capture
    and on the row the rig drove (``row_range``), beside the truth-mask oracle of each capture, tabulated over seeds
    and lightings (``OUT/count-row/``, ``OUT/counts.md``: ``agrinerf_ns.lab.count_row_bench``)."""
    row_range: Dict[str, float] = field(default_factory=dict)
    """Per scene kind (``orchard``, ``garden``): the ``agrinerf-count --max-range`` of the row the rig drove (metres):
    the rig's standoff from the row plus half the spacing to the next row, figures a grower knows of their own block
    (the synthetic scenes' from ``agrinerf_ns/synth/rig.py`` and ``scene.py``), never read from the truth."""
    methods: Optional[Tuple[str, ...]] = None
    """The methods run when ``--methods`` is not given (None: every method but the sample-budget variants)."""


PROFILES: Dict[str, BenchProfile] = {
    # A 2-core CPU: both orchards in about half an hour, budgets of about equal training time per method
    # (measurements: docs/bench_profiles.md).
    "quick": BenchProfile(
        views=16, width=96, height=72,
        steps={"agrinerf-lite": 825, "evdeblurnerf-lite": 500, "agrinerf": 390, "nerfacto": 40, "nerfacto-thermal": 40, "tensorf": 160},
        evaluations=3, rays_per_batch=1024,
    ),
    # A GPU at the paper's settings: 30k steps of every method on the default scene size.
    "full": BenchProfile(
        views=40, width=160, height=120,
        steps={"agrinerf-lite": 30000, "evdeblurnerf-lite": 30000, "agrinerf": 30000, "nerfacto": 30000, "nerfacto-thermal": 30000,
               "tensorf": 30000},
        evaluations=6, rays_per_batch=1024,
    ),
    # Downstream detection on a CPU (agrinerf-detect evaluate --bench): the dark garden at a size where fruit are a few
    # pixels wide in the thermal frames, enough training views for the thermal detector, thermal frames warped at the
    # rig's standoff from the row (1.55 m, what a user sets from how the rig drives, never from the truth), and few
    # held-out views per checkpoint (the detection evaluation renders its own).
    # Why these numbers: docs/bench_profiles.md.
    "detect": BenchProfile(
        views=60, width=320, height=240,
        steps={"agrinerf-lite": 1500, "evdeblurnerf-lite": 1500, "agrinerf": 500, "nerfacto": 150, "nerfacto-thermal": 110, "tensorf": 400},
        evaluations=1, eval_views=3, rays_per_batch=1024, scenes=("garden-dark",), plane_depth=1.55,
    ),
    # Table IV in PSNR (modality ablations of AgriNeRF-lite at equal steps), every lighting of both scenes; enough
    # held-out views per run for paired per-view intervals.
    "ablation": BenchProfile(
        views=32, width=96, height=72,
        steps={"agrinerf-lite": 825, "evdeblurnerf-lite": 500, "agrinerf": 390, "nerfacto": 40, "nerfacto-thermal": 40, "tensorf": 160},
        evaluations=1, eval_every=4,
        scenes=tuple(f"{s}-{light}" for s in ("orchard", "garden") for light in ("bright", "shadowed", "dusk", "dark")),
    ),
    # Motion blur that events can remove (EvDeblurNeRF's setting, Tables I/II): a rig at tractor speed (2 m/s, 7 km/h)
    # in dim light, so that the RGB frames' motion blur is several pixels at a CPU's image size, and the lite model's
    # grid at its final size early (by step 300, at 128 voxels a side), finer than the blur.
    # EvDeblurNeRF's learnt blur kernel and event response start at step 1200 (as published): its budget runs 400
    # steps past that, so that every schedule has started.
    "deblur": BenchProfile(
        views=32, width=128, height=96,
        steps={"agrinerf-lite": 800, "evdeblurnerf-lite": 1600, "agrinerf": 240, "nerfacto": 60, "nerfacto-thermal": 60, "tensorf": 250},
        evaluations=1, eval_every=4, scenes=("orchard-dusk", "orchard-dark", "garden-dusk"),
        synth={"speed": 2.0, "event_step_px": 0.1},
        extra_args={"agrinerf-lite": ("--pipeline.model.upsampling-iters", "100", "200", "300",
                                      "--pipeline.model.final-resolution", "128"),
                    "evdeblurnerf-lite": ("--pipeline.model.upsampling-iters", "100", "200", "300",
                                          "--pipeline.model.final-resolution", "128")},
    ),
    # The same with an ideal event camera (no refractory period, no noise events, one contrast threshold): what the
    # event loss can do when its targets hold.
    "deblur-ideal-events": BenchProfile(
        views=32, width=128, height=96,
        steps={"agrinerf-lite": 800, "evdeblurnerf-lite": 1600, "agrinerf": 240, "nerfacto": 60, "nerfacto-thermal": 60,
               "tensorf": 250},
        evaluations=1, eval_every=4, scenes=("orchard-dusk",),
        synth={"speed": 2.0, "event_step_px": 0.1, "event_refractory_us": 0, "event_noise_hz": 0.0,
               "event_threshold_sigma": 0.0},
        extra_args={"agrinerf-lite": ("--pipeline.model.upsampling-iters", "100", "200", "300",
                                      "--pipeline.model.final-resolution", "128")},
    ),
    # Fruit counted at realistic sizes (#60; docs/bench_profiles.md): the cameras' fields of view narrowed to 22 and
    # 20 degrees so that a fruit is 15-18 px across at 320x240 (docs/count.md), fruit masks made by the product
    # (colour in light, thermal bodies in the dark), agrinerf-lite 3000 steps x 1024 rays, every run counted from its
    # fruit channel on the whole capture and on the row the rig drove, beside the truth-mask oracle, and tabulated
    # over seeds and lightings (OUT/counts.md). About 25 CPU-minutes per run on a 2-core AMD EPYC.
    "count": BenchProfile(
        views=48, width=320, height=240,
        steps={"agrinerf-lite": 3000, "evdeblurnerf-lite": 3000, "agrinerf": 900, "nerfacto": 250, "nerfacto-thermal": 250, "tensorf": 1000},
        evaluations=1, eval_views=3, count=True, count_rule="row", methods=("agrinerf-lite",),
        scenes=tuple(f"{s}-{light}" for s in ("garden", "orchard") for light in ("bright", "shadowed", "dusk", "dark")),
        synth={"rgb_hfov_deg": 22.0, "thermal_hfov_deg": 20.0, "event_substeps": 1},
        process={"fruit_mask_maker": "auto"},
        row_range={"garden": 2.4, "orchard": 4.7},  # standoffs 1.55 and 2.8 m, next row 1.7 and 3.8 m behind
    ),
    # The earlier count profile (``count`` until #60; the tables of results/count-3d, count-seeds, count-detect and
    # others name it): fruit counted from trained runs on a CPU by every path and source (OUT/count.csv, count.md),
    # frames large enough that a fruit covers a median 12 visible pixels in RGB and 4 in the half-width thermal camera
    # (measured from the truth boxes, docs/count.md), and more views so that more fruit are seen twice; one run (train
    # and count) in 30 minutes.
    "count-small": BenchProfile(
        views=48, width=200, height=150,
        steps={"agrinerf-lite": 3000, "evdeblurnerf-lite": 3000, "agrinerf": 900, "nerfacto": 250, "nerfacto-thermal": 250, "tensorf": 1000},
        evaluations=1, eval_views=3, count=True,
        scenes=tuple(f"{s}-{light}" for s in ("orchard", "garden") for light in ("bright", "shadowed", "dusk", "dark")),
    ),
    # The machinery end to end in a test: minutes on a CPU.
    "tiny": BenchProfile(
        views=8, width=64, height=48,
        steps={"agrinerf-lite": 8, "evdeblurnerf-lite": 8, "agrinerf": 4, "nerfacto": 4, "nerfacto-thermal": 4, "tensorf": 4},
        evaluations=2, rays_per_batch=128, scenes=("orchard-dark",),
    ),
}  # fmt: skip
