"""Seeded 3D value noise and fractal sums of it: solid textures evaluated at hit points (multi-view consistent)."""

from __future__ import annotations

import numpy as np
from jaxtyping import Float


class ValueNoise:
    """Smooth lattice value noise in [0, 1] from a seeded permutation table."""

    def __init__(self, rng: np.random.Generator) -> None:
        perm = rng.permutation(256)
        self._perm = np.concatenate([perm, perm]).astype(np.int64)
        self._vals = rng.random(256)

    def __call__(self, p: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, " n"]:
        fl = np.floor(p)
        f = p - fl
        f = f * f * (3.0 - 2.0 * f)
        i = fl.astype(np.int64) & 255
        perm, vals = self._perm, self._vals
        x0, y0, z0 = i[:, 0], i[:, 1], i[:, 2]
        x1, y1, z1 = (x0 + 1) & 255, (y0 + 1) & 255, (z0 + 1) & 255
        px0, px1 = perm[x0], perm[x1]
        pxy00, pxy01, pxy10, pxy11 = perm[px0 + y0], perm[px0 + y1], perm[px1 + y0], perm[px1 + y1]
        fx, fy, fz = f[:, 0], f[:, 1], f[:, 2]

        def lerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
            return a + (b - a) * t

        c00 = lerp(vals[perm[pxy00 + z0]], vals[perm[pxy10 + z0]], fx)
        c10 = lerp(vals[perm[pxy01 + z0]], vals[perm[pxy11 + z0]], fx)
        c01 = lerp(vals[perm[pxy00 + z1]], vals[perm[pxy10 + z1]], fx)
        c11 = lerp(vals[perm[pxy01 + z1]], vals[perm[pxy11 + z1]], fx)
        return lerp(lerp(c00, c10, fy), lerp(c01, c11, fy), fz)

    def fbm(self, p: Float[np.ndarray, "n 3"], octaves: int = 3, gain: float = 0.5) -> Float[np.ndarray, " n"]:
        """Fractal sum of ``octaves`` octaves (frequency doubling), normalised to [0, 1]."""
        total = np.zeros(p.shape[0])
        amp, norm = 1.0, 0.0
        for o in range(octaves):
            total += amp * self(p * (2.0**o) + 17.3 * o)
            norm += amp
            amp *= gain
        return total / norm


def smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    """Hermite step from 0 at ``e0`` to 1 at ``e1``."""
    t = np.clip((x - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
