"""The model's plan (`agrinerf_ns/model/plan.py`): every preset on a scene with all three cameras, an event-less one
and an RGB-only one, and the terms each plan switches on; the trained loss terms are the plan's."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Dict, FrozenSet, Tuple

import pytest

from agrinerf_ns.model.plan import resolve_plan

PRESETS = ("agrinerf", "agrinerf-lite", "evdeblurnerf", "evdeblurnerf-lite", "evdeblurnerf-windowed",
           "evdeblurnerf-windowed-lite")  # fmt: skip
REGS = frozenset({"l1_reg", "tv_reg_density", "tv_reg_appearance"})
THERMAL = frozenset({"thermal_loss", "thermal_camera_loss", "temperature_loss", "reg_rgb_loss"})
ALL = ("rgb", "thermal", "events")
EVENTLESS = ("rgb", "thermal")
RGB_ONLY = ("rgb",)

BLUR = {"agrinerf": "trajectory", "agrinerf-lite": "off", "evdeblurnerf": "learnt", "evdeblurnerf-lite": "learnt",
        "evdeblurnerf-windowed": "trajectory", "evdeblurnerf-windowed-lite": "trajectory"}  # fmt: skip
# (preset, scene's modalities) -> (event supervision, blur model, loss terms): what a reader expects of each preset
EXPECTED: Dict[Tuple[str, Tuple[str, ...]], Tuple[str, str, FrozenSet[str]]] = {
    ("agrinerf", ALL): ("stream", "trajectory", REGS | THERMAL | {"rgb_loss", "event_loss", "reg_event_loss"}),
    ("agrinerf-lite", ALL): ("off", "off", REGS | THERMAL | {"rgb_loss", "reg_event_loss"}),
    ("evdeblurnerf", ALL): ("pairs", "learnt", REGS | {"rgb_loss", "event_loss", "edi_prior_loss"}),
    ("evdeblurnerf-lite", ALL): ("pairs", "learnt", REGS | {"rgb_loss", "event_loss", "edi_prior_loss"}),
    ("evdeblurnerf-windowed", ALL): ("stream", "trajectory", REGS | {"rgb_loss", "event_loss"}),
    ("evdeblurnerf-windowed-lite", ALL): ("stream", "trajectory", REGS | {"rgb_loss", "event_loss"}),
    ("agrinerf", EVENTLESS): ("off", "trajectory", REGS | THERMAL | {"rgb_loss"}),
    ("agrinerf-lite", EVENTLESS): ("off", "off", REGS | THERMAL | {"rgb_loss"}),
    ("evdeblurnerf", EVENTLESS): ("off", "learnt", REGS | {"rgb_loss"}),
    ("evdeblurnerf-lite", EVENTLESS): ("off", "learnt", REGS | {"rgb_loss"}),
    ("evdeblurnerf-windowed", EVENTLESS): ("off", "trajectory", REGS | {"rgb_loss"}),
    ("evdeblurnerf-windowed-lite", EVENTLESS): ("off", "trajectory", REGS | {"rgb_loss"}),
    **{(p, RGB_ONLY): ("off", BLUR[p], REGS | {"rgb_loss"}) for p in PRESETS},
}


@pytest.fixture(scope="module")
def scene(tmp_path_factory) -> Path:
    """A processed synthetic capture in bright light (no low-light rule): timed frames, exposures, events with their
    stream, thermal frames with temperatures, metric poses."""
    root = tmp_path_factory.mktemp("plan")
    subprocess.run(["agrinerf-synth", "--out", str(root / "raw"), "--scene", "orchard", "--lighting", "bright",
                    "--seed", "0", "--views", "8", "--width", "64", "--height", "48", "--no-preview"],
                   check=True, capture_output=True)  # fmt: skip
    subprocess.run(["agrinerf-process", "--raw", str(root / "raw"), "--out", str(root / "data"), "--poses", "given"],
                   check=True, capture_output=True)  # fmt: skip
    return root / "data"


def _metadata(data: Path, modalities: Tuple[str, ...]) -> dict:
    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig

    config = AgriNeRFDataParserConfig(data=data, modalities=modalities)  # type: ignore[arg-type]
    return config.setup().get_dataparser_outputs("train").metadata


def _preset_model_config(name: str):
    from agrinerf_ns.method_configs import agrinerf_methods

    return getattr(agrinerf_methods, name.replace("-", "_")).config.pipeline.model


@pytest.mark.parametrize("modalities", [ALL, EVENTLESS, RGB_ONLY], ids=["all", "eventless", "rgb-only"])
def test_every_preset_plans_the_terms_its_scene_supports(scene: Path, modalities: Tuple[str, ...]) -> None:
    metadata = _metadata(scene, modalities)
    for preset in PRESETS:
        plan = resolve_plan(_preset_model_config(preset), metadata)
        supervision, blur, terms = EXPECTED[(preset, modalities)]
        assert (plan.event_supervision, plan.blur, plan.terms) == (supervision, blur, terms), preset
        assert plan.modalities == tuple(m for m in _preset_model_config(preset).modalities if m in modalities)
        if "events" not in modalities:
            assert not (plan.use_event_loss or plan.edi_prior or plan.use_events), preset
        if "thermal" not in modalities:
            assert not (plan.has_thermal_head or plan.has_thermal_camera or plan.has_temperature), preset


def test_a_supervision_the_data_cannot_give_is_said_not_guessed(scene: Path) -> None:
    """EvDeblurNeRF's pairs need the event stream: without it the plan says it uses the frames' windows."""
    metadata = {k: v for k, v in _metadata(scene, ALL).items() if k != "event_stream"}
    plan = resolve_plan(_preset_model_config("evdeblurnerf-lite"), metadata)
    assert plan.event_supervision == "frames" and not plan.edi_prior
    assert any("event_supervision 'pairs'" in note for note in plan.notes)


def test_low_light_turns_the_event_loss_off_and_the_thermal_camera_up() -> None:
    """The dark rules, on metadata alone: the plan is a pure function of config and metadata."""
    from agrinerf_ns.model.model import AgriNeRFModelConfig

    config = AgriNeRFModelConfig(
        event_supervision="frames", event_rays_per_batch=64, loss_coefficients={"rgb_loss": 1.0, "event_loss": 0.1}
    )
    metadata = {"modalities": ALL, "rgb_level": 0.01, "times": object(), "trajectory": object(),
                "event_windows": object()}  # fmt: skip
    dark = resolve_plan(config, metadata)
    assert dark.low_light and dark.event_supervision == "off" and dark.terms == {"rgb_loss"}
    assert dark.density_gradient_scales["thermal_camera_loss"] == 1.0 and len(dark.notes) == 2
    lit = resolve_plan(config, {**metadata, "rgb_level": 0.5})
    assert not lit.low_light and lit.event_supervision == "frames" and lit.terms == {"rgb_loss", "event_loss"}
    with pytest.raises(ValueError, match="needs RGB or thermal"):
        resolve_plan(AgriNeRFModelConfig(modalities=("events",)), metadata)


@pytest.mark.slow
@pytest.mark.parametrize("preset", ["agrinerf", "evdeblurnerf-lite"])
def test_a_training_step_computes_exactly_the_planned_terms(scene: Path, preset: str) -> None:
    import torch

    from agrinerf_ns.lab.stepper import MethodStepper

    torch.manual_seed(0)
    small = {"init_resolution": 16, "final_resolution": 24, "upsampling_iters": (), "box_fit_iters": (),
             "blur_start_step": 0, "num_coarse_samples": 16, "num_fine_samples": 16}  # fmt: skip
    stepper = MethodStepper(preset, scene, 128, model_overrides=small)
    model = stepper.pipeline.model
    assert set(stepper.loss_dict(0)) == set(model.plan.terms)


@pytest.mark.parametrize(
    ("settings", "reason"),
    [({"event_rays_per_batch": 0}, "event_rays_per_batch is 0"),
     ({"loss_coefficients": {"rgb_loss": 1.0, "event_loss": 0.0}}, r"loss_coefficients\['event_loss'\] is 0.0")],
)  # fmt: skip
def test_the_event_loss_has_one_switch_and_a_count_or_weight_of_zero_is_refused(settings: dict, reason: str) -> None:
    """`event_supervision` alone turns the event loss on or off; 0 rays or a zero weight under it is an error that
    names the switch, not a second, silent switch."""
    from agrinerf_ns.model.model import AgriNeRFModelConfig

    metadata = {"modalities": ALL, "times": object(), "trajectory": object(), "event_windows": object()}
    with pytest.raises(ValueError, match=reason + ".*event-supervision off"):
        resolve_plan(AgriNeRFModelConfig(event_supervision="frames", **settings), metadata)
    assert resolve_plan(AgriNeRFModelConfig(event_supervision="off", **settings), metadata).event_supervision == "off"
    assert resolve_plan(AgriNeRFModelConfig(event_supervision="frames"), metadata).event_supervision == "frames"


def test_only_the_plan_reads_the_event_switch() -> None:
    """The event loss's on/off is checked in one place: no other module of the package reads the config's
    `event_supervision` (the parts read the plan's)."""
    import ast

    root = Path(__file__).resolve().parent.parent
    readers = []
    for path in sorted([*(root / "agrinerf_ns").rglob("*.py"), *(root / "dataparsers").rglob("*.py")]):
        if path.name in ("plan.py", "model_config.py") and path.parent.name == "model":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Attribute) and node.attr == "event_supervision":
                if not (isinstance(node.value, ast.Name) and node.value.id == "plan"):
                    readers.append(f"{path.relative_to(root)}:{node.lineno}")
    assert not readers, readers
