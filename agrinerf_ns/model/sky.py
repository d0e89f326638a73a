"""The sky, found in the thermal frames and kept out of the field.

An L-inf contracted field renders the sky opaque in its outer shell (a far sample spans hundreds of scene units, so
even the density of empty space stops the ray there) and grows haze where sky rays cross the full-resolution box: on
the quick profile's shadowed orchard after 390 `agrinerf` steps the sky pixels' accumulation is 0.999 and a third of
their rendering weight lies inside the box (results/sky). Both are false geometry: exported points on a shell around
the scene, density that a 3D fruit count must ignore, and weight that `fine_region_weight` counts outside the box.

A radiometric thermal camera tells the sky apart without a segmentation model: a clear or hazy sky is tens of degrees
colder than the leaves, fruit, bark and soil it frames. Where the dataset's coldest pixels are far colder than its
mean (`sky_temperature_margin_c`), the pixels near that cold end (`sky_threshold_c`) are sky, and `sky_loss` drives
the accumulation of their rays to zero and that of the rays of pixels near the warm end (the canopy, the ground) to
one; their colour and temperature then come from `SkyField`, a function of the ray's direction alone (spherical
harmonics and a small MLP), composited behind the field's last sample and trained by the data terms through the
transmittance the field leaves. The heads at the far end of each ray (`background_color` "last_sample") modelled the
sky's thermal gradient worse: twice the temperature error on the sky's pixels (results/sky).
Where the thermal camera's rays carry the thermal terms (`thermal_view`) the mask is exact on them; otherwise it is
read on the RGB rays from the warped frames, exact for the sky itself (the warp is through the plane at infinity)
and off by the cameras' parallax only at near silhouettes. A cloud within the margin of the scene's temperature is
not masked: it keeps the field's far shell, as without the term.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Dict, Optional

import torch
from jaxtyping import Bool, Float
from nerfstudio.field_components.encodings import SHEncoding
from nerfstudio.field_components.mlp import MLP
from torch import Tensor, nn

if TYPE_CHECKING:
    from agrinerf_ns.model.model import AgriNeRFModel


def uses_thermal_sky(model: AgriNeRFModel) -> bool:
    """Whether `sky_loss` applies (and the model has a `SkyField`): the model has the temperature output (a
    radiometric thermal camera), the term a weight, and the frames show sky (`sky_threshold_c`)."""
    return (
        model.has_temperature
        and model.temperature_stats is not None
        and model.config.loss_coefficients.get("sky_loss", 0.0) > 0
        and sky_threshold_c(model) is not None
    )


SKY_CHANNELS = {"rgb": slice(0, 3), "thermal": slice(3, 4), "thermal_camera": slice(4, 5), "temperature": slice(5, 6)}
"""The outputs the sky gives, and their channels of `SkyField`'s MLP."""


class SkyField(nn.Module):
    """What lies beyond the field along a direction: colour, thermal values (sigmoid, as the heads') and temperature
    (in the temperature head's normalised units), from degree-3 spherical harmonics of the direction through a
    small MLP. Smooth in direction, as a sky is; it holds no geometry."""

    def __init__(self, width: int = 32) -> None:
        super().__init__()
        self.encoding = SHEncoding(levels=4, implementation="torch")
        self.mlp = MLP(in_dim=self.encoding.get_out_dim(), num_layers=2, layer_width=width, out_dim=6,
                       activation=nn.ReLU(), out_activation=None, implementation="torch")  # fmt: skip

    def forward(self, directions: Float[Tensor, "rays 3"]) -> Dict[str, Float[Tensor, "rays c"]]:
        raw = self.mlp(self.encoding(torch.nn.functional.normalize(directions.float(), dim=-1)))
        values = {name: raw[:, channels] for name, channels in SKY_CHANNELS.items()}
        return {name: v if name == "temperature" else torch.sigmoid(v) for name, v in values.items()}


def backgrounds(
    model: AgriNeRFModel, directions: Float[Tensor, "rays 3"], dense: Dict[str, Float[Tensor, "rays samples c"]]
) -> Dict[str, Float[Tensor, "rays c"]]:
    """The value behind the last sample of each output in `dense` (per-sample values, temperature in degrees C):
    the `SkyField` where the model has one, else `background_color` (the last sample's value, black or white)."""
    if model.sky_field is not None and dense:
        sky = model.sky_field(directions)
        head = model.field.temperature_head
        if "temperature" in dense and head is not None:
            sky["temperature"] = head.to_celsius(sky["temperature"])
        return {name: sky[name].to(values.dtype) for name, values in dense.items()}
    if model.config.background_color == "last_sample":
        return {name: values[:, -1, :] for name, values in dense.items()}
    fill = 1.0 if model.config.background_color == "white" else 0.0
    return {name: torch.full_like(values[:, -1, :], fill) for name, values in dense.items()}


def sky_threshold_c(model: AgriNeRFModel) -> Optional[float]:
    """Temperatures (degrees C) below this are sky: the dataset's coldest pixel plus `sky_temperature_fraction` of
    the span from it to the mean temperature. None where that span is under `sky_temperature_margin_c`: the frames
    show no sky colder than the scene. Measured from the cold end, so the pixels at the sky's edges, which the thermal
    optics mix with the canopy (the quick profile's orchards: a ramp from 2 to 17 C between a -7 to 2 C sky and
    19 C leaves), stay out of the mask; a threshold at the mean less 8 C took them in and cost 1.6 dB of RGB PSNR
    (results/sky)."""
    assert model.temperature_stats is not None
    mean, coldest = float(model.temperature_stats["mean_c"]), float(model.temperature_stats["min_c"])
    if mean - coldest < float(model.config.sky_temperature_margin_c):
        return None
    return coldest + float(model.config.sky_temperature_fraction) * (mean - coldest)


def sky_mask(
    model: AgriNeRFModel,
    temperature: Float[Tensor, "*bs 1"],
    valid: Optional[Float[Tensor, "*bs 1"]],
    scene: bool = False,
) -> Bool[Tensor, "*bs 1"]:
    """Rays whose temperature pixel is valid (the thermal mask) and colder than `sky_threshold_c`; `scene`: those
    warmer than its mirror at the warm end, `sky_temperature_fraction` of the span below the mean (surfaces the
    field must hold). None of either where the frames show no sky; between the two lie the sky's blended edges."""
    threshold = sky_threshold_c(model)
    if threshold is None:
        return torch.zeros_like(temperature, dtype=torch.bool)
    assert model.temperature_stats is not None
    if scene:
        mean = float(model.temperature_stats["mean_c"])
        picked = torch.isfinite(temperature) & (temperature >= mean - (threshold - model.temperature_stats["min_c"]))
    else:
        picked = torch.isfinite(temperature) & (temperature < threshold)
    if valid is not None:
        picked = picked & (valid > 0.5)
    return picked


def sky_loss(
    accumulation: Float[Tensor, "rays 1"], sky: Bool[Tensor, "rays 1"], scene: Bool[Tensor, "rays 1"]
) -> Tensor:
    """Mean accumulation of the sky rays plus mean transparency of the scene rays (each 0 where the batch has none):
    without the second, the `SkyField` explains far, even surfaces too (the ground by the cameras went half
    transparent on the quick profile's shadowed orchard). L1, so the last haze is pushed out as hard as the first."""
    acc = accumulation.float()
    sky_w, scene_w = sky.to(torch.float32), scene.to(torch.float32)
    return (acc * sky_w).sum() / sky_w.sum().clamp(min=1.0) + ((1.0 - acc) * scene_w).sum() / scene_w.sum().clamp(
        min=1.0
    )
