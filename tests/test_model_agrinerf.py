"""AgriNeRF model: parameters per modality, loss terms per modality, numerical safety at the extremes."""

from __future__ import annotations

import copy
from typing import Dict, Tuple

import pytest
import torch
from helpers.small_model import SMALL_MODEL
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns import compat
from agrinerf_ns.modalities import TABLE_IV_ABLATIONS
from agrinerf_ns.model.model import AgriNeRFModel, AgriNeRFModelConfig

compat.activate()  # as every ns-* command does through the entry points (offline LPIPS)

SMALL = SMALL_MODEL


def _model(modalities=("rgb", "thermal", "events"), dataset=("rgb", "thermal", "events"), **kw) -> AgriNeRFModel:
    torch.manual_seed(0)
    cfg = AgriNeRFModelConfig(modalities=modalities, **{**SMALL, **kw})
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    return cfg.setup(scene_box=box, num_train_data=4, metadata={"modalities": dataset})


def _counts(model: AgriNeRFModel) -> Dict[str, int]:
    return {n: p.numel() for n, p in model.named_parameters()}


def _rays(n: int = 32, seed: int = 0, away: bool = False, dtype=torch.float32) -> RayBundle:
    gen = torch.Generator().manual_seed(seed)
    origins = torch.randn(n, 3, generator=gen) * 0.1 + torch.tensor([0.0, 0.0, 3.0])
    target = torch.randn(n, 3, generator=gen) * 0.3
    directions = torch.nn.functional.normalize(target - origins, dim=-1)
    if away:
        directions = -directions
    return RayBundle(
        origins=origins.to(dtype),
        directions=directions.to(dtype),
        pixel_area=torch.full((n, 1), 1e-4, dtype=dtype),
        camera_indices=torch.zeros(n, 1, dtype=torch.long),
    )


def _batch(n: int = 32, rgb: float = 0.3, thermal: float = 0.6, event: float = 0.5, dtype=torch.float32):
    return {
        "image": torch.full((n, 3), rgb, dtype=dtype),
        "thermal": torch.full((n, 1), thermal, dtype=dtype),
        "thermal_mask": torch.ones(n, 1, dtype=dtype),
        "event": torch.full((n, 1), event, dtype=dtype),
        "event_mask": torch.ones(n, 1, dtype=dtype),
    }


def test_rgb_only_scene_has_no_thermal_parameters() -> None:
    rgb_scene = _model(dataset=("rgb",))  # the config asks for all three; the dataset has RGB only
    assert rgb_scene.plan.modalities == ("rgb",)
    names = set(_counts(rgb_scene))
    assert not any("thermal" in n for n in names)
    assert rgb_scene.field.thermal_head is None
    outputs = rgb_scene(_rays())
    assert "thermal" not in outputs and outputs["rgb"].shape == (32, 3)
    losses = rgb_scene.get_loss_dict(outputs, _batch(), rgb_scene.get_metrics_dict(outputs, _batch()))
    assert not any(k.startswith(("thermal", "reg_")) for k in losses)


def test_adding_thermal_adds_exactly_the_thermal_volume_and_mlp() -> None:
    rgb = _counts(_model(dataset=("rgb",)))
    both = _counts(_model(dataset=("rgb", "thermal")))
    added = {n: c for n, c in both.items() if n not in rgb}
    assert set(rgb) <= set(both)
    assert all(rgb[n] == both[n] for n in rgb)
    assert added and all(n.startswith("field.thermal_head.") for n in added)
    # volume: 3 planes + 3 lines of 2 components at resolution 8; basis 6 -> 3; MLP_THERMAL: in -> 8 -> 2
    # (the cross-spectral `thermal` and the `thermal_camera` channel)
    volume = 3 * 2 * 8 * 8 + 3 * 2 * 8
    in_dim = 3 + 3 * 2 * 2  # features + NeRFEncoding(2 frequencies, sin/cos) of them, no direction (view independent)
    mlp = 6 * 3 + (in_dim * 8 + 8) + (8 * 2 + 2)
    assert sum(added.values()) == volume + mlp
    thermal_volume = {n for n in added if ".encoding." in n}
    assert thermal_volume == {"field.thermal_head.encoding.plane_table", "field.thermal_head.encoding.line_table"}


