"""The methods the benchmark compares, and how each is launched with ``ns-train`` on a processed dataset."""

from __future__ import annotations

import dataclasses
import difflib
import importlib.metadata as metadata
import json
from dataclasses import dataclass
from typing import Any, Dict, List, Literal, Mapping, Optional, Sequence, Tuple

from agrinerf_ns.dataset_format import THERMAL_TRANSFORMS, TRANSFORMS
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
    step_scale: float = 1.0
    """Its step budget is its ``ns-train`` method's in the profile times this (a cheaper step trained for about the
    same wall time: `SAMPLE_BUDGETS`)."""

    @property
    def views_rgb_camera(self) -> bool:
        """Whether its cameras are the RGB camera's (``transforms.json``): Nerfacto (Thermal) trains on the thermal
        camera's (``transforms_thermal.json``); a Table IV ablation without RGB frames still has the RGB camera's."""
        return self.data_file == TRANSFORMS


VARIANT_SEPARATOR = "%"
"""Separates a bench key from the model config fields a variant sets: ``BASE%field=value[%field=value...]``."""


def field_values(key: str, texts: Sequence[str], known: Optional[Mapping[str, Any]] = None) -> Dict[str, Any]:
    """The ``FIELD=VALUE`` parts of a key (VALUE in JSON) as {field: value}: the model config fields a variant key
    (`variant`) or a ``bench_step_interleaved.py --runs`` entry sets (FIELD ``loss_coefficients.thermal_loss``: one
    entry of a dict field; ``camera_optimizer.mode``: a field of a nested config). Raises KeyError naming the key and
    the part that is not one, or the field that `known` (model config fields and their defaults, when given) lacks,
    with the close names."""
    values: Dict[str, Any] = {}
    for text in texts:
        name, equals, value_text = text.partition("=")
        if not name or not equals:
            raise KeyError(f"{key!r}: {text!r} is not FIELD=VALUE")
        if known is not None:
            _check_field(key, name, known)
        try:
            values[name] = json.loads(value_text)
        except json.JSONDecodeError as err:
            raise KeyError(f"{key!r}: the value of {name} is not JSON ({err})") from None
    return values


def _check_field(key: str, name: str, known: Mapping[str, Any]) -> None:
    """KeyError unless each part of ``name`` (``field[.entry...]``) is a field of the model config, an entry of a dict
    field's default or a field of a nested config: what ns-train's parser accepts (a dict field takes only the keys
    of its default)."""
    parts = name.split(".")
    choices: Mapping[str, Any] = known
    for depth, part in enumerate(parts):
        if part not in choices:
            close = difflib.get_close_matches(part, [str(c) for c in choices], n=3)
            hint = f" (close: {', '.join(close)})" if close else ""
            where = "no model config field" if depth == 0 else f"model config field {'.'.join(parts[:depth])} has no"
            raise KeyError(f"{key!r}: {where} {part!r}{hint}")
        choices = _entries(choices[part])


def _entries(value: Any) -> Mapping[str, Any]:
    """The names a dotted field can go on with below ``value``: a dict's keys, a nested config's fields, else none."""
    if isinstance(value, Mapping):
        return value
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: getattr(value, f.name) for f in dataclasses.fields(value)}
    return {}


def variant(key: str) -> BenchMethod:
    """The bench method of a variant key ``BASE%field=value[%field=value...]``: BASE's, with model config fields set
    through ``--pipeline.model.<field> <value>`` (`field_values`; a list is several values), e.g.
    ``agrinerf-lite%thermal_rays_per_batch=128``. Built from the key alone, so a worker process (``--ray``) rebuilds
    the same method. Raises KeyError naming the key and what is wrong (an unknown BASE or field, with close names)."""
    base_key, *fields = key.split(VARIANT_SEPARATOR)
    if base_key not in METHODS or not fields:
        close = difflib.get_close_matches(base_key, list(METHODS), n=3)
        hint = f" (close: {', '.join(close)})" if close else ""
        raise KeyError(f"{key!r}: {base_key!r} is not a bench method{hint}")
    base = METHODS[base_key]
    options: List[str] = []
    for name, value in field_values(key, fields, _model_fields(base.ns_method)).items():
        values = value if isinstance(value, list) else [value]
        options += [f"--pipeline.model.{name.replace('_', '-')}", *(str(v) for v in values)]
    return dataclasses.replace(base, label=f"{base.label} ({', '.join(fields)})",
                               train_args=base.train_args + tuple(options))  # fmt: skip


def unknown_reason(key: str) -> Optional[str]:
    """Why ``key`` is no bench method, for an error message (None when it is one)."""
    try:
        METHODS[key]
    except KeyError as err:
        if VARIANT_SEPARATOR in key and err.args:
            return str(err.args[0])  # variant(): names the unknown BASE or field
        close = difflib.get_close_matches(key, list(METHODS), n=3)
        return f"{key!r} is not a bench method" + (f" (close: {', '.join(close)})" if close else "")
    return None


