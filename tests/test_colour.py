"""The one sRGB transfer curve: IEC 61966-2-1's values, a round trip, and finite gradients at the extremes."""

import torch

from agrinerf_ns.colour import linear_to_srgb, srgb_to_linear


def test_known_values_round_trip_and_clamp() -> None:
    srgb = torch.tensor([0.0, 0.04045, 0.5, 1.0], dtype=torch.float64)[:, None].expand(4, 3)
    linear = srgb_to_linear(srgb)
    expected = torch.tensor([0.0, 0.04045 / 12.92, ((0.5 + 0.055) / 1.055) ** 2.4, 1.0], dtype=torch.float64)
    assert linear.dtype == torch.float64 and torch.allclose(linear, expected[:, None].expand(4, 3), rtol=0, atol=1e-15)
    assert torch.allclose(linear_to_srgb(linear), srgb, atol=1e-12)
    assert torch.equal(srgb_to_linear(torch.tensor([-0.5, 1.5, 2.0])), torch.tensor([0.0, 1.0, 1.0]))


def test_gradients_are_finite_at_zero_and_one() -> None:
    x = torch.tensor([[0.0, 1e-12, 0.0031308], [0.04045, 0.999, 1.0]], requires_grad=True)
    (linear_to_srgb(x).sum() + srgb_to_linear(x).sum()).backward()
    assert x.grad is not None and bool(torch.isfinite(x.grad).all()), x.grad
