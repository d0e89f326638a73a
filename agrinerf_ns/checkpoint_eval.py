"""Evaluate saved checkpoints of an ``ns-train`` run on its held-out views, in this process.

Loads each checkpoint with Nerfstudio's own ``eval_setup`` (as ``ns-eval`` does) and renders every eval camera once,
scoring it with the model's own metrics (against the captured held-out frames, as the paper does) and, for synthetic
scenes, against the clean truth after exposure alignment (see :func:`agrinerf_ns.image_metrics.exposure_align`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Callable, Dict, List, Literal, Optional

import numpy as np
import torch
from PIL import Image

from agrinerf_ns import image_metrics
from agrinerf_ns.views import evenly_spaced, rays_per_chunk


class TruthImages:
    """Clean truth RGB of a synthetic capture, undistorted exactly as ``agrinerf-process`` undistorts the frames."""

    def __init__(self, raw: Path) -> None:
        from agrinerf_ns.process import align, readers

        self.folder = raw / "truth" / "rgb_clean"
        if not self.folder.is_dir():
            raise FileNotFoundError(f"{self.folder}: no clean truth (only synthetic captures have it)")
        self._maps = align.undistort_maps(readers.read_calibration(raw / "calib.yaml").rgb)

    def get(self, name: str) -> torch.Tensor:
        """The truth for dataset image ``name`` as float (H, W, 3) in [0, 1]."""
        import cv2

        path = self.folder / name
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no truth image for the dataset frame {name}")
        image = np.asarray(Image.open(path).convert("RGB"))
        if self._maps is not None:
            image = cv2.remap(image, self._maps[0], self._maps[1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return torch.from_numpy(image.astype(np.float32) / 255.0)

    def fruit_mask(self, name: str) -> Optional[torch.Tensor]:
        """(H, W) bool: the truth's fruit pixels of dataset image ``name`` (``truth/fruit_ids``, undistorted like the
        frames); None where the capture has no fruit mask for it."""
        import cv2

        path = self.folder.parent / "fruit_ids" / Path(name).with_suffix(".png").name
        if not path.is_file():
            return None
        ids = np.asarray(Image.open(path)).astype(np.float32)
        if self._maps is not None:
            ids = cv2.remap(ids, self._maps[0], self._maps[1], cv2.INTER_NEAREST, borderMode=cv2.BORDER_REPLICATE)
        return torch.from_numpy(ids > 0)


def _load_at_step(step: int) -> Callable:
    def update(config):
        from nerfstudio.data.datamanagers.base_datamanager import VanillaDataManager
        from nerfstudio.data.datamanagers.parallel_datamanager import ParallelDataManagerConfig

        config.load_step = step
        if isinstance(config.pipeline.datamanager, ParallelDataManagerConfig):
            # same datasets and eval cameras, without spawning training worker processes for an evaluation
            config.pipeline.datamanager._target = VanillaDataManager
        return config

    return update


GRID_METRICS = ("fine_region_weight", "voxel_size_m", "voxel_size_final_m")
"""How the grids fit the scene (`eval_metrics.grid_diagnostics`): the share of the held-out rendering weight at full
resolution, the voxel size at the median rendered depth now and at the preset's final grids (metres)."""


def evaluate_checkpoint(
    config_path: Path,
    step: int,
    supervision: Literal["rgb", "thermal"],
    truth: Optional[TruthImages],
    chunk: Optional[int] = None,
    max_views: Optional[int] = None,
) -> Dict[str, object]:
    """Mean metrics over the eval split (or ``max_views`` of its views, evenly spaced) at one checkpoint, rendered
    ``chunk`` rays at a time (None: :func:`agrinerf_ns.views.rays_per_chunk`). ``supervision``: what the run's main
    ``psnr`` compares against (``"thermal"``: a stock method trained on the thermal frames, whose ``psnr`` is thermal).

    Keys: ``eval_views`` (how many views were rendered), ``psnr``, ``ssim``, ``lpips`` (vs captured RGB; NaN when
    LPIPS is unavailable), ``psnr_clean``, ``ssim_clean`` (vs clean truth), ``psnr_fruit`` (the same PSNR over the truth's fruit pixels), ``thermal_psnr``, ``thermal_ssim`` (vs the
    rescaled thermal frames), ``thermal_camera_psnr`` (the thermal-camera output, where the model has one),
    ``temperature_mae`` (degrees C, where the model has a temperature output), `GRID_METRICS` (AgriNeRF), and
    ``psnr_clean_per_view`` (each rendered view's ``psnr_clean``, by held-out index, for paired comparisons).
    """
    from nerfstudio.utils.eval_utils import eval_setup

    _, pipeline, _, _ = eval_setup(
        config_path,
        eval_num_rays_per_chunk=rays_per_chunk(chunk),
        test_mode="test",
        update_config_callback=_load_at_step(step),
    )
    datamanager = pipeline.datamanager
    names = [Path(p).name for p in datamanager.eval_dataset._dataparser_outputs.image_filenames]
    chosen = set(evenly_spaced(len(names), max_views))
    per_image: List[Dict[str, float]] = []
    for camera, batch in datamanager.fixed_indices_eval_dataloader:
        if int(batch["image_idx"]) not in chosen:
            continue
        with torch.no_grad():
            outputs = pipeline.model.get_outputs_for_camera(camera=camera)
        metrics, _ = pipeline.model.get_image_metrics_and_images(outputs, batch)
        row = {
            k: float(v)
            for k, v in metrics.items()
            if k
            in ("psnr", "ssim", "lpips", "thermal_psnr", "thermal_ssim", "thermal_camera_psnr", "temperature_mae")
            + GRID_METRICS
        }
        if supervision == "thermal" and "psnr" in row:  # Nerfacto on thermal frames: its psnr is thermal
            row = {"thermal_psnr": row["psnr"], "thermal_ssim": row["ssim"]}
        elif truth is not None and "rgb" in outputs:
            target = truth.get(names[int(batch["image_idx"])])
            aligned = image_metrics.exposure_align(outputs["rgb"].detach().cpu().float(), target)
            row["psnr_clean"] = image_metrics.psnr(aligned, target)
            row["ssim_clean"] = image_metrics.ssim(aligned, target)
            fruit = truth.fruit_mask(names[int(batch["image_idx"])])
            if fruit is not None and bool(fruit.any()):  # fine detail: the fruit pixels alone
                mse = float(((aligned - target) ** 2)[fruit].mean())
                row["psnr_fruit"] = -10.0 * math.log10(max(mse, 1e-10))
        per_image.append(row)
    keys = sorted({k for row in per_image for k in row})
    means: Dict[str, object] = {k: _nanmean([row.get(k, math.nan) for row in per_image]) for k in keys}
    if "psnr_clean" in keys:
        means["psnr_clean_per_view"] = ";".join(f"{row.get('psnr_clean', math.nan):.4f}" for row in per_image)
    return {**means, "eval_views": len(per_image)}


def _nanmean(values: List[float]) -> float:
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite else math.nan