def _model_fields(ns_method: str) -> Optional[Dict[str, Any]]:
    """The model config fields of this plugin's ``ns-train`` method with the preset's values (None for Nerfstudio's
    own methods: ns-train checks those); a dict field's value gives the keys it takes."""
    entry_point = next(iter(metadata.entry_points(group="nerfstudio.method_configs", name=ns_method)), None)
    if entry_point is None or not entry_point.value.startswith("agrinerf_ns."):
        return None
    model = entry_point.load().config.pipeline.model
    return {f.name: getattr(model, f.name) for f in dataclasses.fields(model) if not f.name.startswith("_")}


class MethodTable(Dict[str, BenchMethod]):
    """The bench methods by key; a variant key (`variant`) is built on lookup, not stored."""

    def __missing__(self, key: str) -> BenchMethod:
        if isinstance(key, str) and VARIANT_SEPARATOR in key:
            return variant(key)
        raise KeyError(key)

    def __contains__(self, key: object) -> bool:
        if super().__contains__(key):
            return True
        try:
            self[key]  # type: ignore[index]
        except KeyError:
            return False
        return True


METHODS: Dict[str, BenchMethod] = MethodTable(
    {
        m.ns_method if m.supervision == "rgb" else f"{m.ns_method}-thermal": m
        for m in (
            BenchMethod("AgriNeRF-lite", "agrinerf-lite", TRANSFORMS, "rgb"),
            BenchMethod("AgriNeRF", "agrinerf", TRANSFORMS, "rgb"),
            BenchMethod("EvDeblurNeRF-lite", "evdeblurnerf-lite", TRANSFORMS, "rgb"),
            BenchMethod("Nerfacto (RGB)", "nerfacto", TRANSFORMS, "rgb"),
            BenchMethod("Nerfacto (Thermal)", "nerfacto", THERMAL_TRANSFORMS, "thermal"),
            BenchMethod("TensoRF", "tensorf", TRANSFORMS, "rgb", ("nerfstudio-data",)),
        )
    }
)
"""Keyed by the name used on the ``agrinerf-bench --methods`` command line; variant keys (`variant`) too."""

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
            TRANSFORMS,
            "rgb" if "rgb" in TABLE_IV_ABLATIONS[name] else "thermal",
            train_args=("--pipeline.model.modalities", *TABLE_IV_ABLATIONS[name]),
        )
        for key, name in ABLATIONS.items()
    }
)


@dataclass(frozen=True)
class SampleBudget:
    """A preset with other sample counts, trained for about the preset's wall time."""

    preset: str
    fine_samples: int
    """Fine samples per ray (``--pipeline.model.num-fine-samples``)."""
    step_scale: float
    """Steps per step of the preset: the inverse of the variant's step time over the preset's (at the start grids,
    one thread, `benchmarks/bench_step_interleaved.py`; docs/benchmark.md), so both run about equally long."""
    event_rays: int = 0
    """Event samples per batch (``--pipeline.model.event-rays-per-batch``); 0: the preset's."""


SAMPLE_BUDGETS: Dict[str, SampleBudget] = {
    "agrinerf-paper-samples": SampleBudget("agrinerf", 64, 0.38, event_rays=1024),
    "agrinerf-lite-fine32": SampleBudget("agrinerf-lite", 32, 0.61),
}
"""Bench key -> a preset's sample budget, weighed against the preset at about equal wall time (docs/benchmark.md):
``agrinerf-paper-samples`` is the paper's 64 + 64 samples and 1024 event pixels, which the ``agrinerf`` preset
trades for 64 + 32 and 512, ``agrinerf-lite-fine32`` the lite preset's earlier 32 + 32 (results/sample-budget-walltime)."""


def _budget_label(budget: SampleBudget) -> str:
    events = f", {budget.event_rays} event samples" if budget.event_rays else ""
    return f"{METHODS[budget.preset].label} ({budget.fine_samples} fine samples{events})"


METHODS.update(
    {
        key: BenchMethod(
            _budget_label(budget),
            budget.preset,
            TRANSFORMS,
            "rgb",
            train_args=("--pipeline.model.num-fine-samples", str(budget.fine_samples))
            + (("--pipeline.model.event-rays-per-batch", str(budget.event_rays)) if budget.event_rays else ()),
            step_scale=budget.step_scale,
        )
        for key, budget in SAMPLE_BUDGETS.items()
    }
)

METHODS["agrinerf-lite-rgb-rays"] = BenchMethod(
    "AgriNeRF-lite (thermal terms on the RGB rays)",
    "agrinerf-lite",
    TRANSFORMS,
    "rgb",
    train_args=("--pipeline.model.thermal-rays-per-batch", "0"),
)
"""The lite preset with its thermal terms on the RGB camera's rays, as the paper writes L_th, instead of the thermal
camera's (`model/thermal_view.py`): what rendering them from the thermal camera changes, at equal steps."""
