"""`MethodSpecification`s of the AgriNeRF presets, all built by one function (`agrinerf_trainer_config`).

Every `ns-*` command imports this module (the entry points of every preset below), so it stays cheap and never
raises; it must not import `nerfstudio.configs.method_configs` (that module loads the entry points: circular import).

Presets:
- `agrinerf`: the paper (1024 rays, 64 coarse + 64 fine samples, 30k steps, lr decayed x0.1 every 10k steps).
- `agrinerf-lite`: fast on a CPU (smaller grids and MLPs, 32 + 32 samples, 2k steps).
- `evdeblurnerf`, `evdeblurnerf-lite`: the paper's EvDeblurNeRF baseline as published (event-to-event samples, its
  learnt event response, its learnt rigid blur kernel and EDI prior, its learning-rate schedule) on this project's
  TensoRF field (not its PDRF field), without the thermal head; the lite one on `agrinerf-lite`'s field.
- `evdeblurnerf-windowed`, `evdeblurnerf-windowed-lite`: the earlier port: the RGB module's windowed event loss at
  weight 0.1 and the known-trajectory blur kernel.

Device: a preset trains on the GPU when PyTorch sees a CUDA device and on the CPU otherwise (the default of
`--machine.device-type` is chosen when this module is imported, so `--help` shows it and an explicit value wins);
`ns-train` then says in one line that it trains on the CPU (:meth:`AgriNeRFTrainerConfig.print_to_terminal`).

Table IV ablations of the paper are `--pipeline.model.modalities` values of either preset
(see `agrinerf_ns.modalities.TABLE_IV_ABLATIONS`): RGB `rgb`; RGB+Events `rgb events`; RGB+Thermal `rgb thermal`;
Thermal `thermal`; Thermal+Events `thermal events`; All `rgb thermal events` (the default).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Dict, Literal, Optional

import torch
from nerfstudio.configs.base_config import MachineConfig, ViewerConfig
from nerfstudio.engine.optimizers import AdamOptimizerConfig
from nerfstudio.engine.schedulers import ExponentialDecaySchedulerConfig, MultiStepSchedulerConfig
from nerfstudio.engine.trainer import TrainerConfig
from nerfstudio.pipelines.base_pipeline import VanillaPipelineConfig
from nerfstudio.plugins.types import MethodSpecification
from nerfstudio.utils.rich_utils import CONSOLE

from agrinerf_ns.dataparsers.agrinerf_dataset import agrinerf_datamanager_config
from agrinerf_ns.model.model import AgriNeRFModelConfig


@dataclass
class FusedAdamOptimizerConfig(AdamOptimizerConfig):
    """Nerfstudio's Adam config with torch's fused implementation (one kernel per step for all Parameters, the same
    update rule), which torch has for CPU and CUDA tensors."""

    fused: bool = True
    """torch.optim.Adam(fused=...)."""
    weight_decay: float = 0.0
    """Nerfstudio's default, as a float: its ``0`` breaks the annotation when a parser passes it back."""


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
        "blur_kernel": group(lr_fields),  # the learnt blur kernel and event response (`--pipeline.model.blur-kernel
        "event_crf": group(lr_fields),  # learnt`, `...event-crf True`): learnt like the MLPs
        "camera_opt": {
            "optimizer": AdamOptimizerConfig(lr=1e-4, eps=1e-15),
            "scheduler": MultiStepSchedulerConfig(max_steps=max_steps, gamma=0.1, milestones=milestones),
        },
    }


EVDEBLURNERF_LR = 5e-3
"""EvDeblurNeRF's learning rate for every parameter (``lrate``), decayed x0.1 every 10k steps (``lrate_decay 10``)."""

TENSORF_GRID_LR = 2e-2
"""The grids' (VM planes and lines) learning rate of TensoRF and of every preset here. EvDeblurNeRF's 5e-3 was tuned
for PDRF's voxel grids; on the TensoRF field its presets run on, it cost EvDeblurNeRF 1.09 dB (blurred dusk orchard)
and 3.07 dB (garden), results/event-deblur/published-dusk-both."""


