"""Loss routing: which parameter groups each loss term moves, on a tiny AgriNeRF model.

By default only L_rgb shapes the shared density: the thermal-camera term and the cross-spectral terms (L_th and L_reg
on the `thermal` output) train the thermal volume and head alone. Where the training RGB frames are darker than
``low_light_level`` (and the dataset has thermal frames) the thermal-camera term moves the density too. The paper's
routing (every term into the density) and other per-term scales stay configurations; routing changes gradients, never
the rendered values or the loss values.
"""

from __future__ import annotations

from typing import Dict

import pytest
import torch
from helpers.small_model import SMALL_MODEL
from nerfstudio.cameras.rays import RayBundle
from nerfstudio.data.scene_box import SceneBox

from agrinerf_ns.model.gradients import parameter_groups, term_gradient_norms
from agrinerf_ns.model.loss_routing import PAPER_DENSITY_GRADIENT_SCALES
from agrinerf_ns.model.losses import scale_gradient
from agrinerf_ns.model.model import AgriNeRFModel, AgriNeRFModelConfig

SMALL = {**SMALL_MODEL, "density_shift": 0.0}  # dense enough at initialisation that every ray has weight to route


def _model(modalities=("rgb", "thermal", "events"), rgb_level: float = 0.4, **kw) -> AgriNeRFModel:
    torch.manual_seed(0)
    cfg = AgriNeRFModelConfig(modalities=modalities, **{**SMALL, **kw})
    box = SceneBox(aabb=torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    metadata = {"modalities": ("rgb", "thermal", "events"), "rgb_level": rgb_level}
    model = cfg.setup(scene_box=box, num_train_data=4, metadata=metadata)
    model.train()
    return model


def _rays(n: int = 64) -> RayBundle:
    gen = torch.Generator().manual_seed(1)
    origins = torch.randn(n, 3, generator=gen) * 0.1 + torch.tensor([0.0, 0.0, 3.0])
    directions = torch.nn.functional.normalize(torch.randn(n, 3, generator=gen) * 0.3 - origins, dim=-1)
    return RayBundle(
        origins=origins,
        directions=directions,
        pixel_area=torch.full((n, 1), 1e-4),
        camera_indices=torch.zeros(n, 1, dtype=torch.long),
    )


def _batch(n: int = 64) -> Dict[str, torch.Tensor]:
    gen = torch.Generator().manual_seed(2)
    return {
        "image": torch.rand(n, 3, generator=gen),
        "thermal": torch.rand(n, 1, generator=gen),
        "thermal_mask": torch.ones(n, 1),
        "event": torch.rand(n, 1, generator=gen),
        "event_mask": torch.ones(n, 1),
    }


def _norms(model: AgriNeRFModel) -> Dict[str, Dict[str, float]]:
    outputs = model(_rays())
    batch = _batch()
    loss_dict = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
    data_terms = {k: v for k, v in loss_dict.items() if k.endswith("_loss")}
    return term_gradient_norms(data_terms, parameter_groups(model))


def _reached(norms: Dict[str, Dict[str, float]]) -> Dict[str, set]:
    return {term: {group for group, n in groups.items() if n > 0.0} for term, groups in norms.items()}


def test_default_routing_leaves_the_geometry_to_the_rgb_frames() -> None:
    reached = _reached(_norms(_model()))
    assert reached == {
        "rgb_loss": {"density", "rgb_volume", "rgb_mlp"},
        "thermal_camera_loss": {"thermal_volume", "thermal_mlp"},
        "thermal_loss": {"thermal_volume", "thermal_mlp"},
        "reg_rgb_loss": {"thermal_volume", "thermal_mlp"},
        "reg_event_loss": {"thermal_volume", "thermal_mlp"},
    }


def test_the_thermal_camera_term_can_carry_geometry_without_the_cross_spectral_terms() -> None:
    reached = _reached(_norms(_model(density_gradient_scales={"thermal_camera_loss": 1.0, "thermal_loss": 0.0,
                                                              "reg_rgb_loss": 0.0, "reg_event_loss": 0.0})))  # fmt: skip
    assert reached["thermal_camera_loss"] == {"density", "thermal_volume", "thermal_mlp"}
    assert all("density" not in reached[t] for t in ("thermal_loss", "reg_rgb_loss", "reg_event_loss"))


@pytest.mark.parametrize("rgb_level, thermal_geometry", [(0.01, True), (0.039, True), (0.041, False), (0.4, False)])
def test_low_light_routing_lets_the_thermal_camera_move_the_density_only_below_the_level(
    rgb_level: float, thermal_geometry: bool
) -> None:
    reached = _reached(_norms(_model(rgb_level=rgb_level, low_light_level=0.04)))
    assert ("density" in reached["thermal_camera_loss"]) is thermal_geometry
    assert all("density" not in reached[t] for t in ("thermal_loss", "reg_rgb_loss", "reg_event_loss"))
    assert "density" in reached["rgb_loss"]


def test_low_light_routing_needs_thermal_frames_and_a_recorded_level() -> None:
    reached = _reached(_norms(_model(rgb_level=float("nan"), low_light_level=0.04)))
    assert "density" not in reached["thermal_camera_loss"]  # no level recorded: the configured routing
    model = _model(modalities=("rgb", "events"), rgb_level=0.01, low_light_level=0.04)
    assert not model.plan.low_light  # no thermal frames: nothing to route


def test_paper_routing_sends_every_term_into_the_density() -> None:
    model = _model(density_gradient_scales=PAPER_DENSITY_GRADIENT_SCALES, thermal_camera_output=False)
    reached = _reached(_norms(model))
    assert set(reached) == {"rgb_loss", "thermal_loss", "reg_rgb_loss", "reg_event_loss"}
    assert all("density" in groups for groups in reached.values())
    assert all(not (groups & {"rgb_volume", "rgb_mlp"}) for term, groups in reached.items() if term != "rgb_loss")


def test_rgb_and_events_without_thermal_frames_leave_the_geometry_to_rgb() -> None:
    reached = _reached(_norms(_model(modalities=("rgb", "events"))))
    assert set(reached) == {"rgb_loss", "reg_rgb_loss", "reg_event_loss"}  # no thermal frames: no thermal-camera term
    assert [term for term, groups in reached.items() if "density" in groups] == ["rgb_loss"]


def test_the_rgb_term_can_leave_the_geometry_to_the_thermal_camera() -> None:
    reached = _reached(_norms(_model(density_gradient_scales={"rgb_loss": 0.0, "thermal_camera_loss": 1.0})))
    assert reached["rgb_loss"] == {"rgb_volume", "rgb_mlp"}
    assert "density" in reached["thermal_camera_loss"]


@pytest.mark.parametrize("scale", [0.5, 0.1])
def test_a_fractional_scale_scales_the_density_gradient_and_nothing_else(scale: float) -> None:
    full = _norms(_model(density_gradient_scales={"thermal_loss": 1.0, "thermal_camera_loss": 0.0}))["thermal_loss"]
    part = _norms(_model(density_gradient_scales={"thermal_loss": scale, "thermal_camera_loss": 0.0}))["thermal_loss"]
    assert part["density"] == pytest.approx(scale * full["density"], rel=1e-4)
    assert part["thermal_volume"] == pytest.approx(full["thermal_volume"], rel=1e-6)
    assert part["thermal_mlp"] == pytest.approx(full["thermal_mlp"], rel=1e-6)


def test_routing_changes_gradients_not_values() -> None:
    routed, paper = _model(), _model(density_gradient_scales=PAPER_DENSITY_GRADIENT_SCALES)
    rays, batch = _rays(), _batch()
    torch.manual_seed(3)  # the samplers jitter: the same draws for both
    a = routed(rays)
    torch.manual_seed(3)
    b = paper(rays)
    for name in ("rgb", "thermal", "thermal_camera"):
        assert torch.equal(a[name], b[name])
    terms_a, terms_b = routed.get_metrics_dict(a, batch), paper.get_metrics_dict(b, batch)
    for term in ("rgb_loss", "thermal_loss", "reg_rgb_loss", "reg_event_loss", "thermal_camera_loss"):
        assert torch.equal(terms_a[term], terms_b[term])
    routed.eval()
    with torch.no_grad():
        assert not any("/" in key for key in routed(rays))  # routed copies are training-only, never rendered


def test_scale_gradient_is_identity_forward() -> None:
    x = torch.linspace(-3, 3, 7, requires_grad=True)
    for scale in (0.0, 0.25, 1.0):
        y = scale_gradient(x, scale)
        assert torch.equal(y, x)
        (grad,) = torch.autograd.grad(y.sum(), x, allow_unused=True) if scale else (None,)
        if scale:
            assert torch.allclose(grad, torch.full_like(x, scale))
    assert not scale_gradient(x, 0.0).requires_grad


def test_a_camera_that_does_not_move_the_density_leaves_the_rgb_model_bit_identical() -> None:
    """Common random numbers: the thermal head draws its initial values from a forked stream, so RGB+Thermal under
    the default routing trains the very RGB model that RGB alone trains (same initial values, same draws, the same
    gradient on the density and RGB parameters); an ablation's difference is then the modality's effect alone."""
    rays, batch = _rays(), _batch()
    trained = []
    for modalities in (("rgb",), ("rgb", "thermal")):
        model = _model(modalities)
        optimiser = torch.optim.Adam(model.parameters(), lr=1e-2)
        for _ in range(5):
            outputs = model(rays)
            loss_dict = model.get_loss_dict(outputs, batch, model.get_metrics_dict(outputs, batch))
            optimiser.zero_grad()
            torch.stack(list(loss_dict.values())).sum().backward()
            optimiser.step()
        model.eval()
        with torch.no_grad():
            trained.append(model(rays)["rgb"])
    assert torch.equal(trained[0], trained[1])
