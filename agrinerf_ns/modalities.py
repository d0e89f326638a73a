"""The sensor modalities a reconstruction can model, and the paper's Table IV combinations of them.

This is the one definition of :data:`Modality`; the config (``--pipeline.model.modalities``,
``--pipeline.datamanager.dataparser.modalities``), the dataset's ``agrinerf.modalities`` block and the dataparser's
``metadata["modalities"]`` all use it. Spelling: the modality is the stream, ``"events"`` (plural); the names of one
frame's data are singular, ``event``: the per-frame keys of ``transforms.json`` (``event_file_path``,
``event_mask_path``, ``event_sums_path``), the dataparser metadata (``event_filenames``, ``event_mask_filenames``)
and the training batch (``batch["event"]``, ``batch["event_mask"]``), as ``thermal`` / ``thermal_mask`` and
``image`` are one frame's data of the other two. :func:`normalise_modalities` accepts ``"event"`` for ``"events"``.
The detector's input (RGB or thermal) is a different notion: ``agrinerf_ns.detect.eval_plan.DetectorInput``.
"""

from __future__ import annotations

from typing import Dict, Iterable, Literal, Tuple

Modality = Literal["rgb", "thermal", "events"]
ALL_MODALITIES: Tuple[Modality, ...] = ("rgb", "thermal", "events")

DARK_RGB_LEVEL = 0.04
"""RGB frames whose mean is below this fraction of full scale (about 10 DN of 255) are dark: mostly noise. The one
default of the model's ``low_light_level``, the mask makers' ``dark_level`` and the dataparser's ``dark_rgb_level``
(the synthetic scenes' frames average 3 DN in the dark and 42-96 DN at dusk and by day)."""

TABLE_IV_ABLATIONS: Dict[str, Tuple[Modality, ...]] = {
    "RGB": ("rgb",),
    "RGB+Events": ("rgb", "events"),
    "RGB+Thermal": ("rgb", "thermal"),
    "Thermal": ("thermal",),
    "Thermal+Events": ("thermal", "events"),
    "All": ("rgb", "thermal", "events"),
}
"""The paper's Table IV rows as `--pipeline.model.modalities` values."""


def normalise_modalities(names: Iterable[str]) -> Tuple[str, ...]:
    """Canonical modality names ("event" is accepted for "events"), in ALL_MODALITIES order."""
    canon = {"events" if n == "event" else n for n in names}
    unknown = canon - set(ALL_MODALITIES)
    if unknown:
        raise ValueError(f"Unknown modalities {sorted(unknown)}; expected a subset of {ALL_MODALITIES}")
    return tuple(m for m in ALL_MODALITIES if m in canon)
