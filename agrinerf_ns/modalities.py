"""The sensor modalities a reconstruction can model, and the paper's Table IV combinations of them."""

from __future__ import annotations

from typing import Dict, Iterable, Literal, Tuple

Modality = Literal["rgb", "thermal", "events"]
ALL_MODALITIES: Tuple[Modality, ...] = ("rgb", "thermal", "events")

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
