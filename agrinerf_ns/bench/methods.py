"""The methods the benchmark compares, and how each is launched with ``ns-train`` on a processed dataset."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, Literal, Tuple

from agrinerf_ns.modalities import TABLE_IV_ABLATIONS


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
    train_args: Tuple[str, ...] = ()
    """Method options for ``ns-train`` (e.g. the modalities of a Table IV ablation)."""


METHODS: Dict[str, BenchMethod] = {
    m.ns_method if m.supervision == "rgb" else f"{m.ns_method}-thermal": m
    for m in (
        BenchMethod("AgriNeRF-lite", "agrinerf-lite", "transforms.json", "rgb"),
        BenchMethod("AgriNeRF", "agrinerf", "transforms.json", "rgb"),
        BenchMethod("EvDeblurNeRF-lite", "evdeblurnerf-lite", "transforms.json", "rgb"),
        BenchMethod("Nerfacto (RGB)", "nerfacto", "transforms.json", "rgb"),
        BenchMethod("Nerfacto (Thermal)", "nerfacto", "transforms_thermal.json", "thermal"),
        BenchMethod("TensoRF", "tensorf", "transforms.json", "rgb", ("nerfstudio-data",)),
    )
}
"""Keyed by the name used on the ``agrinerf-bench --methods`` command line."""

ABLATION_PREFIX = "lite-ablation-"
ABLATIONS: Dict[str, str] = {
    ABLATION_PREFIX + name.lower().replace("+", "-"): name for name in TABLE_IV_ABLATIONS if name != "All"
}
"""Bench key -> Table IV row: AgriNeRF-lite trained on the modalities of one row of the paper's Table IV. The "All" row
is ``agrinerf-lite`` itself (it models every modality the dataset has)."""
METHODS.update(
    {
        key: BenchMethod(
            f"AgriNeRF-lite ({name})",
            "agrinerf-lite",
            "transforms.json",
            "rgb" if "rgb" in TABLE_IV_ABLATIONS[name] else "thermal",
            train_args=("--pipeline.model.modalities", *TABLE_IV_ABLATIONS[name]),
        )
        for key, name in ABLATIONS.items()
    }
)

SAMPLE_BUDGETS: Dict[str, Tuple[str, int]] = {
    "agrinerf-fine32": ("agrinerf", 32),
    "agrinerf-lite-fine16": ("agrinerf-lite", 16),
}
"""Bench key -> (preset, fine samples per ray): a preset with half its fine samples, at its own step budget, to weigh
the sample budget against wall time (docs/benchmark.md)."""
METHODS.update(
    {
        key: BenchMethod(
            f"{METHODS[preset].label} ({fine} fine samples)",
            preset,
            "transforms.json",
            "rgb",
            train_args=("--pipeline.model.num-fine-samples", str(fine)),
        )
        for key, (preset, fine) in SAMPLE_BUDGETS.items()
    }
)
