"""The methods the benchmark compares, and how each is launched with ``ns-train`` on a processed dataset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Literal, Tuple


@dataclass(frozen=True)
class BenchMethod:
    """One row of the comparison."""

    label: str
    """Name in tables and plots (the paper's naming)."""
    ns_method: str
    """``ns-train`` method name."""
    data_file: str
    """Which transforms file of the dataset it trains on."""
    supervision: Literal["rgb", "thermal"]
    """What its main ``psnr`` metric compares against: the RGB or the thermal frames."""
    dataparser_args: Tuple[str, ...] = ()
    """Dataparser subcommand and options after the method options (e.g. Nerfstudio's for ``tensorf``)."""


METHODS: Dict[str, BenchMethod] = {
    m.ns_method if m.supervision == "rgb" else f"{m.ns_method}-thermal": m
    for m in (
        BenchMethod("AgriNeRF-lite", "agrinerf-lite", "transforms.json", "rgb"),
        BenchMethod("AgriNeRF", "agrinerf", "transforms.json", "rgb"),
        BenchMethod("Nerfacto (RGB)", "nerfacto", "transforms.json", "rgb"),
        BenchMethod("Nerfacto (Thermal)", "nerfacto", "transforms_thermal.json", "thermal"),
        BenchMethod("TensoRF", "tensorf", "transforms.json", "rgb", ("nerfstudio-data",)),
    )
}
"""Keyed by the name used on the ``agrinerf-bench --methods`` command line."""
