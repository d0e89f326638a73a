"""Render a trained Nerfstudio method's views to image files for detection.

Generic over methods: the saved run is loaded with Nerfstudio's ``eval_setup``
(:func:`agrinerf_ns.run_loading.load_run`) and each camera of the chosen split is rendered with
``pipeline.model.get_outputs_for_camera`` (:func:`render_pipeline_views`).
``output="rgb"`` writes the (H, W, 3) colour, ``"thermal"`` the (H, W, 1) cross-spectral channel in [0, 1]
(AgriNeRF's thermal head) as 8-bit PNGs named by the frame's stem, so :mod:`agrinerf_ns.detect.boxes` finds their
true boxes.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import List, Literal, Optional

from agrinerf_ns.images import to_uint8
from agrinerf_ns.run_loading import LoadedRun, load_run, render_camera
from agrinerf_ns.views import evenly_spaced

Output = Literal["rgb", "thermal"]
Split = Literal["eval", "train"]


class MissingOutputError(ValueError):
    """The method does not render the requested output (for example no ``thermal`` for a cross-spectral run)."""


def render_pipeline_views(
    run: LoadedRun, output: Output, out_dir: Path, split: Split = "eval", max_views: Optional[int] = None
) -> List[Path]:
    """Render ``output`` at every camera of ``split`` (or ``max_views`` of them, evenly spaced); writes
    ``out_dir/<frame>.png`` and ``out_dir/renders.json``.

    Raises :class:`MissingOutputError` when the method has no such output (checked on the first view, before
    anything is written).
    """
    from PIL import Image
    from rich.progress import Progress

    datamanager = run.pipeline.datamanager
    dataset = datamanager.eval_dataset if split == "eval" else datamanager.train_dataset
    if dataset is None or len(dataset) == 0:
        raise ValueError(
            f"{run.config_path}: the run's {split} split has no cameras to render (with Nerfstudio's default "
            "train_split_fraction 0.9, a dataset needs at least 11 frames for one eval view)"
        )
    indices = evenly_spaced(len(dataset), max_views)
    out_dir = Path(out_dir)
    written: List[Path] = []
    with Progress(transient=True) as progress:
        task = progress.add_task(f"rendering {output} ({run.method}, {split})", total=len(indices))
        for index in indices:
            outputs = render_camera(run, dataset, index)
            if output not in outputs:
                raise MissingOutputError(
                    f"{run.config_path}: method '{run.method}' has no '{output}' output (it renders: "
                    f"{', '.join(sorted(outputs))}). Cross-spectral detection needs a method with a thermal head, "
                    "such as agrinerf trained on a dataset with thermal frames."
                )
            image = outputs[output].detach().float().cpu().numpy()
            if image.ndim != 3 or image.shape[-1] not in (1, 3):
                raise ValueError(f"{run.config_path}: output '{output}' has shape {image.shape}, expected (H, W, 1|3)")
            pixels = to_uint8(image)
            out_dir.mkdir(parents=True, exist_ok=True)
            path = out_dir / f"{Path(dataset.image_filenames[index]).stem}.png"
            Image.fromarray(pixels[..., 0] if pixels.shape[-1] == 1 else pixels).save(path)
            written.append(path)
            progress.advance(task)
    manifest = {
        "config": str(run.config_path),
        "method": run.method,
        "output": output,
        "split": split,
        "checkpoint": str(run.checkpoint),
        "step": run.step,
        "frames": [p.name for p in written],
    }
    (out_dir / "renders.json").write_text(json.dumps(manifest, indent=2))
    return written


def render_views(
    config_path: Path,
    output: Output,
    out_dir: Path,
    split: Split = "eval",
    max_views: Optional[int] = None,
    eval_num_rays_per_chunk: Optional[int] = None,
) -> List[Path]:
    """Load the run saved at ``config_path`` and render ``output`` at every camera of ``split`` (see above)."""
    run = load_run(config_path, eval_num_rays_per_chunk)
    return render_pipeline_views(run, output, out_dir, split, max_views)
