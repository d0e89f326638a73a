"""The deblur benchmark's rows: each row's options parse into the config it names (a misspelt flag would only fail
an hour into a campaign), and the rows that switch parts of EvDeblurNeRF's recipe off change only those parts."""

from __future__ import annotations

import pytest
import tyro
from helpers.bench_script import load_bench_script

from agrinerf_ns.method_configs.agrinerf_methods import agrinerf_lite, evdeblurnerf_lite

BENCH = load_bench_script("bench_event_deblur")
PRESETS = {"agrinerf-lite": agrinerf_lite.config, "evdeblurnerf-lite": evdeblurnerf_lite.config}


def _parsed(key: str):
    return _parsed_method(BENCH.method(key))


def _parsed_method(method):
    preset = PRESETS[method.ns_method]
    # as ns-train parses them (booleans take a value: --flag False)
    return tyro.cli(tyro.conf.FlagConversionOff[type(preset)], default=preset, args=list(method.train_args))


def test_the_published_recipe_rows_switch_off_only_their_part() -> None:
    published = evdeblurnerf_lite.config
    recipe_rgb, kernel = _parsed("recipe-rgb"), _parsed("learnt-kernel")
    pdrf_lr, fine32 = _parsed("evdeblurnerf-lite-pdrf-lr"), _parsed("evdeblurnerf-lite-fine32")
    for config in (recipe_rgb, kernel):
        assert config.pipeline.model.modalities == ("rgb",) and not config.pipeline.model.edi_prior
    assert recipe_rgb.pipeline.model.blur_samples == 1  # no kernel
    assert kernel.pipeline.model.blur_kernel == "learnt"
    assert kernel.pipeline.model.blur_samples == published.pipeline.model.blur_samples == 10
    # the preset's grids learn at TensoRF's rate; the variant restores the published PDRF one, same decay
    assert published.optimizers["encodings"]["optimizer"].lr == pytest.approx(0.02)
    encodings = pdrf_lr.optimizers["encodings"]
    assert encodings["optimizer"].lr == pytest.approx(5e-3)
    assert encodings["scheduler"].lr_final == pytest.approx(5e-3 * 0.1 ** (2000 / 10_000), rel=1e-5)
    assert pdrf_lr.optimizers["fields"]["optimizer"].lr == published.optimizers["fields"]["optimizer"].lr == 5e-3
    assert pdrf_lr.pipeline.model == published.pipeline.model
    assert fine32.pipeline.model.num_fine_samples == 32 == published.pipeline.model.num_fine_samples  # the preset's
    for key in ("recipe-rgb", "learnt-kernel", "evdeblurnerf-lite-pdrf-lr", "evdeblurnerf-lite-fine32"):
        assert BENCH.row_profile(BENCH.PROFILES["deblur"], key).steps == BENCH.PROFILES["deblur"].steps  # 1600 steps


def test_each_minus_part_row_is_evdeblurnerf_without_that_part_alone() -> None:
    """Issue #63, item 1a: each row differs from the published recipe in its own model fields, nothing else."""
    import dataclasses

    published = evdeblurnerf_lite.config
    expected = {
        "evdeblurnerf-lite-no-edi": {"edi_prior": False},
        "evdeblurnerf-lite-no-crf": {"event_crf": False},
        "evdeblurnerf-lite-trajectory": {"blur_kernel": "trajectory"},
        "evdeblurnerf-lite-windows": {"event_supervision": "stream", "event_crf": False},
    }
    assert published.pipeline.model.edi_prior and published.pipeline.model.event_crf
    assert (published.pipeline.model.blur_kernel, published.pipeline.model.event_supervision) == ("learnt", "pairs")
    for key, fields in expected.items():
        config = _parsed(key)
        model = config.pipeline.model
        changed = {f.name: getattr(model, f.name) for f in dataclasses.fields(model)
                   if getattr(model, f.name) != getattr(published.pipeline.model, f.name)}  # fmt: skip
        assert changed == fields, key
        assert config.optimizers == published.optimizers and config.max_num_iterations == published.max_num_iterations


@pytest.mark.parametrize("key", sorted([*BENCH.ROWS, *BENCH.PUBLISHED_VARIANTS]))
def test_every_row_parses(key: str) -> None:
    assert _parsed(key).method_name == BENCH.method(key).ns_method


def test_the_gated_row_is_the_paper_presets_event_term() -> None:
    from agrinerf_ns.method_configs.agrinerf_methods import agrinerf

    gated, paper = _parsed("blur-events-gate").pipeline.model, agrinerf.config.pipeline.model
    assert gated.event_gate and paper.event_gate
    assert (gated.event_loss_weighting, gated.event_supervision) == (
        paper.event_loss_weighting,
        paper.event_supervision,
    )
    assert not _parsed("blur-events-noise").pipeline.model.event_gate


def test_a_training_seed_reaches_every_row() -> None:
    for key in ("rgb", "blur-events-gate", "evdeblurnerf-lite-pdrf-lr"):
        method = BENCH.method(key, 43)
        assert _parsed_method(method).machine.seed == 43


def _model_fields(key: str) -> dict:
    return dict(vars(_parsed(key).pipeline.model))


def test_each_part_row_is_ours_with_only_that_part_added() -> None:
    ours = _model_fields("blur-events-gate")
    changed = {
        "gate-plus-edi": {"edi_prior": True},
        "gate-plus-pairs": {"event_supervision": "pairs"},
        "gate-plus-pairs-crf": {"event_supervision": "pairs", "event_crf": True, "event_crf_start_step": 0},
        "gate-plus-learnt-kernel": {"blur_kernel": "learnt"},
        "gate-plus-evd-schedule": {},
    }
    assert set(changed) == set(BENCH.OURS_PLUS_PARTS)
    for key, part in changed.items():
        fields = _model_fields(key)
        assert {name: value for name, value in fields.items() if ours[name] != value} == part, key
        assert BENCH.row_profile(BENCH.PROFILES["deblur"], key).steps[key] == 800
        assert (key, "blur-events-gate") == next(p[:2] for p in BENCH.PAIRS if p[0] == key)
    # the schedule row: the same model under evdeblurnerf-lite's optimizers, not agrinerf-lite's
    schedule, gate = _parsed("gate-plus-evd-schedule").optimizers, _parsed("blur-events-gate").optimizers
    assert schedule == evdeblurnerf_lite.config.optimizers
    assert type(schedule["fields"]["scheduler"]) is not type(gate["fields"]["scheduler"])