def _evdeblurnerf_optimizers(max_steps: int) -> Dict[str, Dict[str, Any]]:
    """EvDeblurNeRF's schedule, Adam times 0.1^(step / 10k), at its 5e-3 for every parameter group but the grids,
    which take TensoRF's rate (the field they are)."""

    def group(lr: float) -> Dict[str, Any]:
        return {
            "optimizer": AdamOptimizerConfig(lr=lr, eps=1e-15),
            "scheduler": ExponentialDecaySchedulerConfig(
                lr_final=lr * 0.1 ** (max_steps / 10_000), max_steps=max_steps
            ),
        }

    groups = {name: group(EVDEBLURNERF_LR) for name in ("fields", "blur_kernel", "event_crf", "camera_opt")}
    return {**groups, "encodings": group(TENSORF_GRID_LR)}


def default_device_type() -> Literal["cuda", "cpu"]:
    """``cuda`` where PyTorch sees a CUDA device, else ``cpu`` (Nerfstudio's own default is always ``cuda``)."""
    from agrinerf_ns.machine import torch_device_type

    return torch_device_type()


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
    lr_encodings: float = TENSORF_GRID_LR,
    steps_per_eval_batch: int = 500,
    steps_per_save: int = 2000,
    optimizers: Optional[Dict[str, Dict[str, Any]]] = None,
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
        optimizers=optimizers or _optimizers(lr_fields, lr_encodings, max_num_iterations),
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
presets also turn the event loss on at EvDeblurNeRF's fixed weight 0.1; `agrinerf` weights it by the events' noise
instead and leaves it off in low light, `agrinerf-lite` leaves it off (docs/model.md, Event loss and blur model)."""

EVDEBLURNERF_PUBLISHED: Dict[str, Any] = dict(
    event_supervision="pairs",
    event_rays_per_batch=4096,
    event_log_eps=1e-5,
    event_crf=True,
    event_crf_start_step=1200,
    blur_kernel="learnt",
    blur_samples=10,
    blur_start_step=1200,
    edi_prior=True,
)
"""EvDeblurNeRF's recipe (its configs ``tx_blur*_evdeblurnerf_ediprior_evcrf``): 4096 event-to-event samples per 1024
RGB rays at weight 0.1, log(luma + 1e-5) after its event response learnt from step 1200, DP-NeRF's rigid blur kernel
of 10 rays from step 1200, the EDI prior from step 0, 30k steps at lr 5e-3 x 0.1^(step / 10k). Not reproduced: its
PDRF field (voxel grids and small MLPs; the presets keep the TensoRF field AgriNeRF shares), the event loss on its
coarse pass (this model's coarse pass renders density only), DP-NeRF's adaptive weight proposal and the RGB gamma
curve of its simulated scenes (the frames here are sRGB and so is the render)."""

LITE: Dict[str, Any] = dict(
    max_num_iterations=2000,
    steps_per_eval_batch=200,
    steps_per_save=500,
    init_resolution=32,
    final_resolution=96,
    upsampling_iters=(300, 600, 900),
    num_coarse_samples=32,
    num_fine_samples=16,
    num_density_components=8,
    num_rgb_components=16,
    rgb_appearance_dim=16,
    num_thermal_components=8,
    thermal_appearance_dim=8,
    mlp_width=64,
    occupancy_resolution=32,
    occupancy_update_iters=(500, 1000, 1500),
)
"""The CPU preset: small grids and MLPs, 32 + 16 samples (32 + 32 before: 16 fine samples render sharper fields at
equal wall time, results/sample-budget-walltime), 2k steps, no blur model, no event loss."""

PAPER_EVENTS: Dict[str, Any] = dict(
    event_supervision="stream",
    event_rays_per_batch=512,
    event_loss_weighting="noise",
    event_gate=True,
    loss_coefficients={**AgriNeRFModelConfig().loss_coefficients, "event_loss": 1.0},
)
"""The paper preset's event loss (AgriNeRF is EvDeblurNeRF's RGB module plus the thermal head): 512 event pixels per
batch from the event stream, weighted by the events' noise (coefficient 1), not EvDeblurNeRF's fixed 0.1 (why:
docs/model.md, Event loss), and gated by a held-out share of the events (`event_gate`): the term opens only once the
field the frames shape explains them, which kept it from costing the blurred dusk garden 3.5 dB
(results/event-diagnose). ``--pipeline.model.event-gate False`` removes the gate. Scenes without events get no event
loss."""

SAMPLE_BUDGET: Dict[str, Any] = dict(num_coarse_samples=64, num_fine_samples=32)
"""The paper preset's samples per ray: the paper's 64 coarse, and 32 fine where the paper has 64 (with 512 event
pixels, not 1024): at equal wall time on a CPU this budget renders sharper fields than the paper's
(results/sample-budget-walltime). ``--pipeline.model.num-fine-samples 64 --pipeline.model.event-rays-per-batch 1024``
restores the paper's."""

