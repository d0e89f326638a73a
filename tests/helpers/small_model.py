"""The smallest AgriNeRF model config the model tests build (8^3 grids, 8 + 8 samples, narrow MLPs)."""

from typing import Any, Dict

SMALL_MODEL: Dict[str, Any] = dict(
    init_resolution=8,
    final_resolution=12,
    upsampling_iters=(3,),
    num_coarse_samples=8,
    num_fine_samples=8,
    num_density_components=3,
    num_rgb_components=4,
    rgb_appearance_dim=4,
    num_thermal_components=2,
    thermal_appearance_dim=3,
    mlp_width=16,
    thermal_mlp_width=8,
    occupancy_resolution=8,
)
"""`AgriNeRFModelConfig` fields; tests add their own (e.g. `density_shift`) on top."""
