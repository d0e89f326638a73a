"""Render a trained Nerfstudio method's views to image files for detection.

Generic over methods: the saved run is loaded with Nerfstudio's ``eval_setup`` and each camera of the chosen split is
rendered with ``pipeline.model.get_outputs_for_camera``. ``output="rgb"`` writes the (H, W, 3) colour, ``"thermal"``
the (H, W, 1) cross-spectral channel in [0, 1] (AgriNeRF's thermal head) as 8-bit PNGs named by the frame's stem, so
:mod:`agrinerf_ns.detect.boxes` finds their true boxes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Literal, Optional

import numpy as np
from jaxtyping import Float, UInt8

Output = Literal["rgb", "thermal"]
Split = Literal["eval", "train"]


class MissingOutputError(ValueError):
    """The method does not render the requested output (for example no ``thermal`` for a cross-spectral run)."""


def to_uint8(image: Float[np.ndarray, "h w c"]) -> UInt8[np.ndarray, "h w c"]:
    """[0, 1] floats -> 8-bit, NaN/Inf mapped to 0/1 first."""
    image = np.nan_to_num(np.asarray(image, dtype=np.float32), nan=0.0, posinf=1.0, neginf=0.0)
    return (np.clip(image, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def render_views(
    config_path: Path,
    output: Output,
    out_dir: Path,
    split: Split = "eval",
    max_views: Optional[int] = None,
    eval_num_rays_per_chunk: Optional[int] = None,
) -> List[Path]:
    """Render ``output`` at every camera of ``split`` of the run saved at ``config_path``; returns the written PNGs.

    Writes ``out_dir/<frame>.png`` and ``out_dir/renders.json`` (method, output, step, split, frames). Raises
    :class:`MissingOutputError` when the method has no such output (checked on the first view).
    """
    import torch
    from PIL import Image
    from rich.progress import Progress

    from agrinerf_ns import compat

    compat.activate()
    from nerfstudio.utils.eval_utils import eval_setup

    config_path = Path(config_path)
    if not config_path.is_file():
        raise FileNotFoundError(
            f"{config_path}: no such Nerfstudio run config (outputs/<name>/<method>/<time>/config.yml)"
        )
    config, pipeline, checkpoint, step = eval_setup(
        config_path, eval_num_rays_per_chunk=eval_num_rays_per_chunk, test_mode="test"
    )
    dataset = pipeline.datamanager.eval_dataset if split == "eval" else pipeline.datamanager.train_dataset
    if dataset is None or len(dataset) == 0:
        raise ValueError(
            f"{config_path}: the run's {split} split has no cameras to render (with Nerfstudio's default "
            "train_split_fraction 0.9, a dataset needs at least 11 frames for one eval view)"
        )
    count = len(dataset) if max_views is None else min(max_views, len(dataset))
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    device = pipeline.device
    written: List[Path] = []
    with Progress(transient=True) as progress:
        task = progress.add_task(f"rendering {output} ({config.method_name}, {split})", total=count)
        for index in range(count):
            camera = dataset.cameras[index : index + 1].to(device)
            with torch.no_grad():
                outputs = pipeline.model.get_outputs_for_camera(camera)
            if output not in outputs:
                raise MissingOutputError(
                    f"{config_path}: method '{config.method_name}' has no '{output}' output (it renders: "
                    f"{', '.join(sorted(outputs))}). Cross-spectral detection needs a method with a thermal head, "
                    "such as agrinerf trained on a dataset with thermal frames."
                )
            image = outputs[output].detach().float().cpu().numpy()
            if image.ndim != 3 or image.shape[-1] not in (1, 3):
                raise ValueError(f"{config_path}: output '{output}' has shape {image.shape}, expected (H, W, 1 or 3)")
            pixels = to_uint8(image)
            path = out_dir / f"{Path(dataset.image_filenames[index]).stem}.png"
            Image.fromarray(pixels[..., 0] if pixels.shape[-1] == 1 else pixels).save(path)
            written.append(path)
            progress.advance(task)
    manifest = {
        "config": str(config_path),
        "method": config.method_name,
        "output": output,
        "split": split,
        "checkpoint": str(checkpoint),
        "step": int(step),
        "frames": [p.name for p in written],
    }
    (out_dir / "renders.json").write_text(json.dumps(manifest, indent=2))
    return written
