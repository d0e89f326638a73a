"""AgriNeRF losses against values computed by hand (paper Eqs. 1-3, TensoRF L1/TV)."""

from __future__ import annotations

import math

import pytest
import torch

from agrinerf_ns.model import losses


def test_luminance_is_bt601() -> None:
    rgb = torch.tensor([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 1.0], [0.2, 0.4, 0.6]])
    y = losses.luminance(rgb)
    expected = torch.tensor([[0.299], [0.587], [0.114], [1.0], [0.299 * 0.2 + 0.587 * 0.4 + 0.114 * 0.6]])
    assert torch.allclose(y, expected, atol=1e-6)


def test_rgb_loss_by_hand() -> None:
    pred = torch.tensor([[0.0, 0.5, 1.0], [0.2, 0.2, 0.2]])
    gt = torch.tensor([[1.0, 0.5, 0.0], [0.4, 0.2, 0.0]])
    # squared errors: 1, 0, 1 | 0.04, 0, 0.04 -> sum 2.08 over 6 values
    assert losses.rgb_loss(pred, gt).item() == pytest.approx(2.08 / 6, abs=1e-6)


def test_thermal_loss_respects_the_mask() -> None:
    pred = torch.tensor([[0.1], [0.5], [0.9], [0.3]])
    gt = torch.tensor([[0.2], [0.0], [0.9], [1.0]])
    mask = torch.tensor([[1.0], [1.0], [1.0], [0.0]])
    # valid: 0.01, 0.25, 0 -> mean over 3
    assert losses.thermal_loss(pred, gt, mask).item() == pytest.approx(0.26 / 3, abs=1e-6)
    assert losses.thermal_loss(pred, gt).item() == pytest.approx((0.26 + 0.49) / 4, abs=1e-6)


def test_empty_mask_gives_zero_with_a_gradient_path_not_nan() -> None:
    pred = torch.rand(4, 1, requires_grad=True)
    loss = losses.thermal_loss(pred, torch.rand(4, 1), torch.zeros(4, 1))
    loss.backward()
    assert loss.item() == 0.0 and torch.isfinite(pred.grad).all()


def test_cross_spectral_terms_by_hand() -> None:
    th = torch.tensor([[0.5], [0.0]])
    rgb = torch.tensor([[1.0, 1.0, 1.0], [0.0, 1.0, 0.0]])  # Y = 1.0, 0.587
    ev = torch.tensor([[0.5], [1.0]])
    ev_mask = torch.tensor([[1.0], [0.0]])
    rgb_term = (0.25 + 0.587**2) / 2
    assert losses.cross_spectral_rgb_term(th, rgb).item() == pytest.approx(rgb_term, abs=1e-6)
    assert losses.cross_spectral_event_term(th, ev, ev_mask).item() == pytest.approx(0.0, abs=1e-7)
    assert losses.cross_spectral_event_term(th, ev).item() == pytest.approx(0.5, abs=1e-6)
    total = losses.cross_spectral_loss(th, rgb, ev, None, rgb_weight=2.0, event_weight=0.5)
    assert total.item() == pytest.approx(2.0 * rgb_term + 0.5 * 0.5, abs=1e-6)
    assert losses.cross_spectral_loss(th, None, ev).item() == pytest.approx(0.5, abs=1e-6)
    assert losses.cross_spectral_loss(th, None, None).item() == 0.0


def test_l1_volume_loss_by_hand() -> None:
    """The L1 term averages |x| over every entry of every tensor (the planes' TV is checked in test_vm_encoding)."""
    a = torch.tensor([1.0, -2.0, 3.0])
    b = torch.tensor([[-4.0]])
    assert losses.l1_volume_loss(a, b).item() == pytest.approx(10.0 / 4)


@pytest.mark.parametrize("dtype", [torch.float16, torch.float32])
def test_losses_are_finite_at_extremes(dtype: torch.dtype) -> None:
    n = 16
    for rgb_val, ev_val, th_val in [(0.0, 0.0, 0.0), (1.0, 1.0, 1.0), (0.0, 1.0, 0.5)]:
        pred_th = torch.full((n, 1), th_val, dtype=dtype, requires_grad=True)
        pred_rgb = torch.full((n, 3), 1.0 - rgb_val, dtype=dtype, requires_grad=True)
        gt_rgb = torch.full((n, 3), rgb_val, dtype=dtype)
        ev = torch.full((n, 1), ev_val, dtype=dtype)
        total = (
            losses.rgb_loss(pred_rgb, gt_rgb)
            + losses.thermal_loss(pred_th, torch.full((n, 1), 0.5, dtype=dtype))
            + losses.cross_spectral_loss(pred_th, gt_rgb, ev)
        )
        total.backward()
        assert total.dtype == torch.float32 and math.isfinite(total.item())
        assert torch.isfinite(pred_th.grad).all() and torch.isfinite(pred_rgb.grad).all()


def test_non_finite_targets_are_ignored() -> None:
    pred = torch.tensor([[0.5], [0.5]])
    gt = torch.tensor([[float("nan")], [0.0]])
    assert losses.thermal_loss(pred, gt).item() == pytest.approx(0.25)
