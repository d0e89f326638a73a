"""Field head names that Nerfstudio's FieldHeadNames does not have."""

from enum import Enum


class AgriNeRFFieldHeadNames(Enum):
    """Extra outputs of the AgriNeRF field (Nerfstudio's own heads stay in `FieldHeadNames`)."""

    THERMAL = "thermal"
    """Single-channel cross-spectral (thermal) value in [0, 1] per sample."""
