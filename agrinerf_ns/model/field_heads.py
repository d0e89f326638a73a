"""Field head names that Nerfstudio's FieldHeadNames does not have."""

from enum import Enum


class AgriNeRFFieldHeadNames(Enum):
    """Extra outputs of the AgriNeRF field (Nerfstudio's own heads stay in `FieldHeadNames`)."""

    THERMAL = "thermal"
    """Thermal head values in [0, 1] per sample: channel 0 the cross-spectral value, channel 1 (when built) the thermal
    camera's value."""
    TEMPERATURE = "temperature"
    """Temperature per sample in the dataset's normalised units, (T - mean) / std (the model turns it into degrees C)."""