def test_config_modalities_are_intersected_with_the_dataset() -> None:
    model = _model(modalities=("rgb", "thermal"), dataset=("rgb", "thermal", "events"))
    assert model.plan.modalities == ("rgb", "thermal") and not model.plan.use_events
    model = _model(modalities=("rgb", "thermal", "events"), dataset=("rgb", "events"))
    assert model.plan.modalities == ("rgb", "events") and model.field.thermal_head is not None  # Table IV RGB+Events
    model = _model(modalities=("thermal",))
    assert model.field.rgb_head is None and "rgb" not in model(_rays())
    with pytest.raises(ValueError, match="needs RGB or thermal"):
        _model(modalities=("events",))
    no_metadata = AgriNeRFModelConfig(**SMALL).setup(
        scene_box=SceneBox(aabb=torch.tensor([[-1.0, -1, -1], [1, 1, 1]])), num_train_data=2
    )
    assert no_metadata.plan.modalities == ("rgb",)


@pytest.mark.parametrize("name", sorted(TABLE_IV_ABLATIONS))
def test_table_iv_ablations_build_and_give_the_right_loss_terms(name: str) -> None:
    modalities = TABLE_IV_ABLATIONS[name]
    model = _model(modalities=modalities)
    model.train()
    outputs = model(_rays())
    metrics = model.get_metrics_dict(outputs, _batch())
    loss = model.get_loss_dict(outputs, _batch(), metrics)
    expected = set()
    if "rgb" in modalities:
        expected.add("rgb_loss")
    if "thermal" in modalities:
        expected.update({"thermal_loss", "thermal_camera_loss"})
    if "rgb" in modalities and {"thermal", "events"} & set(modalities):
        expected.add("reg_rgb_loss")
    if "events" in modalities:
        expected.add("reg_event_loss")
    data_terms = {k for k in loss if not k.endswith("_reg") and not k.startswith("tv_")}
    assert data_terms == expected


def test_weights_are_applied_in_the_loss_and_raw_terms_go_to_metrics() -> None:
    model = _model(loss_coefficients={"rgb_loss": 2.0, "thermal_loss": 0.5, "reg_rgb_loss": 0.0, "reg_event_loss": 3.0})
    model.train()
    outputs = model(_rays())
    metrics = model.get_metrics_dict(outputs, _batch())
    loss = model.get_loss_dict(outputs, _batch(), metrics)
    assert loss["rgb_loss"].item() == pytest.approx(2.0 * metrics["rgb_loss"].item())
    assert loss["thermal_loss"].item() == pytest.approx(0.5 * metrics["thermal_loss"].item())
    assert loss["reg_event_loss"].item() == pytest.approx(3.0 * metrics["reg_event_loss"].item())
    assert "reg_rgb_loss" not in loss and "l1_reg" not in loss  # weight 0 (or absent): not computed


def _assert_finite(model: AgriNeRFModel, rays: RayBundle, batch) -> Tuple[Dict, Dict]:
    outputs = model(rays)
    for key, value in outputs.items():
        assert torch.isfinite(value).all(), key
    metrics = model.get_metrics_dict(outputs, batch)
    loss = model.get_loss_dict(outputs, batch, metrics)
    total = sum(loss.values())
    assert torch.isfinite(total), loss
    model.zero_grad(set_to_none=True)
    total.backward()
    for name, param in model.named_parameters():
        if param.grad is not None:
            assert torch.isfinite(param.grad).all(), name
    return outputs, loss


EXTREMES = {
    "black rgb, empty events": (dict(rgb=0.0, event=0.0, thermal=0.5), True),
    "saturated rgb, flooded events": (dict(rgb=1.0, event=1.0, thermal=1.0), False),
    "constant cold thermal": (dict(rgb=0.5, event=0.5, thermal=0.0), True),
}
"""Case -> (constant batch values, scene contraction on/off)."""


@pytest.mark.parametrize("case", sorted(EXTREMES))
def test_extreme_inputs_stay_finite_over_50_steps(case: str) -> None:
    values, contraction = EXTREMES[case]
    model = _model(scene_contraction=contraction)
    model.train()
    optimizer = torch.optim.Adam(model.parameters(), lr=2e-2)
    first = None
    for step in range(50):
        _, loss = _assert_finite(model, _rays(n=16, seed=step), _batch(n=16, **values))
        optimizer.step()
        total = sum(v.item() for k, v in loss.items() if k.endswith("_loss"))
        first = total if first is None else first
    assert total <= first + 1e-3  # not diverging: the data terms end no higher than they started


def test_huge_initial_density_float16_inputs_and_rays_missing_the_box() -> None:
    model = _model(scene_contraction=False, density_shift=80.0)  # softplus(80) > max_density: clamped
    model.train()
    _assert_finite(model, _rays(), _batch())
    _assert_finite(model, _rays(dtype=torch.float16), _batch(dtype=torch.float16, rgb=1.0))
    outputs, _ = _assert_finite(model, _rays(away=True), _batch())  # rays leave the box: nothing accumulates
    assert outputs["accumulation"].max().item() < 1e-3
    model.eval()
    with torch.no_grad():
        outputs = model(_rays(away=True))
    assert ((outputs["rgb"] >= 0) & (outputs["rgb"] <= 1)).all()


