"""Vectorised numpy ray casting of ellipsoids, finite cylinders and the ground plane through a pinhole-radtan camera.

Each primitive is tested only against the pixels of its projected bounding box (pairs of pixel and primitive are
generated with numpy, never with a Python loop over pixels), so a render costs about (pixels x overlap) tests.
Pixel convention (OpenCV / Kalibr): the centre of pixel column ``i`` is at ``u = i``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from typing import List, Tuple

import numpy as np
from jaxtyping import Bool, Float, Int

NEAR = 0.05
"""Nearest hit distance along a ray in metres."""

SKY = -1
GROUND = -2


@dataclass(frozen=True)
class PinholeRadtan:
    """A pinhole camera with Kalibr/OpenCV radial-tangential distortion (k1, k2, p1, p2)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: Tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)

    def scaled(self, s: int) -> "PinholeRadtan":
        """The same lens sampled ``s`` times denser per axis (for supersampling)."""
        return PinholeRadtan(
            self.width * s,
            self.height * s,
            self.fx * s,
            self.fy * s,
            self.cx * s + (s - 1) / 2,
            self.cy * s + (s - 1) / 2,
            self.dist,
        )

    def distort(self, x: Float[np.ndarray, "*n"], y: Float[np.ndarray, "*n"]) -> Tuple[np.ndarray, np.ndarray]:
        """Normalised undistorted coordinates to normalised distorted ones."""
        k1, k2, p1, p2 = self.dist
        r2 = x * x + y * y
        radial = 1.0 + k1 * r2 + k2 * r2 * r2
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        return xd, yd

    def undistort(self, xd: Float[np.ndarray, "*n"], yd: Float[np.ndarray, "*n"]) -> Tuple[np.ndarray, np.ndarray]:
        """Invert :meth:`distort` by fixed-point iteration (accurate to ~1e-10 for mild lenses)."""
        k1, k2, p1, p2 = self.dist
        x, y = xd.copy(), yd.copy()
        for _ in range(30):
            r2 = x * x + y * y
            radial = 1.0 + k1 * r2 + k2 * r2 * r2
            dx = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            dy = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x = (xd - dx) / radial
            y = (yd - dy) / radial
        return x, y

    def project(self, pts: Float[np.ndarray, "n 3"]) -> Tuple[Float[np.ndarray, "n 2"], Bool[np.ndarray, " n"]]:
        """Camera-frame points to distorted pixel coordinates, and whether each is in front of the camera."""
        z = pts[:, 2]
        front = z > 1e-6
        zs = np.where(front, z, 1.0)
        xd, yd = self.distort(pts[:, 0] / zs, pts[:, 1] / zs)
        return np.stack([self.fx * xd + self.cx, self.fy * yd + self.cy], -1), front

    @cached_property
    def normalized_grid(self) -> Tuple[Float[np.ndarray, "h w"], Float[np.ndarray, "h w"]]:
        """Undistorted normalised coordinates of every pixel centre."""
        u, v = np.meshgrid(np.arange(self.width, dtype=np.float64), np.arange(self.height, dtype=np.float64))
        return self.undistort((u - self.cx) / self.fx, (v - self.cy) / self.fy)

    @cached_property
    def ray_dirs(self) -> Float[np.ndarray, "hw 3"]:
        """Unit ray directions of every pixel in the camera frame (row-major)."""
        x, y = self.normalized_grid
        d = np.stack([x.ravel(), y.ravel(), np.ones(x.size)], -1)
        return d / np.linalg.norm(d, axis=1, keepdims=True)

    @cached_property
    def _column_row_bounds(self) -> Tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        x, y = self.normalized_grid
        # running extrema make the bounds monotonic, so searchsorted gives conservative pixel ranges
        return (
            np.minimum.accumulate(x.min(0)[::-1])[::-1],
            np.maximum.accumulate(x.max(0)),
            np.minimum.accumulate(y.min(1)[::-1])[::-1],
            np.maximum.accumulate(y.max(1)),
        )

    def pixel_boxes(
        self, lo: Float[np.ndarray, "n 2"], hi: Float[np.ndarray, "n 2"]
    ) -> Tuple[Int[np.ndarray, " n"], Int[np.ndarray, " n"], Int[np.ndarray, " n"], Int[np.ndarray, " n"]]:
        """Pixel rectangles [x0, x1) x [y0, y1) holding every pixel whose undistorted coordinates lie in [lo, hi]."""
        cmin, cmax, rmin, rmax = self._column_row_bounds
        x0 = np.searchsorted(cmax, lo[:, 0], side="left")
        x1 = np.searchsorted(cmin, hi[:, 0], side="right")
        y0 = np.searchsorted(rmax, lo[:, 1], side="left")
        y1 = np.searchsorted(rmin, hi[:, 1], side="right")
        return x0, x1, y0, y1


