"""The event term's own settings (`EventSettings`), built from the flat model settings (`model_config.part_settings`);
what each field does is documented on `model_config.AgriNeRFSettings`, whose fields of the same names set them."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal


@dataclass(frozen=True)
class EventSettings:
    """The settings of the event loss, its `noise` weighting, its data gate and the learnt event response."""

    event_rays_per_batch: int
    event_threshold: float
    event_threshold_learnt: bool
    event_window_min_fraction: float
    event_loss_bound: bool
    event_loss_weighting: Literal["fixed", "noise"]
    event_log_eps: float
    event_start_step: int
    event_crf_start_step: int
    event_gate_every: int
    event_gate_samples: int
