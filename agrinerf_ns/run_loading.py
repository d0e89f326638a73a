"""Find and load a trained Nerfstudio run (its ``config.yml`` and latest checkpoint) for rendering or sampling: the
one way the counter, the detector, the demo and the benchmarks open a run."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, Optional

from agrinerf_ns.views import rays_per_chunk


class NotATrainedRunError(ValueError):
    """A path that is not a trained Nerfstudio run (no config.yml, no checkpoint, no dataparser_transforms.json); the
    message names it."""


def trained_run_config(path: Path) -> Path:
    """The ``config.yml`` of the trained run at ``path`` (the run folder or its config.yml); raises
    :class:`NotATrainedRunError` naming ``path`` when it is not a trained Nerfstudio run (no config.yml, no checkpoint
    under nerfstudio_models/, no dataparser_transforms.json)."""
    from agrinerf_ns.ns_commands import CHECKPOINTS_DIR, checkpoints

    path = Path(path)
    config = path / "config.yml" if path.is_dir() else path
    if not path.exists():
        raise NotATrainedRunError(f"{path}: no such run folder or config.yml")
    if config.name != "config.yml" or not config.is_file():
        raise NotATrainedRunError(
            f"{path}: not a trained Nerfstudio run (no config.yml; give the run folder "
            "outputs/<name>/<method>/<time>/ or its config.yml)"
        )
    if not checkpoints(config):
        raise NotATrainedRunError(
            f"{path}: not a trained Nerfstudio run (no step-*.ckpt checkpoint in {config.parent / CHECKPOINTS_DIR})"
        )
    transforms = config.parent / "dataparser_transforms.json"
    if not transforms.is_file():
        raise NotATrainedRunError(f"{path}: not a trained Nerfstudio run ({transforms} is missing; ns-train writes it)")
    return config


@dataclass
class LoadedRun:
    """A trained run loaded for rendering."""

    config_path: Path
    method: Optional[str]
    """The config's ``method_name`` (Nerfstudio types it optional)."""
    pipeline: Any
    checkpoint: Path
    step: int

    @property
    def dataset_dir(self) -> Optional[Path]:
        """The dataset folder the run was trained on (None where its datamanager does not say)."""
        return datamanager_dataset(self.pipeline.datamanager.config)


def datamanager_dataset(datamanager_config: Any) -> Optional[Path]:
    """The dataset folder a run's datamanager settings name (None where they do not)."""
    data = getattr(datamanager_config, "data", None)
    return dataset_folder(Path(data)) if data else None


def run_dataset(config_path: Path) -> Optional[Path]:
    """The dataset folder of the run at ``config_path`` (its config.yml), read from the config alone: no checkpoint or
    dataset is loaded (None where the config does not name one)."""
    import yaml

    from agrinerf_ns import compat

    compat.activate()
    config = yaml.load(Path(config_path).read_text(), Loader=yaml.Loader)
    return datamanager_dataset(config.pipeline.datamanager)


def dataset_folder(data: Path) -> Path:
    """The dataset folder of a run's ``--data``: the folder itself, or the folder of the transforms JSON it names
    (``ns-train ... --data DATA/transforms.json``, as ``agrinerf-bench`` trains)."""
    return data.parent if data.suffix == ".json" else data


def load_run(config_path: Path, eval_num_rays_per_chunk: Optional[int] = None) -> LoadedRun:
    """Load a saved Nerfstudio run (config.yml + latest checkpoint) with its train and eval datasets, rendering
    ``eval_num_rays_per_chunk`` rays at once (None: :func:`agrinerf_ns.views.rays_per_chunk`)."""
    from agrinerf_ns import compat

    compat.activate()
    from nerfstudio.utils.eval_utils import eval_setup

    config_path = Path(config_path)
    if not config_path.is_file():
        raise FileNotFoundError(
            f"{config_path}: no such Nerfstudio run config (outputs/<name>/<method>/<time>/config.yml)"
        )
    config, pipeline, checkpoint, step = eval_setup(
        config_path, eval_num_rays_per_chunk=rays_per_chunk(eval_num_rays_per_chunk), test_mode="test"
    )
    return LoadedRun(config_path, config.method_name, pipeline, Path(checkpoint), int(step))


def render_camera(run: LoadedRun, dataset: Any, index: int) -> Dict[str, Any]:
    """Every output of the run's model (tensors of shape (H, W, C)) at camera ``index`` of ``dataset``, no gradients."""
    import torch

    camera = dataset.cameras[index : index + 1].to(run.pipeline.device)
    with torch.no_grad():
        return run.pipeline.model.get_outputs_for_camera(camera)