@dataclass
class Primitives:
    """Scene geometry: axis-aligned ellipsoids and finite cylinders (the ground is the plane z = 0)."""

    ell_center: Float[np.ndarray, "e 3"]
    ell_radii: Float[np.ndarray, "e 3"]
    cyl_p0: Float[np.ndarray, "c 3"]
    cyl_p1: Float[np.ndarray, "c 3"]
    cyl_radius: Float[np.ndarray, " c"]
    aabb_lo: Float[np.ndarray, "p 3"] = field(init=False)
    aabb_hi: Float[np.ndarray, "p 3"] = field(init=False)

    def __post_init__(self) -> None:
        r = self.cyl_radius[:, None]
        self.aabb_lo = np.concatenate([self.ell_center - self.ell_radii, np.minimum(self.cyl_p0, self.cyl_p1) - r], 0)
        self.aabb_hi = np.concatenate([self.ell_center + self.ell_radii, np.maximum(self.cyl_p0, self.cyl_p1) + r], 0)

    @property
    def num_ellipsoids(self) -> int:
        return len(self.ell_center)

    @property
    def count(self) -> int:
        return len(self.aabb_lo)


@dataclass
class Hits:
    """Per-pixel results of one render (row-major, flattened)."""

    t: Float[np.ndarray, " n"]
    """Distance along the unit ray, inf for sky."""
    prim: Int[np.ndarray, " n"]
    """Index of the primitive hit (ellipsoids first, then cylinders), GROUND or SKY."""
    points: Float[np.ndarray, "n 3"]
    normals: Float[np.ndarray, "n 3"]
    dirs_world: Float[np.ndarray, "n 3"]
    zdepth: Float[np.ndarray, " n"]
    """Metric z-depth in the camera frame, inf for sky."""
    width: int
    height: int


