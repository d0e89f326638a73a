"""The field's L-inf contraction is Nerfstudio's `SceneContraction(order=inf)`, computed with `amax`."""

from __future__ import annotations

import torch
from nerfstudio.field_components.spatial_distortions import SceneContraction

from agrinerf_ns.model.contraction import LinfContraction


def test_equals_nerfstudios_linf_contraction() -> None:
    gen = torch.Generator().manual_seed(0)
    points = torch.cat(
        [
            torch.rand(200, 3, generator=gen) * 2 - 1,  # inside the unit cube: unchanged
            torch.randn(200, 3, generator=gen) * 50,  # far: into the shell
            torch.tensor([[1.0, 0.0, 0.0], [-1.0, 1.0, -1.0], [1e6, -3.0, 2.0], [0.0, 0.0, 0.0]]),
        ]
    ).reshape(2, 202, 3)
    expected = SceneContraction(order=float("inf"))(points)
    got = LinfContraction()(points)
    assert got.shape == points.shape
    torch.testing.assert_close(got, expected, rtol=0, atol=1e-6)
    assert float(got.abs().max()) < 2.0
    inside = points.abs().amax(-1) < 1
    torch.testing.assert_close(got[inside], points[inside], rtol=0, atol=0)
