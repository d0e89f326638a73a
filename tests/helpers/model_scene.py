"""A tiny, multi-view-consistent tri-modal scene for the model tests: a textured sphere under a sky.

RGB: a checker-textured sphere; thermal: a warm sphere (warmer at the top) in a cold sky; event frames: the
sphere's silhouette edges (0.5 = no change, as a signed polarity frame), masks valid except a left strip of the
thermal frame (what the thermal camera did not see). Written as docs/formats.md describes the dataset folder; the sphere and its rays are
``tiny_scene``'s.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, Optional, Sequence

import numpy as np
from PIL import Image

from helpers.tiny_scene import cast_sphere_view, make_dataset_folders, sphere_rgb, write_transforms


def _save(path: Path, values: np.ndarray) -> None:
    Image.fromarray((np.clip(values, 0.0, 1.0) * 255).round().astype(np.uint8)).save(path)


def write_model_scene(
    root: Path,
    views: int = 10,
    width: int = 64,
    height: int = 48,
    modalities: Sequence[str] = ("rgb", "thermal", "events"),
    constant: Optional[Dict[str, float]] = None,
) -> Path:
    """Write the scene under `root` (images/, thermal/, events/, masks, transforms.json); returns `root`.

    `constant` replaces a stream by a constant value in [0, 1] (keys "rgb", "thermal", "event") for extreme tests.
    """
    constant = constant or {}
    make_dataset_folders(root, modalities)
    focal = 0.9 * width
    frames = []
    for i in range(views):
        view = cast_sphere_view(i, views, width, height, focal)
        hit, points, rgb = view.hit, view.points, sphere_rgb(view)
        name = f"frame_{i:05d}.png"
        _save(root / "images" / name, np.full_like(rgb, constant["rgb"]) if "rgb" in constant else rgb)
        frame = {"file_path": f"images/{name}", "transform_matrix": view.c2w.tolist()}
        if "thermal" in modalities:
            thermal = np.where(hit, 0.6 + 0.3 * points[..., 2], 0.1)
            thermal = np.full_like(thermal, constant["thermal"]) if "thermal" in constant else thermal
            mask = np.ones_like(thermal)
            mask[:, : width // 8] = 0.0
            _save(root / "thermal" / name, thermal)
            _save(root / "thermal_masks" / name, mask)
            frame.update(thermal_file_path=f"thermal/{name}", thermal_mask_path=f"thermal_masks/{name}")
        if "events" in modalities:
            edge = np.zeros_like(hit)
            edge[:, 1:] |= hit[:, 1:] != hit[:, :-1]
            edge[1:, :] |= hit[1:, :] != hit[:-1, :]
            event = np.where(edge, 1.0, 0.5)
            event = np.full_like(event, constant["event"]) if "event" in constant else event
            _save(root / "events" / name, event)
            _save(root / "event_masks" / name, np.ones_like(event))
            frame.update(event_file_path=f"events/{name}", event_mask_path=f"event_masks/{name}")
        frames.append(frame)
    return write_transforms(root, frames, width, height, focal, modalities, source="model test scene")


def tiny_trainer_config(data: Path, output_dir: Path, max_num_iterations: int = 20, rays: int = 256, **model_overrides):
    """A deep copy of the registered `agrinerf-lite` TrainerConfig shrunk for CPU tests (device cpu, few rays).

    `model_overrides` set fields of the AgriNeRF model config (for example `modalities=("rgb",)`).
    """
    import copy

    from agrinerf_ns.method_configs.agrinerf_methods import agrinerf_lite

    config = copy.deepcopy(agrinerf_lite.config)
    config.machine.device_type = "cpu"
    config.machine.seed = 42
    config.vis = "tensorboard"
    config.output_dir = output_dir
    config.data = data
    config.pipeline.datamanager.data = data
    config.max_num_iterations = max_num_iterations
    config.steps_per_save = 10_000
    config.steps_per_eval_batch = 10_000
    config.steps_per_eval_image = 10_000
    config.steps_per_eval_all_images = 10_000
    config.save_only_latest_checkpoint = False
    config.pipeline.datamanager.train_num_rays_per_batch = rays
    config.pipeline.datamanager.eval_num_rays_per_batch = rays
    model = config.pipeline.model
    small = dict(
        init_resolution=16,
        final_resolution=24,
        upsampling_iters=(),
        num_coarse_samples=16,
        num_fine_samples=16,
        num_density_components=4,
        num_rgb_components=8,
        rgb_appearance_dim=8,
        num_thermal_components=4,
        thermal_appearance_dim=4,
        mlp_width=32,
        occupancy_resolution=16,
        occupancy_update_iters=(),
        box_fit_iters=(10,),  # the box is fitted to the scene within a short run: every run loaded in tests has one
        box_fit_rays=1024,
        eval_num_rays_per_chunk=4096,
    )
    small.update(model_overrides)
    for key, value in small.items():
        setattr(model, key, value)
    for group in config.optimizers.values():
        group["scheduler"].max_steps = max_num_iterations
    return config
