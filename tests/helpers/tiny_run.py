"""A tiny trained AgriNeRF run on disk (config.yml + checkpoint), for tests of the commands that load one."""

from __future__ import annotations

from pathlib import Path

import torch

from helpers.model_scene import tiny_trainer_config, write_model_scene


def train_saved_run(config, seed: int = 42) -> Path:
    """Train a TrainerConfig through Nerfstudio's Trainer and save its config; returns config.yml."""
    config.set_timestamp()
    torch.manual_seed(seed)
    trainer = config.setup(local_rank=0, world_size=1)
    trainer.setup()
    trainer.train()
    config.save_config()
    return config.get_base_dir() / "config.yml"


def train_tiny_run(root: Path, steps: int = 20) -> Path:
    """Train the shrunk agrinerf-lite on the tiny tri-modal scene through Nerfstudio's Trainer; returns config.yml."""
    data = write_model_scene(root / "scene")
    return train_saved_run(tiny_trainer_config(data, root / "outputs", max_num_iterations=steps))
