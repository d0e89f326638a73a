"""Held-out image metrics of an AgriNeRF render: RGB PSNR / SSIM / LPIPS, the thermal outputs' PSNR and SSIM over
the thermal mask, the temperature error, and where the rendering weight falls on the grids."""

from __future__ import annotations

from typing import Any, Callable, Dict, Optional, Protocol, Tuple, runtime_checkable

import torch
from jaxtyping import Float
from nerfstudio.utils import colormaps
from torch import Tensor

from agrinerf_ns.model import losses
from agrinerf_ns.model.fruit_head import fruit_iou
from agrinerf_ns.model.plan import ModelPlan


@runtime_checkable
class Evaluated(Protocol):
    """What the held-out metrics read of a model."""

    plan: ModelPlan
    psnr: Callable[..., Tensor]
    ssim: Callable[..., Any]
    metres_per_unit: Optional[float]
    camera_optimizer: Any

    @property
    def device(self) -> torch.device: ...

    def temperature_unit(self, celsius: Tensor) -> Tensor: ...

    def lpips(self) -> torch.nn.Module: ...


def image_metrics_and_images(
    model: Evaluated, outputs: Dict[str, Tensor], thermal_outputs: Dict[str, Tensor], batch: Dict[str, Any]
) -> Tuple[Dict[str, float], Dict[str, Tensor]]:
    """RGB: psnr, ssim, lpips; thermal (and thermal_camera): <output>_psnr, <output>_ssim against the rescaled
    thermal frames, over the thermal mask (read from `thermal_outputs`: the outputs with their thermal ones as the
    thermal camera saw them, where training used that camera). Images side by side."""
    metrics: Dict[str, float] = {}
    images: Dict[str, Tensor] = {
        "accumulation": colormaps.apply_colormap(outputs["accumulation"]),
        "depth": colormaps.apply_depth_colormap(outputs["depth"], accumulation=outputs["accumulation"]),
    }
    metrics.update(grid_diagnostics(model.metres_per_unit, outputs))
    plan = model.plan
    if plan.use_rgb:
        gt = batch["image"][..., :3].to(model.device).float()
        pred = outputs["rgb"]
        images["img"] = torch.cat([gt, pred], dim=1)
        gt_c, pred_c = gt.permute(2, 0, 1)[None], pred.permute(2, 0, 1)[None]
        metrics["psnr"] = float(model.psnr(pred_c, gt_c).item())
        metrics["ssim"] = float(model.ssim(pred_c, gt_c).item())  # type: ignore[union-attr]
        metrics["lpips"] = float(model.lpips()(pred_c.clamp(0, 1), gt_c.clamp(0, 1)).item())
    if "fruit" in outputs and "fruit" in batch:  # the fruit head against the held-out frame's mask
        known = batch["fruit_known"].to(model.device)
        thermal_mask = "fruit_thermal" in batch and bool(batch["fruit_thermal"].flatten()[0] > 0.5)
        fruit = thermal_outputs["fruit"] if thermal_mask and "fruit" in thermal_outputs else outputs["fruit"]
        metrics["fruit_iou"] = fruit_iou(fruit, batch["fruit"].to(model.device), known)
        images["fruit"] = torch.cat([batch["fruit"].to(model.device) * known, fruit], dim=1).expand(-1, -1, 3)
    outputs = thermal_outputs
    if plan.has_thermal_head:
        pred_th = outputs["thermal"]
        images["thermal"] = pred_th.expand(*pred_th.shape[:-1], 3)
        if plan.use_thermal and "thermal" in batch:
            gt_th = batch["thermal"].to(model.device).float()
            mask = batch.get("thermal_mask")
            mask = torch.ones_like(gt_th) if mask is None else (mask.to(model.device).float() > 0.5).float()
            for name in ("thermal", "thermal_camera"):
                if name in outputs:
                    metrics.update(thermal_metrics(model, name, outputs[name], gt_th, mask))
                    images[name] = torch.cat([gt_th, outputs[name]], dim=1).expand(-1, -1, 3)
    if "temperature" in outputs and "temperature" in batch:
        gt_t = batch["temperature"].to(model.device).float()
        mask_t = batch.get("temperature_mask")
        mask_t = torch.ones_like(gt_t) if mask_t is None else (mask_t.to(model.device).float() > 0.5).float()
        error = (outputs["temperature"] - gt_t).abs() * mask_t
        metrics["temperature_mae"] = float((error.sum() / mask_t.sum().clamp(min=1.0)).item())
        images["temperature"] = colormaps.apply_colormap(
            model.temperature_unit(torch.cat([gt_t * mask_t, outputs["temperature"]], dim=1))
        )
    model.camera_optimizer.get_metrics_dict(metrics)  # type: ignore[arg-type]
    return metrics, images


def grid_diagnostics(metres_per_unit: Optional[float], outputs: Dict[str, Tensor]) -> Dict[str, float]:
    """How well the grids fit the scene in a rendered image: `fine_region_weight`, the share of its rendering
    weight inside the full-resolution box, and `voxel_size_m`, the median over the rays that hit something
    (accumulation > 0.5) of the largest side of the grid cell at the ray's median depth, in metres (NaN where the
    dataset's scale is unknown; `voxel_size_units` in scene units); `voxel_size_final_m`: the same at the
    preset's final resolution in the current box."""
    if "full_resolution_weight" not in outputs:
        return {}
    acc = outputs["accumulation"]
    share = outputs["full_resolution_weight"].sum() / acc.sum().clamp(min=1e-12)
    hits = acc[..., 0] > 0.5
    scale = float("nan") if metres_per_unit is None else float(metres_per_unit)
    metrics = {"fine_region_weight": float(share)}
    for key in ("voxel_size", "voxel_size_final"):
        sizes = outputs[key][..., 0][hits] if bool(hits.any()) else outputs[key].reshape(-1)
        metrics[f"{key}_units"] = float(sizes.median())
        metrics[f"{key}_m"] = metrics[f"{key}_units"] * scale
    return metrics


def thermal_metrics(
    model: Evaluated,
    name: str,
    pred: Float[Tensor, "h w 1"],
    gt: Float[Tensor, "h w 1"],
    mask: Float[Tensor, "h w 1"],
) -> Dict[str, float]:
    """`<name>_psnr` over the thermal mask and `<name>_ssim` (outside the mask the prediction is replaced by the
    truth first) of one thermal output against the rescaled thermal frame."""
    mse = losses.thermal_loss(pred, gt, mask)
    filled = pred * mask + gt * (1.0 - mask)
    ssim = model.ssim(filled.permute(2, 0, 1)[None], gt.permute(2, 0, 1)[None])  # type: ignore[operator]
    return {
        f"{name}_psnr": float((-10.0 * torch.log10(mse.clamp(min=1e-10))).item()),
        f"{name}_ssim": float(ssim.item()),  # type: ignore[union-attr]
    }
