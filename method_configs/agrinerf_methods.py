"""`MethodSpecification`s of the AgriNeRF presets, all built by one function (`agrinerf_trainer_config`).

Every `ns-*` command imports this module (the entry points of every preset below), so it stays cheap and never
raises; it must not import `nerfstudio.configs.method_configs` (that module loads the entry points: circular import).

Presets:
- `agrinerf`: the paper (1024 rays, 64 coarse + 64 fine samples, 30k steps, lr decayed x0.1 every 10k steps).
- `agrinerf-lite`: fast on a CPU (smaller grids and MLPs, 32 + 32 samples, 2k steps).
- `evdeblurnerf`, `evdeblurnerf-lite`: the paper's EvDeblurNeRF baseline, the same presets' RGB module (event loss and
  blur model) without the thermal head.

Device: a preset trains on the GPU when PyTorch sees a CUDA device and on the CPU otherwise (the default of
`--machine.device-type` is chosen when this module is imported, so `--help` shows it and an explicit value wins);
`ns-train` then says in one line that it trains on the CPU (:meth:`AgriNeRFTrainerConfig.print_to_terminal`).

Table IV ablations of the paper are `--pipeline.model.modalities` values of either preset
(see `agrinerf_ns.modalities.TABLE_IV_ABLATIONS`): RGB `rgb`; RGB+Events `rgb events`; RGB+Thermal `rgb thermal`;
Thermal `thermal`; Thermal+Events `thermal events`; All `rgb thermal events` (the default).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Literal

import torch
from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.schedulers import MultiStepSchedulerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.pipelines.base_pipeline import VanillaPipelineConfig
from nerfstudio.plugins.types import MethodSpecification
from nerfstudio.utils.rich_utils import CONSOLE

from agrinerf_ns.model.dataset import agrinerf_datamanager_config
from agrinerf_ns.model.model import AgriNeRFModelConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """Nerfstudio's Adam config with torch's fused implementation (one kernel per step for all Parameters, the same
    update rule), which torch has for CPU and CUDA tensors."""

    fused: bool = True
    """torch.optim.Adam(fused=...)."""


def _optimizers(lr_fields: float, lr_encodings: float, max_steps: int) -> Dict[str, Dict[str, Any]]:
    """Adam for the MLPs ("fields") and TensoRF volumes ("encodings"), x0.1 at 1/3 and 2/3 of training."""
    milestones = (max_steps // 3, 2 * max_steps // 3)

    def group(lr: float) -> Dict[str, Any]:
        return {
            "optimizer": FusedAdamOptimizerConfig(lr=lr, eps=1e-15),
            "scheduler": MultiStepSchedulerConfig(max_steps=max_steps, gamma=0.1, milestones=milestones),
        }

    return {
        "fields": group(lr_fields),
        "encodings": group(lr_encodings),
        "camera_opt": {
            "optimizer": AdamOptimizerConfig(lr=1e-4, eps=1e-15),
            "scheduler": MultiStepSchedulerConfig(max_steps=max_steps, gamma=0.1, milestones=milestones),
        },
    }


def default_device_type() -> Literal["cuda", "cpu"]:
    """``cuda`` where PyTorch sees a CUDA device, else ``cpu`` (Nerfstudio's own default is always ``cuda``)."""
    return "cuda" if torch.cuda.is_available() else "cpu"


@dataclass
class AgriNeRFTrainerConfig(TrainerConfig):
    """Nerfstudio's ``TrainerConfig`` whose machine defaults to the device this machine has."""

    machine: MachineConfig = field(default_factory=lambda: MachineConfig(device_type=default_device_type()))
    """Machine configuration (``--machine.device-type`` defaults to ``cuda`` with a CUDA device, else ``cpu``)."""

    def print_to_terminal(self) -> None:
        """Nerfstudio's config print-out (``ns-train`` shows it before training), then one line when this run trains
        on the CPU because no CUDA device is present."""
        super().print_to_terminal()
        if self.machine.device_type == "cpu" and not torch.cuda.is_available():
            CONSOLE.print(
                f"{self.method_name}: no CUDA device found, training on the CPU (--machine.device-type cpu)",
                soft_wrap=True,
            )


def agrinerf_trainer_config(
    method_name: str,
    max_num_iterations: int,
    num_rays_per_batch: int = 1024,
    lr_fields: float = 5e-3,
    lr_encodings: float = 2e-2,
    steps_per_eval_batch: int = 500,
    steps_per_save: int = 2000,
    **model_overrides: Any,
) -> AgriNeRFTrainerConfig:
    """The one base of every preset: a `TrainerConfig` whose presets differ only in the arguments given here."""
    return AgriNeRFTrainerConfig(
        method_name=method_name,
        steps_per_eval_batch=steps_per_eval_batch,
        steps_per_eval_image=steps_per_save,
        steps_per_save=steps_per_save,
        max_num_iterations=max_num_iterations,
        mixed_precision=False,
        pipeline=VanillaPipelineConfig(
            datamanager=agrinerf_datamanager_config(
                train_num_rays_per_batch=num_rays_per_batch, eval_num_rays_per_batch=num_rays_per_batch
            ),
            model=AgriNeRFModelConfig(eval_num_rays_per_chunk=1 << 13, **model_overrides),
        ),
        optimizers=_optimizers(lr_fields, lr_encodings, max_num_iterations),
        viewer=ViewerConfig(num_rays_per_chunk=1 << 13, quit_on_train_completion=True),
        vis="viewer",
    )


PAPER_BLUR: Dict[str, Any] = dict(blur_samples=5, blur_start_step=1200)
"""The paper preset's blur model, EvDeblurNeRF's (which AgriNeRF extends), from step 1200; EvDeblurNeRF itself renders
10 rays per blurred pixel."""

EVDEBLURNERF: Dict[str, Any] = dict(
    modalities=("rgb", "events"), cross_spectral_output=False, low_light_event_loss=True
)
"""The EvDeblurNeRF baseline's scene: RGB and events, no thermal head, the event loss in any light (as published). Its
presets also turn the event loss on at EvDeblurNeRF's fixed weight 0.1 (EvDeblurNeRF uses 2048-4096 event pixels per
batch); `agrinerf` weights it by the events' noise instead and leaves it off in low light, `agrinerf-lite` leaves it
off (docs/model.md, Event loss and blur model)."""

LITE: Dict[str, Any] = dict(
    max_num_iterations=2000,
    steps_per_eval_batch=200,
    steps_per_save=500,
    init_resolution=32,
    final_resolution=96,
    upsampling_iters=(300, 600, 900),
    num_coarse_samples=32,
    num_fine_samples=32,
    num_density_components=8,
    num_rgb_components=16,
    rgb_appearance_dim=16,
    num_thermal_components=8,
    thermal_appearance_dim=8,
    mlp_width=64,
    occupancy_resolution=32,
    occupancy_update_iters=(500, 1000, 1500),
)
"""The CPU preset: small grids and MLPs, 32 + 32 samples, 2k steps, no blur model, no event loss."""

PAPER_EVENTS: Dict[str, Any] = dict(
    event_rays_per_batch=1024,
    event_loss_weighting="noise",
    loss_coefficients={**AgriNeRFModelConfig().loss_coefficients, "event_loss": 1.0},
)
"""The paper preset's event loss (AgriNeRF is EvDeblurNeRF's RGB module plus the thermal head): 1024 event pixels per
batch from the event stream, weighted by the events' noise (coefficient 1), not EvDeblurNeRF's fixed 0.1 (why:
docs/model.md, Event loss). Scenes without events get no event loss."""

agrinerf = MethodSpecification(
    config=agrinerf_trainer_config("agrinerf", max_num_iterations=30000, **PAPER_BLUR, **PAPER_EVENTS),
    description="AgriNeRF (paper settings): RGB + thermal + event TensoRF NeRF, 64+64 samples, 30k steps.",
)

agrinerf_lite = MethodSpecification(
    config=agrinerf_trainer_config("agrinerf-lite", **LITE),
    description="AgriNeRF, fast CPU preset: small grids and MLPs, 32+32 samples, 2k steps.",
)

evdeblurnerf = MethodSpecification(
    config=agrinerf_trainer_config(
        "evdeblurnerf", max_num_iterations=30000, event_rays_per_batch=1024, **PAPER_BLUR, **EVDEBLURNERF
    ),
    description="EvDeblurNeRF-style baseline: the RGB TensoRF with the event loss and blur model, no thermal head.",
)

evdeblurnerf_lite = MethodSpecification(
    config=agrinerf_trainer_config(
        "evdeblurnerf-lite", blur_samples=3, event_rays_per_batch=256, **LITE, **EVDEBLURNERF
    ),
    description="EvDeblurNeRF-style baseline, CPU preset: AgriNeRF-lite's RGB module with the event loss and a 3-ray "
    "blur model, no thermal head.",
)
