"""`agrinerf-bench --methods BASE%FIELD=VALUE`: a preset with model config fields set, from the key alone."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import tyro
import yaml

from agrinerf_ns.lab import results
from agrinerf_ns.lab.cli import BenchConfig, main
from agrinerf_ns.lab.methods import METHODS
from agrinerf_ns.method_configs.agrinerf_methods import agrinerf_lite


def test_a_variant_key_sets_the_fields_as_ns_train_parses_them() -> None:
    key = "agrinerf-lite%thermal_rays_per_batch=128%upsampling_iters=[100,200,300]%thermal_view_dependent=true"
    assert key in METHODS
    method = METHODS[key]
    assert (method.ns_method, method.data_file, method.supervision) == ("agrinerf-lite", "transforms.json", "rgb")
    assert (
        method.label
        == "AgriNeRF-lite (thermal_rays_per_batch=128, upsampling_iters=[100,200,300], thermal_view_dependent=true)"
    )
    preset = agrinerf_lite.config
    parsed = tyro.cli(tyro.conf.FlagConversionOff[type(preset)], default=preset, args=list(method.train_args))
    model = parsed.pipeline.model
    assert model.thermal_rays_per_batch == 128 and tuple(model.upsampling_iters) == (100, 200, 300)
    assert model.thermal_view_dependent and not preset.pipeline.model.thermal_view_dependent
    assert preset.pipeline.model.thermal_rays_per_batch == 256  # the registry's preset is left as it was


def test_a_variant_key_sets_one_entry_of_a_dict_field() -> None:
    method = METHODS["agrinerf-lite%loss_coefficients.event_loss=0"]
    preset = agrinerf_lite.config
    parsed = tyro.cli(tyro.conf.FlagConversionOff[type(preset)], default=preset, args=list(method.train_args))
    coefficients = parsed.pipeline.model.loss_coefficients
    assert coefficients["event_loss"] == 0.0 and preset.pipeline.model.loss_coefficients["event_loss"] > 0
    assert {k: v for k, v in coefficients.items() if k != "event_loss"} == {
        k: v for k, v in preset.pipeline.model.loss_coefficients.items() if k != "event_loss"
    }


@pytest.mark.parametrize(
    "key, reason",
    [
        ("agrinerf-lite%no_such_field=1", "'agrinerf-lite%no_such_field=1': no model config field 'no_such_field'"),
        ("agrinerf-lite%thermal_rays=128", r"no model config field 'thermal_rays' \(close: thermal_rays_per_batch"),
        ("agrinerf-lite%loss_weights.event_loss=0", "no model config field 'loss_weights'"),
        ("agrinerf-lite%loss_coefficients.evnt_loss=0", r"loss_coefficients has no 'evnt_loss' \(close: event_loss"),
        ("agrinerf-lite%camera_optimizer.mod=0", r"camera_optimizer has no 'mod' \(close: mode"),
        ("agrinerf-lite%thermal_rays_per_batch.x=1", "thermal_rays_per_batch has no 'x'"),
        ("agrinerf-lite%thermal_rays_per_batch", "not FIELD=VALUE"),
        ("agrinerf-lite%thermal_rays_per_batch=12x", "not JSON"),
        ("no-such-method%thermal_rays_per_batch=1", "'no-such-method' is not a bench method"),
        ("agrinerf-lte%thermal_rays_per_batch=1", r"'agrinerf-lte' is not a bench method \(close: agrinerf-lite"),
    ],
)
def test_a_bad_variant_key_is_refused_with_the_reason(key: str, reason: str) -> None:
    """At lookup, naming the key and the unknown BASE or field with the close names; the bench's own error too."""
    assert key not in METHODS
    with pytest.raises(KeyError, match=reason):
        METHODS[key]
    with pytest.raises(ValueError, match="unknown methods") as err:
        main(BenchConfig(out=Path("/nonexistent"), profile="tiny", methods=(key,)))
    assert key in str(err.value) and re.search(reason, str(err.value))


def test_a_variant_key_sets_a_field_of_a_nested_config() -> None:
    method = METHODS['agrinerf-lite%camera_optimizer.mode="SO3xR3"']
    preset = agrinerf_lite.config
    parsed = tyro.cli(tyro.conf.FlagConversionOff[type(preset)], default=preset, args=list(method.train_args))
    assert parsed.pipeline.model.camera_optimizer.mode == "SO3xR3"
    assert preset.pipeline.model.camera_optimizer.mode == "off"


def test_the_bench_trains_a_variant_under_its_own_key(tmp_path: Path) -> None:
    key = "agrinerf-lite%thermal_rays_per_batch=0%upsampling_iters=[2,4,6]"
    rows = main(BenchConfig(out=tmp_path / "bench", profile="tiny", methods=(key,)))
    assert rows and {r["method"] for r in rows} == {key}
    assert {r["method"] for r in results.read_rows(tmp_path / "bench" / "results.csv")} == {key}
    (config,) = (tmp_path / "bench" / "runs").glob("*/*/agrinerf-lite/run/config.yml")
    model = yaml.load(config.read_text(), Loader=yaml.Loader).pipeline.model
    assert model.thermal_rays_per_batch == 0 and tuple(model.upsampling_iters) == (2, 4, 6)
