"""Configuration of a synthetic tri-modal capture: scene, lighting, rig and sensor sizes."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, Optional, Tuple

import tyro
from typing_extensions import Annotated

SCENES = ("orchard", "garden")
LIGHTINGS = ("bright", "shadowed", "dusk", "dark")
MAX_SUBFRAMES = 63
"""Most sub-frame renders per blurred RGB frame."""
MAX_EXPOSURE_FRACTION = 0.95
"""An auto-exposed frame's exposure is at most this fraction of the frame interval (the rest is readout)."""


class SynthConfigError(ValueError):
    """An invalid synthetic-capture argument (nothing has been written when this is raised)."""


@dataclass(frozen=True)
class SynthConfig:
    """A synthetic capture. The defaults are the documented default scene (40 frames, RGB 160x120)."""

    scene: Annotated[str, tyro.conf.arg(metavar="{orchard,garden}")] = "orchard"
    """Procedural scene: a row of fruit trees (orchard) or of staked fruiting plants (garden)."""
    lighting: Annotated[str, tyro.conf.arg(metavar="{bright,shadowed,dusk,dark}")] = "bright"
    """Visible lighting: bright, shadowed, dusk or dark. Thermal is independent of it; events see the linear
    radiance (high dynamic range)."""
    seed: int = 0
    """Seed of everything random: scene layout, temperatures, path wobble, sensor noise."""
    views: int = 40
    """Number of RGB (and thermal) frames along the path."""
    width: int = 160
    """RGB image width in pixels."""
    height: int = 120
    """RGB image height in pixels."""
    thermal_size: Optional[Tuple[int, int]] = None
    """Thermal (width, height); None derives 320x256-like from the RGB size (half the RGB width)."""
    event_size: Optional[Tuple[int, int]] = None
    """Event camera (width, height); None derives a 16:9 sensor of 0.8x the RGB width."""
    rgb_hfov_deg: float = 66.0
    """Horizontal field of view of the RGB camera (degrees): narrower shows the same fruit larger at the same frame
    size (docs/count.md: the realistic count profile)."""
    thermal_hfov_deg: float = 56.0
    """Horizontal field of view of the thermal camera (degrees)."""
    event_hfov_deg: float = 72.0
    """Horizontal field of view of the event camera (degrees)."""
    fps: float = 10.0
    """Frame rate of the RGB and thermal cameras."""
    speed: float = 0.75
    """Rig speed along the row in m/s."""
    heldout: Optional[int] = None
    """Number of held-out truth views off the path; None gives max(2, views // 5)."""
    event_substeps: Optional[int] = None
    """Event-camera renders per frame interval, fixed; None chooses them from ``event_step_px``."""
    event_step_px: float = 0.25
    """Largest image motion of the event camera between two of its renders (pixels, 95th percentile over its pixels).
    The simulator interpolates each pixel's log intensity linearly between renders, so a coarser step misses texture
    that crosses a pixel between two renders and under-reports the change; with ``event_supersample`` pixels a finer
    step changes little (docs/synth.md, Events; ``benchmarks/event_sim_fidelity.py``)."""
    event_supersample: int = 3
    """Rays per event pixel per axis, averaged in linear intensity. A real pixel integrates the light over its area, so
    an edge crossing it ramps its log intensity over the crossing time and its events spread in time; a point-sampled
    pixel jumps at once and the refractory period swallows most of the jump's events (docs/synth.md, Events)."""
    event_threshold: float = 0.2
    """Mean log-intensity contrast threshold of the event pixels."""
    event_threshold_sigma: float = 0.03
    """Pixel-to-pixel standard deviation of the contrast threshold."""
    event_refractory_us: int = 1000
    """Refractory period of an event pixel in microseconds."""
    event_noise_hz: float = 0.1
    """Background-activity noise rate per pixel in Hz (scaled up in dim lighting)."""
    motion_blur: bool = True
    """Render each RGB camera frame as the average of sub-frame renders across its exposure interval (the
    lighting's auto-exposure time: long at dusk and in the dark); off: instantaneous frames (zero-length exposure).
    The truth (truth/rgb_clean) is always the sharp mid-exposure frame."""
    exposure_s: Optional[float] = None
    """RGB exposure time in seconds; None: the lighting's auto-exposure time (bright 2 ms, shadowed 4 ms, dusk
    60 ms, dark 100 ms), at most 95 % of the frame interval."""
    blur_step_px: float = 1.0
    """Largest image motion between two sub-frames (pixels, 95th percentile over the frame's pixels): each frame
    gets the odd number of sub-frames that keeps its blur this smooth (1, i.e. sharp, when its blur is shorter)."""
    blur_subframes: Optional[int] = None
    """Sub-frames per RGB frame, fixed; None chooses them per frame from ``blur_step_px``."""
    rgb_supersample: int = 1
    """Supersampling factor per axis of the RGB renders (anti-aliasing)."""
    min_box_pixels: int = 3
    """A fruit gets a truth box in a view when at least this many of its pixels are visible."""

    def __post_init__(self) -> None:
        self.validate()

    @staticmethod
    def tiny(**overrides: object) -> "SynthConfig":
        """The tiny test scene: 8 frames, RGB 64x48, thermal 32x26, events 52x30."""
        base: Dict[str, object] = dict(views=8, width=64, height=48, heldout=2, event_substeps=4)
        base.update(overrides)
        return SynthConfig(**base)  # type: ignore[arg-type]

    def replace(self, **changes: object) -> "SynthConfig":
        """A copy with some fields changed."""
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]

    @property
    def thermal_wh(self) -> Tuple[int, int]:
        """Thermal resolution (width, height)."""
        if self.thermal_size is not None:
            return int(self.thermal_size[0]), int(self.thermal_size[1])
        w = max(8, self.width // 2)
        return w, max(8, round(w * 256 / 320))

    @property
    def event_wh(self) -> Tuple[int, int]:
        """Event camera resolution (width, height)."""
        if self.event_size is not None:
            return int(self.event_size[0]), int(self.event_size[1])
        w = max(8, round(self.width * 0.8))
        return w, max(8, round(w * 9 / 16))

    def rgb_exposure_s(self, lighting_exposure_s: float) -> float:
        """The RGB exposure time: ``exposure_s``, else the lighting's, capped at 95 % of the frame interval; 0 when
        motion blur is off (instantaneous frames)."""
        if not self.motion_blur:
            return 0.0
        if self.exposure_s is not None:
            return float(self.exposure_s)
        return float(min(lighting_exposure_s, MAX_EXPOSURE_FRACTION / self.fps))

    @property
    def num_heldout(self) -> int:
        """Number of held-out views."""
        return max(2, self.views // 5) if self.heldout is None else self.heldout

    def validate(self) -> None:
        """Raise SynthConfigError naming the first invalid field."""
        if self.scene not in SCENES:
            raise SynthConfigError(f"unknown scene {self.scene!r}: choose one of {', '.join(SCENES)}")
        if self.lighting not in LIGHTINGS:
            raise SynthConfigError(f"unknown lighting {self.lighting!r}: choose one of {', '.join(LIGHTINGS)}")
        if not isinstance(self.views, int) or self.views < 2:
            raise SynthConfigError(f"views must be an integer >= 2, got {self.views!r}")
        for name, (w, h) in (
            ("RGB", (self.width, self.height)),
            ("thermal", self.thermal_wh),
            ("event", self.event_wh),
        ):
            if not (isinstance(w, int) and isinstance(h, int)) or w < 8 or h < 8:
                raise SynthConfigError(f"{name} resolution must be at least 8x8 pixels, got {w}x{h}")
            if w * h > 4096 * 4096:
                raise SynthConfigError(f"{name} resolution {w}x{h} is too large for this renderer")
        for name, hfov in (
            ("rgb", self.rgb_hfov_deg),
            ("thermal", self.thermal_hfov_deg),
            ("event", self.event_hfov_deg),
        ):
            if not 1.0 <= hfov <= 170.0:
                raise SynthConfigError(f"{name}_hfov_deg must lie in 1 .. 170 degrees, got {hfov}")
        if not self.fps > 0:
            raise SynthConfigError(f"fps must be positive, got {self.fps}")
        if not self.speed > 0:
            raise SynthConfigError(f"speed must be positive, got {self.speed}")
        if self.num_heldout < 0:
            raise SynthConfigError(f"heldout must be >= 0, got {self.heldout}")
        if self.event_substeps is not None and self.event_substeps < 1:
            raise SynthConfigError(f"event_substeps must be >= 1 (or None), got {self.event_substeps}")
        if self.event_supersample < 1:
            raise SynthConfigError(f"event_supersample must be >= 1, got {self.event_supersample}")
        if not self.event_step_px > 0:
            raise SynthConfigError(f"event_step_px must be positive, got {self.event_step_px}")
        if not self.event_threshold > 0.01:
            raise SynthConfigError(f"event_threshold must be > 0.01, got {self.event_threshold}")
        if self.event_threshold_sigma < 0 or self.event_noise_hz < 0 or self.event_refractory_us < 0:
            raise SynthConfigError("event_threshold_sigma, event_noise_hz and event_refractory_us must be >= 0")
        if self.rgb_supersample < 1 or self.rgb_supersample > 4:
            raise SynthConfigError(f"rgb_supersample must be in 1..4, got {self.rgb_supersample}")
        if self.exposure_s is not None and not 0 <= self.exposure_s <= 1.0 / self.fps:
            raise SynthConfigError(f"exposure_s must be in [0, 1/fps = {1.0 / self.fps:.4f}] s, got {self.exposure_s}")
        if not self.blur_step_px > 0:
            raise SynthConfigError(f"blur_step_px must be positive, got {self.blur_step_px}")
        if self.blur_subframes is not None and not 1 <= self.blur_subframes <= MAX_SUBFRAMES:
            raise SynthConfigError(f"blur_subframes must be in 1..{MAX_SUBFRAMES}, got {self.blur_subframes}")
        if self.min_box_pixels < 1:
            raise SynthConfigError(f"min_box_pixels must be >= 1, got {self.min_box_pixels}")


def views_for_row(length_m: float, speed: float, fps: float) -> int:
    """The frames that drive ``length_m`` metres of row at ``speed`` m/s and ``fps`` frames/s (the first frame at the
    row's start, the last at its end); raises SynthConfigError for a length under two frames."""
    if not length_m > 0 or not speed > 0 or not fps > 0:
        raise SynthConfigError(f"row length, speed and fps must be positive, got {length_m}, {speed}, {fps}")
    views = int(round(length_m * fps / speed)) + 1
    if views < 2:
        raise SynthConfigError(f"a row of {length_m} m is under one frame step ({speed / fps:g} m) long")
    return views


def check_output_dir(out: Path) -> None:
    """Raise SynthConfigError when ``out`` cannot receive a new capture (a file, or a non-empty folder)."""
    out = Path(out)
    if out.exists():
        if not out.is_dir():
            raise SynthConfigError(f"output {out} exists and is not a folder")
        if any(out.iterdir()):
            raise SynthConfigError(f"output folder {out} exists and is not empty")
