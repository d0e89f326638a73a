"""One method's training steps on request, in a process of its own (`bench_step_interleaved.py` drives several).

    python benchmarks/step_worker.py METHOD DATA RAYS AT_STEP SEED [OVERRIDES_JSON]

Builds the method's Nerfstudio pipeline with `agrinerf_ns.lab.stepper.MethodStepper` from whatever `agrinerf_ns` the
interpreter imports (PYTHONPATH may point at another checkout: the same benchmark then times that checkout's code). An
AgriNeRF model is first put in the state of training step AT_STEP: its grids at that step's resolution (in a fitted
box where the model fits one) and its step-dependent terms (blur model, event loss) as from that step. Then, for each
line "STEP i" on stdin, it takes one training step and prints "SECONDS <wall seconds>"; it prints "READY <json>" first.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import torch


def prepare(stepper, at_step: int) -> dict:
    """Grids and step-dependent terms of training step `at_step` (an AgriNeRF model; others are left as built)."""
    model = stepper.pipeline.model
    info: dict = {}
    if at_step > 0 and hasattr(model, "grid"):  # the grid schedule as a part (today's tree)
        from agrinerf_ns.model.grid_schedule import sync_optimizers

        model.grid.fit_box(model.surface_points, stepper.pipeline.datamanager.train_dataset.cameras, 0)
        model.grid.upsample(model.grid.resolution_at_step(at_step))
        sync_optimizers(model.get_param_groups(), stepper.optimizers)
        model.step = at_step
    elif at_step > 0 and hasattr(model, "resolution_at_step"):  # an older checkout's model methods
        if hasattr(model, "fit_box"):  # a checkout whose grids follow a fitted box: fit it as training would
            model.fit_box(stepper.pipeline.datamanager.train_dataset.cameras, 0)
        model.upsample_volumes(model.resolution_at_step(at_step))
        model.sync_optimizers(stepper.optimizers)
        model.step = at_step
    if hasattr(model, "field") and hasattr(model.field, "volumes"):
        info["resolution"] = str(model.field.density_encoding.resolution)
    info["parameters"] = sum(p.numel() for p in stepper.pipeline.parameters())
    return info


def main() -> None:
    method, data, rays, at_step, seed = (
        sys.argv[1],
        Path(sys.argv[2]),
        int(sys.argv[3]),
        int(sys.argv[4]),
        int(sys.argv[5]),
    )
    overrides = json.loads(sys.argv[6]) if len(sys.argv) > 6 else {}
    overrides = {k: tuple(v) if isinstance(v, list) else v for k, v in overrides.items()}
    torch.manual_seed(seed)
    from agrinerf_ns.lab.stepper import MethodStepper

    stepper = MethodStepper(method, data, rays, model_overrides=overrides)
    info = prepare(stepper, at_step)
    print("READY " + json.dumps(info), flush=True)
    for line in sys.stdin:
        command, _, value = line.strip().partition(" ")
        if command != "STEP":
            break
        print(f"SECONDS {stepper.step(int(value)):.6f}", flush=True)


if __name__ == "__main__":
    main()
