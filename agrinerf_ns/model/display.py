"""Outputs for display only: the RGB render at a chosen exposure, and temperatures on a fixed scale with a legend.

A field trained on a dark capture reproduces it faithfully: its ``rgb`` is as dark as the frames. ``rgb_display`` is
``rgb`` times a gain in linear light, ``2 ** EV``: by default the gain that brings the training frames' mean level
(dataparser metadata ``rgb_level`` times ``rgb_gain``) to :data:`DISPLAY_LEVEL`, a lit frame's (0 EV for frames that
are lit already); else the EV set in the viewer's control panel ("Display exposure (EV)"), by ``ns-render ...
--display-ev EV`` or by the environment variable ``AGRINERF_DISPLAY_EV``. ``temperature_display`` is the
``temperature`` output (degrees C) mapped to [0, 1] over the dataset's temperature range, so that a colour means the
same temperature in every view; the viewer's control panel shows its colour bar in degrees C.

Both are added where a camera is rendered whole (:meth:`DisplayOutputs.add`, called from the model's
``get_outputs_for_camera``: viewer, ``ns-render``, evaluation), never in training: no loss reads them, and ``ns-eval``
still scores ``rgb``. Where the training frames are dark (below ``DARK_RGB_LEVEL``), ``rgb_display`` comes first, so
the viewer opens on it.

``ns-render --display-ev``: :mod:`agrinerf_ns.render_option`.
"""

from __future__ import annotations

import base64
import io
import math
from typing import Any, Callable, Dict, Mapping, Optional, Sequence, Tuple

import torch
from jaxtyping import Float
from nerfstudio.utils import colormaps
from torch import Tensor, nn

from agrinerf_ns.modalities import DARK_RGB_LEVEL
from agrinerf_ns.render_option import env_ev

DISPLAY_LEVEL = 0.35
"""Mean sRGB level that ``rgb_display`` brings the training frames to by default: a lit frame's (the synthetic bright
orchard's frames average 0.36 of full scale)."""

EV_RANGE = (-4.0, 12.0)
"""The viewer slider's range of stops (12 stops: a gain of 4096)."""

DARK_LEVEL_NAME = "rgb_level"
GAIN_NAME = "rgb_gain"


def _srgb_to_linear(value: float) -> float:
    return value / 12.92 if value <= 0.04045 else ((value + 0.055) / 1.055) ** 2.4


def frames_ev(rgb_level: float, rgb_gain: float = 1.0) -> float:
    """The stops of gain (linear light) that bring frames of mean sRGB level ``rgb_level`` (times the dataset's
    ``rgb_gain``) to :data:`DISPLAY_LEVEL`; 0 for lit frames and where the level is unknown (NaN)."""
    level = min(rgb_level * rgb_gain, 1.0)
    if not math.isfinite(level) or level >= DISPLAY_LEVEL:
        return 0.0
    gain = _srgb_to_linear(DISPLAY_LEVEL) / _srgb_to_linear(max(level, 1.0 / 255.0))
    return float(min(max(math.log2(gain), 0.0), EV_RANGE[1]))


def expose(rgb: Any, ev: float) -> Any:
    """``rgb`` (sRGB in [0, 1], a tensor ``(..., 3)``) times ``2 ** ev`` in linear light, clipped to [0, 1]."""
    from agrinerf_ns.colour import linear_to_srgb, srgb_to_linear

    return linear_to_srgb(srgb_to_linear(rgb) * 2.0**ev)


def colour_bar_png(width: int = 256, height: int = 14) -> bytes:
    """A PNG of the colormap the viewer and ``ns-render`` give a one-channel output (Nerfstudio's default: turbo),
    from 0 (left) to 1 (right)."""
    import numpy as np
    import torch
    from nerfstudio.utils import colormaps
    from PIL import Image

    ramp = torch.linspace(0.0, 1.0, width)[None, :, None].expand(height, width, 1)  # cpu: a legend image, not a render
    colours = colormaps.apply_colormap(ramp, colormaps.ColormapOptions())
    buffer = io.BytesIO()
    Image.fromarray((colours.numpy() * 255).round().astype(np.uint8)).save(buffer, format="PNG")
    return buffer.getvalue()


def legend_markdown(low_c: float, high_c: float) -> str:
    """The viewer's legend of ``temperature_display``: its colour bar with the temperatures at its ends and middle."""
    data = base64.b64encode(colour_bar_png()).decode()
    middle = (low_c + high_c) / 2
    return (
        f"**temperature_display**, degrees C\n\n![colour scale](data:image/png;base64,{data})\n\n"
        f"{low_c:.1f} °C | {middle:.1f} °C | {high_c:.1f} °C (left, middle, right)\n\n"
        "The colours match this bar with Render Options > Normalize unchecked (checked, they span each frame's range)."
    )


