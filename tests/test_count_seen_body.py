"""A counted fruit is a dense body that the cameras see (``count/volume.py``: :func:`body_weights`,
:func:`pixels_on_object`). On the dark demo's field the count took the sky, painted by the field on fog behind the
canopy's top edge, for a fruit at -7.5 C: seen only through the 3x3 rim allowance beside the canopy, where the rays
stop well in front of it. Here the rule is held on a scene whose density is known: a dense fruit in sight, a blob
hidden behind a leaf wall and a translucent floater."""

from __future__ import annotations

from typing import Tuple

import numpy as np
import torch

from agrinerf_ns.count.volume import MIN_BODY_WEIGHT, DepthView, body_weights, pixels_on_object, views_showing_pixels

FRUIT = np.array([0.0, 0.0, -2.0])
HIDDEN = np.array([0.6, 0.0, -2.5])
FLOATER = np.array([-0.6, 0.0, -2.0])
RADIUS = 0.1


class KnownDensity:
    """The density of a known scene, read as the count reads a field (``to_grid``, ``density_at``): a dense fruit, a
    dense blob behind a leaf wall (the wall covers x > 0.3 at z = -1.5), a translucent floater (density 2)."""

    def to_grid(self, positions: torch.Tensor) -> Tuple[torch.Tensor, torch.Tensor]:
        return positions, torch.ones(positions.shape[:-1], dtype=torch.bool)

    def density_at(self, coords: torch.Tensor, inside: torch.Tensor) -> torch.Tensor:
        density = torch.zeros(coords.shape[:-1], dtype=torch.float32)
        for centre, value in ((FRUIT, 60.0), (HIDDEN, 60.0), (FLOATER, 2.0)):
            density[(coords - torch.as_tensor(centre, dtype=coords.dtype)).norm(dim=-1) < RADIUS] = value
        wall = (coords[..., 0] > 0.3) & ((coords[..., 2] + 1.5).abs() < 0.03)
        density[wall] = 200.0
        return (density * inside)[..., None]


def _camera(x: float) -> DepthView:
    """A 40x40 camera at (x, 0, 0) looking down -z (OpenGL axes) that renders the plane z = -2 (the depth the pixel
    rule reads; the weights read the density)."""
    c2w = np.eye(4)[:3]
    c2w[0, 3] = x
    u = (np.arange(40) + 0.5 - 20.0) / 40.0
    depth = 2.0 * np.sqrt(1.0 + u[None, :] ** 2 + u[:, None] ** 2)
    return DepthView(c2w, 40.0, 40.0, 20.0, 20.0, depth, np.zeros((0, 3)))


def test_only_a_dense_body_in_sight_holds_the_rays_weight() -> None:
    field, views = KnownDensity(), [_camera(0.0), _camera(0.2)]
    fruit = body_weights(field, views, FRUIT, RADIUS)
    hidden = body_weights(field, views, HIDDEN, RADIUS)
    floater = body_weights(field, views, FLOATER, RADIUS)
    assert np.all(fruit > 0.99), fruit  # 60 per unit over a 0.2 chord: opacity 1 - exp(-12)
    assert np.all(hidden < 0.01), hidden  # the wall in front stops the rays first
    assert np.all(floater < MIN_BODY_WEIGHT) and np.all(floater > 0.2), floater  # 1 - exp(-0.4) = 0.33


def test_a_view_shows_only_the_body_it_sees() -> None:
    """views_showing_pixels with the field: the fruit is shown by both views, the hidden blob and the floater by none
    (the pixel rule alone, all depths at 2 here, cannot tell the floater from the fruit)."""
    field, views = KnownDensity(), [_camera(0.0), _camera(0.2)]
    offsets = np.stack(np.meshgrid(*[np.linspace(-0.06, 0.06, 4)] * 3), -1).reshape(-1, 3)
    margin = 0.05
    assert views_showing_pixels(FRUIT + offsets, views, margin, 3.0, field) == 2
    assert views_showing_pixels(FLOATER + offsets, views, margin, 3.0) == 2  # without the field
    assert views_showing_pixels(FLOATER + offsets, views, margin, 3.0, field) == 0
    assert views_showing_pixels(HIDDEN + offsets, views, margin, 3.0, field) == 0


def test_a_pixel_whose_ray_stops_in_front_does_not_show_the_object() -> None:
    """A rim pixel beside an occluder (rendered depth well in front of the object), a sky pixel (nothing rendered)
    and a pixel whose ray passes through to a surface behind do not show the object; a pixel on it does."""
    depth = np.array([[2.0, 1.2], [np.inf, 3.0]])
    view = DepthView(np.eye(4)[:3], 1.0, 1.0, 1.0, 1.0, depth, np.zeros((0, 3)))
    points = np.array([[0.0, 0.0, -2.0], [0.0, 0.0, -2.05]] * 4)
    pixel = np.array([0, 0, 1, 1, 2, 2, 3, 3])
    assert pixels_on_object(points, pixel, view, margin=0.05).tolist() == [0]