def _pairs(
    prims: Primitives, cam: PinholeRadtan, R_cw: np.ndarray, origin: np.ndarray
) -> Tuple[np.ndarray, np.ndarray]:
    """(pixel, primitive) candidate pairs from each primitive's projected bounding box."""
    lo, hi = prims.aabb_lo, prims.aabb_hi
    sel = np.array([[0, 0, 0], [0, 0, 1], [0, 1, 0], [0, 1, 1], [1, 0, 0], [1, 0, 1], [1, 1, 0], [1, 1, 1]], bool)
    corners = np.where(sel[None], hi[:, None, :], lo[:, None, :])  # (p, 8, 3)
    cam_pts = (corners - origin) @ R_cw.T
    z = cam_pts[..., 2]
    behind = z < NEAR
    all_behind = behind.all(1)
    some_behind = behind.any(1) & ~all_behind
    zs = np.where(behind, 1.0, z)
    nx, ny = cam_pts[..., 0] / zs, cam_pts[..., 1] / zs
    big = 1e6
    blo = np.stack([np.where(behind, big, nx).min(1), np.where(behind, big, ny).min(1)], -1)
    bhi = np.stack([np.where(behind, -big, nx).max(1), np.where(behind, -big, ny).max(1)], -1)
    blo[some_behind] = -big
    bhi[some_behind] = big
    blo[all_behind] = big
    bhi[all_behind] = -big
    _tighten_ellipsoids(prims, R_cw, origin, blo, bhi)
    x0, x1, y0, y1 = cam.pixel_boxes(blo, bhi)
    w = np.clip(x1 - x0, 0, None)
    h = np.clip(y1 - y0, 0, None)
    n = w * h
    keep = np.nonzero(n > 0)[0]
    if keep.size == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    n, w, x0, y0 = n[keep], w[keep], x0[keep], y0[keep]
    prim = np.repeat(keep, n)
    starts = np.repeat(np.cumsum(n) - n, n)
    local = np.arange(prim.size) - starts
    wr = np.repeat(w, n)
    pix = (np.repeat(y0, n) + local // wr) * cam.width + np.repeat(x0, n) + local % wr
    return pix, prim


def _tighten_ellipsoids(
    prims: Primitives, R_cw: np.ndarray, origin: np.ndarray, blo: np.ndarray, bhi: np.ndarray
) -> None:
    """Shrink the bounds of ellipsoids wholly in front of the camera to their exact silhouette extents (in place).

    A plane through the camera centre with normal n = (1, 0, -a) touches the ellipsoid (centre c, shape
    Q = R diag(r^2) R^T in the camera frame) when (n . c)^2 = n^T Q n; its two roots a are the extreme x / z.
    """
    ne = prims.num_ellipsoids
    c = (prims.ell_center - origin) @ R_cw.T
    Q = np.einsum("ij,ej,kj->eik", R_cw, prims.ell_radii**2, R_cw)
    ok = c[:, 2] - np.sqrt(Q[:, 2, 2]) > NEAR
    if not ok.any():
        return
    A = c[:, 2] ** 2 - Q[:, 2, 2]
    A = np.where(ok, A, 1.0)
    for axis in (0, 1):
        B = c[:, axis] * c[:, 2] - Q[:, axis, 2]
        C = c[:, axis] ** 2 - Q[:, axis, axis]
        sq = np.sqrt(np.clip(B * B - A * C, 0.0, None))
        lo, hi = (B - sq) / A, (B + sq) / A
        blo[:ne, axis] = np.where(ok, np.maximum(blo[:ne, axis], lo - 1e-9), blo[:ne, axis])
        bhi[:ne, axis] = np.where(ok, np.minimum(bhi[:ne, axis], hi + 1e-9), bhi[:ne, axis])


Candidates = Tuple[Int[np.ndarray, " k"], Float[np.ndarray, " k"], Int[np.ndarray, " k"]]
"""(pixel, ray distance, primitive) of each ray-primitive intersection in front of the camera."""


def _ellipsoid_hits(
    prims: Primitives, origin: np.ndarray, dirs: np.ndarray, pix: np.ndarray, prim: np.ndarray
) -> Candidates:
    """Intersections of the (pixel, ellipsoid) pairs ``pix``, ``prim``: the entry, or the exit from inside."""
    inv_r = 1.0 / prims.ell_radii
    oc = (origin - prims.ell_center) * inv_r  # (e, 3)
    d = dirs[pix] * inv_r[prim]
    o = oc[prim]
    a = np.einsum("ij,ij->i", d, d)
    b = np.einsum("ij,ij->i", o, d)
    c = np.einsum("ij,ij->i", o, o) - 1.0
    disc = b * b - a * c
    ok = disc > 0
    sq = np.sqrt(np.where(ok, disc, 0.0))
    t = (-b - sq) / a
    t = np.where(t > NEAR, t, (-b + sq) / a)  # camera inside the ellipsoid: take the exit
    ok &= t > NEAR
    return pix[ok], t[ok], prim[ok]


def _cylinder_hits(
    prims: Primitives, origin: np.ndarray, dirs: np.ndarray, pix: np.ndarray, cyl: np.ndarray
) -> Candidates:
    """Intersections of the (pixel, cylinder) pairs ``pix``, ``cyl`` (cylinder indices, from 0) with the finite
    cylinders' sides; the primitives returned are numbered after the ellipsoids."""
    ne = prims.num_ellipsoids
    axis = prims.cyl_p1 - prims.cyl_p0
    length = np.linalg.norm(axis, axis=1)
    axis = axis / length[:, None]
    w0 = origin - prims.cyl_p0  # (c, 3)
    a_ = axis[cyl]
    d = dirs[pix]
    w = w0[cyl]
    dd = np.einsum("ij,ij->i", d, a_)
    wa = np.einsum("ij,ij->i", w, a_)
    dp = d - dd[:, None] * a_
    wp = w - wa[:, None] * a_
    A = np.einsum("ij,ij->i", dp, dp)
    B = np.einsum("ij,ij->i", wp, dp)
    C = np.einsum("ij,ij->i", wp, wp) - prims.cyl_radius[cyl] ** 2
    disc = B * B - A * C
    ok = (disc > 0) & (A > 1e-12)
    t = (-B - np.sqrt(np.where(ok, disc, 0.0))) / np.where(A > 1e-12, A, 1.0)
    s = wa + t * dd
    ok &= (t > NEAR) & (s >= 0) & (s <= length[cyl])
    return pix[ok], t[ok], cyl[ok] + ne


def _nearest_hits(
    origin: np.ndarray, dirs: np.ndarray, candidates: List[Tuple[np.ndarray, np.ndarray, np.ndarray]]
) -> Tuple[Float[np.ndarray, " n"], Int[np.ndarray, " n"]]:
    """Per pixel, the distance and primitive of the nearest of the ground plane z = 0 (the camera is above it) and
    ``candidates`` (ties: the lower primitive); the sky where nothing is hit."""
    dz = dirs[:, 2]
    tg = np.where(dz < -1e-9, -origin[2] / np.where(dz < -1e-9, dz, -1.0), np.inf)
    t_best = tg.copy()
    prim_best = np.where(np.isfinite(tg), GROUND, SKY).astype(np.int64)
    if candidates:
        cp = np.concatenate([c[0] for c in candidates])
        ct = np.concatenate([c[1] for c in candidates])
        cq = np.concatenate([c[2] for c in candidates])
        order = np.lexsort((cq, ct, cp))
        cp, ct, cq = cp[order], ct[order], cq[order]
        first = np.ones(cp.size, bool)
        first[1:] = cp[1:] != cp[:-1]
        cp, ct, cq = cp[first], ct[first], cq[first]
        closer = ct < t_best[cp]
        t_best[cp[closer]] = ct[closer]
        prim_best[cp[closer]] = cq[closer]
    return t_best, prim_best


def _surface_normals(
    prims: Primitives, points: Float[np.ndarray, "n 3"], prim_best: Int[np.ndarray, " n"]
) -> Float[np.ndarray, "n 3"]:
    """Unit surface normals at ``points`` on the primitives ``prim_best`` (zero on the sky)."""
    ne = prims.num_ellipsoids
    normals = np.zeros_like(points)
    normals[prim_best == GROUND] = (0.0, 0.0, 1.0)
    m = (prim_best >= 0) & (prim_best < ne)
    if m.any():
        q = prim_best[m]
        nrm = (points[m] - prims.ell_center[q]) / prims.ell_radii[q] ** 2
        normals[m] = nrm / np.linalg.norm(nrm, axis=1, keepdims=True)
    m = prim_best >= ne
    if m.any():
        q = prim_best[m] - ne
        axis = prims.cyl_p1[q] - prims.cyl_p0[q]
        axis /= np.linalg.norm(axis, axis=1, keepdims=True)
        rel = points[m] - prims.cyl_p0[q]
        nrm = rel - np.einsum("ij,ij->i", rel, axis)[:, None] * axis
        normals[m] = nrm / np.maximum(np.linalg.norm(nrm, axis=1, keepdims=True), 1e-12)
    return normals


def cast(prims: Primitives, cam: PinholeRadtan, T_wc: Float[np.ndarray, "4 4"]) -> Hits:
    """Render the nearest hit of every pixel of ``cam`` at camera-to-world pose ``T_wc`` (OpenCV axes)."""
    R_wc, origin = T_wc[:3, :3], T_wc[:3, 3]
    dirs = cam.ray_dirs @ R_wc.T
    pix, prim = _pairs(prims, cam, R_wc.T, origin)
    ne = prims.num_ellipsoids
    candidates: List[Tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    is_e = prim < ne
    pe, ie = pix[is_e], prim[is_e]
    if pe.size:
        candidates.append(_ellipsoid_hits(prims, origin, dirs, pe, ie))
    pc, ic = pix[~is_e], prim[~is_e] - ne
    if pc.size:
        candidates.append(_cylinder_hits(prims, origin, dirs, pc, ic))
    t_best, prim_best = _nearest_hits(origin, dirs, candidates)

    hit = np.isfinite(t_best)
    points = origin + np.where(hit, t_best, 0.0)[:, None] * dirs
    normals = _surface_normals(prims, points, prim_best)
    zdepth = np.where(hit, t_best * cam.ray_dirs[:, 2], np.inf)
    return Hits(t_best, prim_best, points, normals, dirs, zdepth, cam.width, cam.height)