def _viewer_elements(auto_ev: float, temperature_range: Optional[Tuple[float, float]]) -> Tuple[Any, Any]:
    """The viewer's exposure slider and temperature legend (None where Nerfstudio's viewer cannot be imported)."""
    try:
        from nerfstudio.viewer.viewer_elements import ViewerElement, ViewerSlider
    except ImportError:  # a Nerfstudio without the viewer: the outputs still work
        return None, None

    class ViewerLegend(ViewerElement[str]):
        """A read-only markdown block in the viewer's control panel (a colour bar with its labels)."""

        def __init__(self, name: str, markdown: str) -> None:
            super().__init__(name)
            self.value = markdown

        def _create_gui_handle(self, viser_server: Any) -> None:
            self.gui_handle = viser_server.gui.add_markdown(self.value, visible=self.visible)

        def install(self, viser_server: Any) -> None:
            self._create_gui_handle(viser_server)

    low, high = EV_RANGE
    hint = "Stops of gain on rgb_display (default: from the training frames); rgb is untouched"
    slider = ViewerSlider("Display exposure (EV)", round(auto_ev * 4) / 4, low, high, 0.25, hint=hint)
    legend = None
    if temperature_range is not None:
        legend = ViewerLegend("Temperature scale", legend_markdown(*temperature_range))
    return slider, legend


class DisplayOutputs(nn.Module):
    """The display outputs of one model (see the module's docstring)."""

    def __init__(
        self,
        metadata: Mapping[str, Any],
        temperature_range: Optional[Tuple[float, float]] = None,
        temperature_unit: Optional[Callable[[Any], Any]] = None,
    ) -> None:
        super().__init__()  # a module without parameters: the viewer finds its controls in the model's modules
        level = float(metadata.get(DARK_LEVEL_NAME, math.nan))
        self.auto_ev = frames_ev(level, float(metadata.get(GAIN_NAME, 1.0)))
        """The default exposure, from the training frames."""
        self.dark = level * float(metadata.get(GAIN_NAME, 1.0)) < DARK_RGB_LEVEL
        """Whether the training frames (as trained on) are dark (:data:`~agrinerf_ns.modalities.DARK_RGB_LEVEL`, the
        model's low-light rule): then the viewer opens on ``rgb_display``."""
        self.temperature_range = temperature_range
        """(low, high) degrees C of ``temperature_display``'s [0, 1]; None: the model renders no temperature."""
        self.temperature_unit = temperature_unit
        """Degrees C -> [0, 1] over ``temperature_range`` (the model's ``temperature_unit``)."""
        self.slider, self.legend = _viewer_elements(self.auto_ev, temperature_range)

    @classmethod
    def of(cls, model: Any, metadata: Mapping[str, Any]) -> "DisplayOutputs":
        """The display outputs of an AgriNeRF ``model`` built on a dataset with ``metadata``: the temperature scale
        where the model has a temperature head and the dataset its range (``model.temperature_stats``)."""
        stats = model.temperature_stats if model.field.temperature_head is not None else None
        low_high = (stats["min_c"], stats["max_c"]) if stats else None
        return cls(metadata, low_high, model.temperature_unit if low_high else None)

    def ev(self) -> float:
        """The exposure in stops: ``AGRINERF_DISPLAY_EV`` where set, else the viewer's slider, else the training
        frames'."""
        chosen = env_ev()
        if chosen is not None:
            return chosen
        return float(self.slider.value) if self.slider is not None else self.auto_ev

    def add(self, outputs: Dict[str, Any]) -> Dict[str, Any]:
        """``outputs`` with ``rgb_display`` (where it has ``rgb``; first where the frames are dark) and
        ``temperature_display`` (where it has ``temperature`` and the range is known)."""
        added: Dict[str, Any] = {}
        if "rgb" in outputs:
            added["rgb_display"] = expose(outputs["rgb"], self.ev())
        if "temperature" in outputs and self.temperature_range is not None and self.temperature_unit is not None:
            added["temperature_display"] = self.temperature_unit(outputs["temperature"])
        if not added:
            return outputs
        if self.dark and "rgb_display" in added:
            return {"rgb_display": added.pop("rgb_display"), **outputs, **added}
        return {**outputs, **added}

    def viewer_elements(self) -> Sequence[Any]:
        """The viewer's controls of these outputs (for tests)."""
        return [e for e in (self.slider, self.legend) if e is not None]


def temperature_unit(celsius: Tensor, stats: Optional[Mapping[str, float]]) -> Tensor:
    """Degrees C -> [0, 1] over the dataset's temperature range `stats` (``min_c``, ``max_c``; None: [0, 1] C)."""
    stats = stats or {"min_c": 0.0, "max_c": 1.0}
    low, high = stats["min_c"], max(stats["max_c"], stats["min_c"] + 1e-3)
    return ((celsius - low) / (high - low)).clamp(0.0, 1.0)


def rgba_image(
    outputs: Dict[str, Tensor], output_name: str, temperature_unit: Callable[[Tensor], Tensor]
) -> Float[Tensor, "*bs 4"]:
    """RGB plus alpha of an output, for Nerfstudio's exporters (`ns-export pointcloud`, `tsdf`, `poisson`).

    Alpha is the accumulation, so a ray that hits nothing (accumulation below 0.5, where the median depth is not a
    surface) gives no point. A single-channel output (`thermal`) is coloured by Nerfstudio's colormap for one channel
    (turbo, unnormalised: colours mean the same value in every export); `temperature` first by `temperature_unit`.
    """
    image = outputs[output_name]
    if output_name == "temperature":
        image = temperature_unit(image)
    if image.shape[-1] not in (1, 3):
        raise ValueError(f"Output '{output_name}' has {image.shape[-1]} channels; an RGBA export needs 1 or 3")
    colours = colormaps.apply_colormap(image.clamp(0.0, 1.0))
    return torch.cat([colours, outputs["accumulation"].to(colours.dtype)], dim=-1)
