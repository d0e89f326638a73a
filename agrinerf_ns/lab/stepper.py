"""A method's Nerfstudio pipeline trained step by step in this process, as ``ns-train`` sets it up.

For benchmarks that look inside a step (its time, the gradients of each loss term) rather than at a finished run.
"""

from __future__ import annotations

import copy
import time
from pathlib import Path
from typing import Any, Dict, Optional

import torch

from agrinerf_ns.lab.methods import METHODS
from agrinerf_ns.machine import torch_device_type


class MethodStepper:
    """One method's pipeline, optimizers, schedulers and training callbacks, on the GPU where PyTorch sees one.

    Args:
        key: an ``agrinerf-bench`` method key (``agrinerf_ns.lab.methods.METHODS``).
        data: a processed dataset folder.
        rays_per_batch: training rays per batch.
        model_overrides: model config fields to set (e.g. ``{"modalities": ("rgb",)}``).
        callbacks: run the model's training callbacks (upsampling, occupancy) after each step, as the trainer does.
    """

    def __init__(
        self,
        key: str,
        data: Path,
        rays_per_batch: int,
        model_overrides: Optional[Dict[str, Any]] = None,
        callbacks: bool = False,
    ) -> None:
        from nerfstudio.configs.dataparser_configs import all_dataparsers
        from nerfstudio.configs.method_configs import all_methods
        from nerfstudio.engine.callbacks import TrainingCallbackAttributes
        from nerfstudio.engine.optimizers import Optimizers

        method = METHODS[key]
        config = copy.deepcopy(all_methods[method.ns_method])  # the registry's config is shared: never mutate it
        config.set_timestamp()
        datamanager = config.pipeline.datamanager
        if method.dataparser_args:
            datamanager.dataparser = all_dataparsers[method.dataparser_args[0]]
        datamanager.data = data / method.data_file
        datamanager.dataparser.data = data / method.data_file
        datamanager.train_num_rays_per_batch = rays_per_batch
        for name, value in (model_overrides or {}).items():
            if not hasattr(config.pipeline.model, name):
                raise ValueError(f"{type(config.pipeline.model).__name__} has no field {name!r}")
            setattr(config.pipeline.model, name, value)
        self.pipeline = config.pipeline.setup(device=torch_device_type(), test_mode="val", world_size=1, local_rank=0)
        self.pipeline.train()
        self.optimizers = Optimizers(config.optimizers.copy(), self.pipeline.get_param_groups())
        self.callbacks = (
            self.pipeline.get_training_callbacks(
                TrainingCallbackAttributes(
                    optimizers=self.optimizers, grad_scaler=None, pipeline=self.pipeline, trainer=None
                )
            )
            if callbacks
            else []
        )

    def loss_dict(self, step: int) -> Dict[str, torch.Tensor]:
        """The weighted loss terms of the next training batch (graph kept, nothing stepped)."""
        _, loss_dict, _ = self.pipeline.get_train_loss_dict(step=step)
        return loss_dict

    def apply(self, loss_dict: Dict[str, torch.Tensor], step: int) -> None:
        """Backward of the summed terms, optimizer and scheduler step, then the callbacks of `step`."""
        from nerfstudio.engine.callbacks import TrainingCallbackLocation

        self.optimizers.zero_grad_all()
        torch.stack([v for v in loss_dict.values()]).sum().backward()
        self.optimizers.optimizer_step_all()
        self.optimizers.scheduler_step_all(step)
        for callback in self.callbacks:
            callback.run_callback_at_location(step, location=TrainingCallbackLocation.AFTER_TRAIN_ITERATION)

    def step(self, step: int) -> float:
        """One training step (next batch, forward, loss, backward, optimizer step); returns its wall seconds."""
        start = time.perf_counter()
        self.apply(self.loss_dict(step), step)
        if torch.device(self.pipeline.device).type == "cuda":
            torch.cuda.synchronize()  # the step's kernels are queued, not done, when apply returns
        return time.perf_counter() - start