def test_upsampling_callback_resizes_every_volume_and_repoints_the_optimizers() -> None:
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes
    from nerfstudio.engine.optimizers import AdamOptimizerConfig, Optimizers

    model = _model()
    model.train()
    groups = model.get_param_groups()
    opt_cfg = {k: {"optimizer": AdamOptimizerConfig(lr=1e-2), "scheduler": None} for k in groups}
    optimizers = Optimizers(copy.deepcopy(opt_cfg), groups)
    callbacks = model.get_training_callbacks(TrainingCallbackAttributes(optimizers, None, None, None))
    kept = []  # outputs of every step stay alive, as the trainer keeps the last step's metrics during the next one
    for step in range(5):
        outputs, loss = _assert_finite(model, _rays(seed=step), _batch())
        kept.append(loss)
        optimizers.optimizer_step_all()
        for cb in callbacks:
            cb.run_callback_at_location(step, cb.where_to_run[0])
    resolutions = {name: vol.resolution for name, vol in model.field.volumes().items()}
    assert resolutions == {"density": (12, 12, 12), "rgb": (12, 12, 12), "thermal": (12, 12, 12)}
    now = model.get_param_groups()
    for name, optimizer in optimizers.optimizers.items():
        assert [id(p) for p in optimizer.param_groups[0]["params"]] == [id(p) for p in now[name]]
        for p in now[name]:
            assert optimizer.state[p]["exp_avg"].shape == p.shape  # Adam restarted at the new size (steps 4, 5)
    assert optimizers.optimizers["encodings"].state[now["encodings"][0]]["step"].item() == 1.0
    assert optimizers.optimizers["fields"].state[now["fields"][0]]["step"].item() == 5.0  # MLP moments kept


def test_heads_on_every_sample_equal_heads_on_the_selected_ones(monkeypatch: pytest.MonkeyPatch) -> None:
    """The dense path (heads on all fine samples, unselected ones masked) renders and trains as the gathered one."""
    import agrinerf_ns.model.model as model_module

    model = _model(weight_threshold=0.02, background_color="black")
    model.train()
    rays, batch = _rays(64), _batch(64)
    results, seen = {}, {}
    appearance_at = model.field.appearance_at
    for name, fraction in (("gathered", 2.0), ("dense", 0.0)):
        monkeypatch.setattr(model_module, "DENSE_HEADS_FRACTION", fraction)

        def counting(coords, directions, corners=None, heads=None, name=name):
            seen[name] = coords.shape[0]
            return appearance_at(coords, directions, corners, heads)

        monkeypatch.setattr(model.field, "appearance_at", counting)
        model.zero_grad()
        torch.manual_seed(5)  # the same PDF jitter for both
        outputs = model(rays)  # the collider sets near and far, then get_outputs
        loss = sum(model.get_loss_dict(outputs, batch).values())
        loss.backward()
        grads = {n: p.grad.clone() for n, p in model.named_parameters() if p.grad is not None}
        results[name] = (outputs, grads)
    (out_a, grad_a), (out_b, grad_b) = results["gathered"], results["dense"]
    for key in ("rgb", "thermal", "accumulation", "depth"):
        torch.testing.assert_close(out_b[key], out_a[key], rtol=1e-5, atol=1e-6)
    assert grad_a.keys() == grad_b.keys() and any(n.startswith("field.thermal_head") for n in grad_a)
    for name in grad_a:
        torch.testing.assert_close(grad_b[name], grad_a[name], rtol=1e-4, atol=1e-6)
    # the threshold really left samples out (else this would not test the masking): the gathered run got fewer
    assert 0 < seen["gathered"] < seen["dense"] == 64 * SMALL["num_fine_samples"]


def test_pose_refinement_moves_the_cameras_positions_through_the_field() -> None:
    # Nerfstudio's camera optimizer shifts ray origins; only the samples' positions carry that to the loss, so a lookup
    # that detaches them would leave the translations untrained (the CPU's row lookup did, before it had a gradient
    # in the coordinates)
    from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig

    model = _model(modalities=("rgb",), dataset=("rgb",), camera_optimizer=CameraOptimizerConfig(mode="SO3xR3"))
    model.train()
    outputs = model(_rays())
    model.get_loss_dict(outputs, _batch(), model.get_metrics_dict(outputs, _batch()))["rgb_loss"].backward()
    grad = model.camera_optimizer.pose_adjustment.grad
    assert grad is not None
    translation, rotation = grad[0, :3], grad[0, 3:]
    assert float(translation.abs().sum()) > 0 and float(rotation.abs().sum()) > 0