PAPER_THERMAL_RAYS = 1024
"""The paper preset renders its thermal terms from the thermal camera on all 1024 rays of a batch (the lite preset
and the model's default: 256): on the count-small profile's garden 1024 rays held the fruit's temperature better (per
fruit 1.96 against 2.20 C bright) and at the paper preset's final grids, with its blur renders and events, they cost
about what 256 do (1.09x against 1.08x of none; results/thermal-rays)."""

agrinerf = MethodSpecification(
    config=agrinerf_trainer_config(
        "agrinerf",
        max_num_iterations=30000,
        thermal_rays_per_batch=PAPER_THERMAL_RAYS,
        **PAPER_BLUR,
        **PAPER_EVENTS,
        **SAMPLE_BUDGET,
    ),  # fmt: skip
    description="AgriNeRF (paper settings, 30k steps): RGB + thermal + event TensoRF NeRF; 64 + 32 samples and 512 "
    "event pixels, which beat the paper's 64 + 64 and 1024 at equal wall time (--pipeline.model.num-fine-samples 64 "
    "--pipeline.model.event-rays-per-batch 1024 restores them).",
)

agrinerf_lite = MethodSpecification(
    config=agrinerf_trainer_config("agrinerf-lite", **LITE),
    description="AgriNeRF, fast CPU preset: small grids and MLPs, 32 + 16 samples, 2k steps.",
)

evdeblurnerf = MethodSpecification(
    config=agrinerf_trainer_config(
        "evdeblurnerf",
        max_num_iterations=30000,
        optimizers=_evdeblurnerf_optimizers(30000),
        **EVDEBLURNERF_PUBLISHED,
        **EVDEBLURNERF,
    ),
    description="EvDeblurNeRF as published (event-to-event loss, learnt event response, learnt rigid blur kernel, EDI "
    "prior, its schedule) on the TensoRF field, not its PDRF field; no thermal head. The grids learn at TensoRF's 2e-2, "
    "not the 5e-3 tuned for PDRF's voxel grids, which on this field cost it 1.1-3.1 dB "
    "(--optimizers.encodings.optimizer.lr 5e-3 --optimizers.encodings.scheduler.lr-final 5e-6 restores it).",
)

evdeblurnerf_lite = MethodSpecification(
    config=agrinerf_trainer_config(
        "evdeblurnerf-lite",
        optimizers=_evdeblurnerf_optimizers(LITE["max_num_iterations"]),
        # 32 fine samples, not AgriNeRF-lite's 16: on the blurred dusk scenes 16 cost this recipe 0.97 (orchard) and
        # 2.14 dB (garden), results/event-deblur/published-dusk-both
        **{**LITE, **EVDEBLURNERF_PUBLISHED, "num_fine_samples": 32},
        **EVDEBLURNERF,
    ),
    description="EvDeblurNeRF as published on AgriNeRF-lite's field with 32 + 32 samples (CPU preset, 2k steps): "
    "event-to-event loss, learnt event response and rigid blur kernel from step 1200, EDI prior; not its PDRF field; "
    "no thermal head. The grids learn at TensoRF's 2e-2, not the 5e-3 tuned for PDRF's voxel grids, which on this "
    "field cost it 1.1-3.1 dB (--optimizers.encodings.optimizer.lr 5e-3 --optimizers.encodings.scheduler.lr-final "
    "3.15e-3 restores it).",
)

evdeblurnerf_windowed = MethodSpecification(
    config=agrinerf_trainer_config(
        "evdeblurnerf-windowed",
        max_num_iterations=30000,
        event_supervision="stream",
        event_rays_per_batch=1024,
        **PAPER_BLUR,
        **EVDEBLURNERF,
    ),
    description="The earlier EvDeblurNeRF port: the RGB TensoRF with the windowed event loss at weight 0.1 and the "
    "known-trajectory blur model, no thermal head.",
)

evdeblurnerf_windowed_lite = MethodSpecification(
    config=agrinerf_trainer_config(
        "evdeblurnerf-windowed-lite",
        blur_samples=3,
        event_supervision="stream",
        event_rays_per_batch=256,
        **LITE,
        **EVDEBLURNERF,
    ),
    description="The earlier EvDeblurNeRF port, CPU preset: AgriNeRF-lite's RGB module with the windowed event loss "
    "and a 3-ray known-trajectory blur model, no thermal head.",
)
