"""Procedural orchard / garden rows: geometry, materials, visible shading under a lighting preset, temperatures.

World frame: x along the row (the rig's direction of travel), y away from the rig across the row, z up, metres.
The front row stands on y = 0, a second row behind it; the ground is the plane z = 0.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Dict, List

import numpy as np
from jaxtyping import Float, Int

from agrinerf_ns.synth.raycast import GROUND, SKY, Hits, Primitives
from agrinerf_ns.synth.textures import ValueNoise, smoothstep

LEAF, FRUIT, BARK, STAKE = 0, 1, 2, 3
MATERIAL_NAMES = {LEAF: "leaf", FRUIT: "fruit", BARK: "bark", STAKE: "stake", GROUND: "ground", SKY: "sky"}


@dataclass(frozen=True)
class Lighting:
    """Visible illumination: a sun (direction towards it, colour x irradiance) and a sky dome."""

    name: str
    sun_dir: tuple
    sun: tuple
    sky_zenith: tuple
    sky_horizon: tuple
    ambient: tuple
    canopy_density: float
    """Extinction (1/m) of sunlight through a canopy envelope (soft cast shadows)."""
    event_noise_scale: float
    """Background-activity noise multiplier of the event camera (dim light is noisier)."""
    exposure_s: float
    """RGB auto-exposure time in seconds (the motion-blur length; the image level is the capped gain of
    ``sensors.exposure_gains``)."""


def _dir(elev_deg: float, azim_deg: float) -> tuple:
    e, a = np.radians(elev_deg), np.radians(azim_deg)
    return (float(np.cos(e) * np.cos(a)), float(np.cos(e) * np.sin(a)), float(np.sin(e)))


# fmt: off
# Lighting(name, sun_dir, sun, sky_zenith, sky_horizon, ambient, canopy_density, event_noise_scale, exposure_s)
LIGHTING_PRESETS: Dict[str, Lighting] = {
    # sun high behind the rig: the camera sees the lit side of the row
    "bright": Lighting("bright", _dir(55.0, -110.0), (2.6, 2.5, 2.3), (0.30, 0.48, 0.95), (0.85, 0.92, 1.05),
                       (0.40, 0.48, 0.62), 2.0, 1.0, 0.002),
    # lower sun behind the row: the camera sees the shaded side, with sunlit patches through the gaps
    "shadowed": Lighting("shadowed", _dir(28.0, 75.0), (2.8, 2.6, 2.3), (0.25, 0.40, 0.85), (0.75, 0.82, 0.95),
                         (0.16, 0.19, 0.26), 3.0, 1.0, 0.004),
    # sun on the horizon, warm and dim
    "dusk": Lighting("dusk", _dir(5.0, -150.0), (0.30, 0.15, 0.06), (0.035, 0.04, 0.08), (0.20, 0.11, 0.06),
                     (0.030, 0.026, 0.035), 2.5, 2.0, 0.060),
    # night: faint sky light only
    "dark": Lighting("dark", _dir(-20.0, 0.0), (0.0, 0.0, 0.0), (0.0012, 0.0016, 0.003), (0.002, 0.0022, 0.003),
                     (0.001, 0.0012, 0.0016), 2.5, 5.0, 0.100),
}
# fmt: on


@dataclass
class Scene:
    """Geometry plus per-primitive materials, colours and temperatures; envelopes of the canopies."""

    prims: Primitives
    material: Int[np.ndarray, " p"]
    color: Float[np.ndarray, "p 3"]
    temp_offset: Float[np.ndarray, " p"]
    fruit_id: Int[np.ndarray, " p"]
    """Index into ``fruits`` for fruit primitives, -1 otherwise."""
    tree: Int[np.ndarray, " p"]
    """Index of the plant a primitive belongs to (-1 for none)."""
    env_center: Float[np.ndarray, "t 3"]
    env_radii: Float[np.ndarray, "t 3"]
    temps: Dict[str, float]
    """Base temperatures in degrees Celsius (air, leaf, fruit, bark, ground, stake)."""
    fruits: List[dict]
    kind: str
    noise: ValueNoise


def _tree_rng(seed: int, row: int, k: int) -> np.random.Generator:
    return np.random.default_rng([seed, 101, row, k + 1000])


def _plant(
    rng: np.random.Generator, kind: str, x: float, y: float, fruit_color: np.ndarray, out: dict, tree_index: int
) -> None:
    """Append one tree (orchard) or staked plant (garden) to the primitive lists in ``out``."""
    if kind == "orchard":
        h_env = rng.uniform(1.65, 2.0)
        env_r = np.array([rng.uniform(0.75, 0.95), rng.uniform(0.5, 0.65), rng.uniform(0.85, 1.1)])
        n_clusters, cl_r, n_fruit, fruit_r = rng.integers(60, 75), (0.12, 0.23), rng.integers(22, 34), (0.042, 0.055)
        trunk_r = rng.uniform(0.055, 0.085)
        lean = rng.normal(0, 0.05, 2)
        top = np.array([x + lean[0], y + lean[1], h_env + 0.2])
        out["cyl"].append((np.array([x, y, -0.05]), top, trunk_r, BARK, tree_index))
        for _ in range(rng.integers(2, 4)):  # scaffold branches
            z0 = rng.uniform(0.85, 1.3)
            a = rng.uniform(0, 2 * np.pi)
            end = np.array([x + 0.7 * env_r[0] * np.cos(a), y + 0.7 * env_r[1] * np.sin(a), z0 + rng.uniform(0.3, 0.6)])
            out["cyl"].append((np.array([x, y, z0]), end, trunk_r * 0.45, BARK, tree_index))
    else:
        h_env = rng.uniform(0.6, 0.8)
        env_r = np.array([rng.uniform(0.30, 0.38), rng.uniform(0.26, 0.32), rng.uniform(0.42, 0.55)])
        n_clusters, cl_r, n_fruit, fruit_r = rng.integers(34, 44), (0.07, 0.13), rng.integers(8, 14), (0.026, 0.036)
        out["cyl"].append(
            (np.array([x + 0.05, y - 0.12, -0.05]), np.array([x + 0.05, y - 0.12, 1.45]), 0.014, STAKE, tree_index)
        )
        out["cyl"].append((np.array([x, y, -0.05]), np.array([x, y, h_env + 0.3]), 0.012, BARK, tree_index))
    center = np.array([x, y, h_env])
    out["env"].append((center, env_r))
    leaf_base = np.array([0.10, 0.26, 0.06]) * rng.uniform(0.8, 1.2)
    for _ in range(n_clusters):
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        c = center + d * env_r * rng.uniform(0.45, 0.95) ** 0.5
        r = rng.uniform(*cl_r, 3) * np.array([1.0, 1.0, 0.8])
        col = leaf_base * rng.uniform(0.75, 1.25, 3) * np.array([1.0, rng.uniform(0.9, 1.15), 1.0])
        out["ell"].append((c, r, LEAF, col, rng.normal(0, 0.4), -1, tree_index))
    for _ in range(n_fruit):
        d = rng.normal(size=3)
        d[2] = -abs(d[2]) * 0.6 if rng.random() < 0.7 else d[2]  # more fruit in the lower canopy
        d /= np.linalg.norm(d)
        c = center + d * env_r * rng.uniform(0.85, 1.05)
        rr = rng.uniform(*fruit_r)
        r = np.array([rr, rr, rr * rng.uniform(0.85, 0.95)])
        col = np.clip(fruit_color * rng.uniform(0.8, 1.15, 3), 0, 1)
        out["ell"].append((c, r, FRUIT, col, rng.normal(0, 0.5), len(out["fruits"]), tree_index))
        out["fruits"].append({"center": c, "radii": r, "tree": tree_index})


def build_scene(kind: str, seed: int, x_min: float, x_max: float) -> Scene:
    """A row of plants covering [x_min, x_max] (plants are seeded by their slot, so they do not depend on the range)."""
    rng = np.random.default_rng([seed, 7])
    spacing, back_y = (1.6, 3.8) if kind == "orchard" else (0.75, 1.7)
    varieties = (
        [np.array([0.62, 0.07, 0.05]), np.array([0.80, 0.33, 0.04]), np.array([0.55, 0.55, 0.08])]
        if kind == "orchard"
        else [np.array([0.72, 0.06, 0.04]), np.array([0.85, 0.45, 0.03])]
    )
    fruit_color = varieties[int(rng.choice(len(varieties), p=[0.5, 0.3, 0.2] if kind == "orchard" else [0.7, 0.3]))]
    air = float(rng.uniform(12.0, 24.0))
    leaf = air - float(rng.uniform(0.5, 2.0))
    delta = float(rng.uniform(2.0, 5.0)) * (1.0 if rng.random() < 0.5 else -1.0)
    temps = {
        "air": air,
        "leaf": leaf,
        "fruit": leaf + delta,
        "bark": air + float(rng.uniform(0.0, 2.0)),
        "ground": air + float(rng.uniform(1.0, 5.0)),
        "stake": air + 1.0,
        "sky_zenith": -10.0,
        "sky_horizon": 2.0,
    }
    noise = ValueNoise(np.random.default_rng([seed, 11]))
    out: dict = {"ell": [], "cyl": [], "env": [], "fruits": []}
    tree_index = 0
    for row, (y, shift) in enumerate(((0.0, 0.0), (back_y, 0.5))):
        k0 = int(np.floor(x_min / spacing - shift)) - 1
        k1 = int(np.ceil(x_max / spacing - shift)) + 1
        for k in range(k0, k1 + 1):
            trng = _tree_rng(seed, row, k)
            x = (k + shift) * spacing + trng.uniform(-0.12, 0.12) * spacing
            _plant(trng, kind, x, y + trng.uniform(-0.08, 0.08), fruit_color, out, tree_index)
            tree_index += 1
    # a hedge far behind the rows closes the view (no ground to the horizon), leaving sky above it
    hedge_y, hedge_h = (back_y + 5.0, 3.2) if kind == "orchard" else (back_y + 3.3, 1.8)
    for k in range(int(np.floor(x_min)) - 4, int(np.ceil(x_max)) + 5):
        hrng = np.random.default_rng([seed, 202, k + 1000])
        r = np.array([hrng.uniform(0.7, 1.0), hrng.uniform(0.6, 0.9), hedge_h * hrng.uniform(0.4, 0.55)])
        c = np.array([k + hrng.uniform(-0.3, 0.3), hedge_y + hrng.uniform(-0.3, 0.3), r[2] * hrng.uniform(0.7, 0.9)])
        col = np.array([0.07, 0.18, 0.05]) * hrng.uniform(0.75, 1.2, 3)
        out["ell"].append((c, r, LEAF, col, float(hrng.normal(0, 0.4)), -1, -1))
    ell, cyl = out["ell"], out["cyl"]
    prims = Primitives(
        ell_center=np.array([e[0] for e in ell]),
        ell_radii=np.array([e[1] for e in ell]),
        cyl_p0=np.array([c[0] for c in cyl]),
        cyl_p1=np.array([c[1] for c in cyl]),
        cyl_radius=np.array([c[2] for c in cyl], dtype=np.float64),
    )
    cyl_col = {BARK: np.array([0.24, 0.17, 0.11]), STAKE: np.array([0.50, 0.40, 0.26])}
    fruits = []
    fruit_ell = {e[5]: e for e in ell if e[5] >= 0}
    for i, f in enumerate(out["fruits"]):
        e = fruit_ell[i]
        fruits.append(
            {
                "id": i,
                "center": [round(float(v), 6) for v in f["center"]],
                "radii": [round(float(v), 6) for v in f["radii"]],
                "plant": int(f["tree"]),
                "temperature_c": round(temps["fruit"] + float(e[4]), 4),
            }
        )
    return Scene(
        prims=prims,
        material=np.array([e[2] for e in ell] + [c[3] for c in cyl], dtype=np.int64),
        color=np.array([e[3] for e in ell] + [cyl_col[c[3]] for c in cyl]),
        temp_offset=np.array([e[4] for e in ell] + [0.0 for _ in cyl]),
        fruit_id=np.array([e[5] for e in ell] + [-1 for _ in cyl], dtype=np.int64),
        tree=np.array([e[6] for e in ell] + [c[4] for c in cyl], dtype=np.int64),
        env_center=np.array([e[0] for e in out["env"]]),
        env_radii=np.array([e[1] for e in out["env"]]),
        temps=temps,
        fruits=fruits,
        kind=kind,
        noise=noise,
    )


def material_of(scene: Scene, hits: Hits) -> Int[np.ndarray, " n"]:
    """Material per pixel (LEAF, FRUIT, BARK, STAKE, GROUND or SKY)."""
    return np.where(hits.prim >= 0, scene.material[np.clip(hits.prim, 0, None)], hits.prim)


def fruit_ids(scene: Scene, hits: Hits) -> Int[np.ndarray, " n"]:
    """Fruit index per pixel, -1 where no fruit is seen."""
    return np.where(hits.prim >= 0, scene.fruit_id[np.clip(hits.prim, 0, None)], -1)


def _ground_mix(scene: Scene, p: np.ndarray) -> np.ndarray:
    """0 = grass, 1 = bare soil."""
    q = p * np.array([0.9, 0.9, 0.0]) + 40.0
    return smoothstep(0.42, 0.62, scene.noise.fbm(q, 3))


def albedo(scene: Scene, hits: Hits, mat: np.ndarray) -> Float[np.ndarray, "n 3"]:
    """Diffuse reflectance per pixel from solid textures."""
    n = hits.t.shape[0]
    alb = np.zeros((n, 3))
    nz = scene.noise
    hitp = hits.prim >= 0
    base = np.where(hitp[:, None], scene.color[np.clip(hits.prim, 0, None)], 0.0)
    m = mat == LEAF
    if m.any():
        p = hits.points[m]
        coarse = nz.fbm(p * 14.0, 3)
        fine = nz(p * 40.0 + 3.1)
        alb[m] = base[m] * (0.35 + 1.3 * coarse[:, None]) * (0.75 + 0.5 * fine[:, None])
    m = mat == FRUIT
    if m.any():
        p = hits.points[m]
        blush = nz.fbm(p * 25.0 + 7.7, 2)
        alb[m] = base[m] * (0.8 + 0.4 * blush[:, None])
    m = (mat == BARK) | (mat == STAKE)
    if m.any():
        p = hits.points[m]
        streak = nz.fbm(p * np.array([30.0, 30.0, 5.0]) + 5.5, 3)
        alb[m] = base[m] * (0.5 + 1.0 * streak[:, None])
    m = mat == GROUND
    if m.any():
        p = hits.points[m]
        mix = _ground_mix(scene, p)[:, None]
        detail = nz.fbm(p * 11.0 + 91.0, 3)[:, None]
        speck = nz(p * 30.0 + 13.0)[:, None]
        grass = np.array([0.13, 0.25, 0.06]) * (0.45 + 1.1 * detail)
        soil = np.array([0.32, 0.24, 0.16]) * (0.6 + 0.8 * detail)
        alb[m] = (grass * (1 - mix) + soil * mix) * (0.7 + 0.6 * speck)
    return alb


def _canopy_transmittance(scene: Scene, p: np.ndarray, s: np.ndarray, density: float) -> np.ndarray:
    """Sunlight reaching ``p`` through the canopy envelopes (soft shadows): exp(-density x chord length).

    Points are indexed by their coordinates across the sun direction, so each envelope is tested only against the
    points whose sun ray passes within its bounding sphere.
    """
    trans = np.ones(p.shape[0])
    if p.shape[0] == 0:
        return trans
    u = np.cross(s, [0.0, 0.0, 1.0])
    u = u / np.linalg.norm(u) if np.linalg.norm(u) > 1e-6 else np.array([1.0, 0.0, 0.0])
    v = np.cross(s, u)
    qu, qv = p @ u, p @ v
    order = np.argsort(qu, kind="stable")
    qu_sorted = qu[order]
    log_t = np.zeros(p.shape[0])
    for c, r in zip(scene.env_center, scene.env_radii * 1.1, strict=True):
        big = r.max()
        cu = c @ u
        lo, hi = np.searchsorted(qu_sorted, [cu - big, cu + big])
        if hi <= lo:
            continue
        idx = order[lo:hi]
        idx = idx[np.abs(qv[idx] - c @ v) < big]
        if idx.size == 0:
            continue
        o = (p[idx] - c) / r
        d = s / r
        a = d @ d
        b = o @ d
        cc = np.einsum("ij,ij->i", o, o) - 1.0
        disc = b * b - a * cc
        ok = disc > 0
        sq = np.sqrt(np.where(ok, disc, 0.0))
        t0 = np.clip((-b - sq) / a, 0.0, None)
        t1 = np.clip((-b + sq) / a, 0.0, None)
        log_t[idx] -= density * np.where(ok, t1 - t0, 0.0)
    return trans * np.exp(log_t)


def _sky(light: Lighting, d: np.ndarray) -> np.ndarray:
    elev = np.clip(d[:, 2], 0.0, 1.0)[:, None]
    w = elev**0.5
    return np.array(light.sky_horizon) * (1 - w) + np.array(light.sky_zenith) * w


def radiance(scene: Scene, hits: Hits, light: Lighting) -> Float[np.ndarray, "n 3"]:
    """Linear RGB radiance per pixel under ``light``."""
    mat = material_of(scene, hits)
    out = np.zeros((hits.t.shape[0], 3))
    sky = mat == SKY
    out[sky] = _sky(light, hits.dirs_world[sky])
    m = ~sky
    if not m.any():
        return out
    p, nrm, vdir = hits.points[m], hits.normals[m], hits.dirs_world[m]
    alb = albedo(scene, hits, mat)[m]
    s = np.array(light.sun_dir)
    sun = np.array(light.sun)
    cos = nrm @ s
    shadow = _canopy_transmittance(scene, p, s, light.canopy_density) if s[2] > 0 else np.zeros(p.shape[0])
    # ambient occlusion of canopy interiors: deeper inside a plant's envelope is darker
    tree = np.where(hits.prim[m] >= 0, scene.tree[np.clip(hits.prim[m], 0, None)], -1)
    ao = np.ones(p.shape[0])
    it = tree >= 0
    if it.any():
        rho = np.linalg.norm((p[it] - scene.env_center[tree[it]]) / scene.env_radii[tree[it]], axis=1)
        ao[it] = 0.35 + 0.65 * np.clip(rho, 0.0, 1.0) ** 1.5
    ambient = np.array(light.ambient)[None] * (0.55 + 0.45 * nrm[:, 2:3]) * ao[:, None]
    direct = sun[None] * (np.clip(cos, 0.0, None) * shadow)[:, None]
    mm = mat[m]
    leaf = mm == LEAF
    direct[leaf] += sun[None] * (0.35 * np.clip(-cos[leaf], 0.0, None) * shadow[leaf])[:, None]  # translucency
    rad = alb * (direct + ambient)
    fr = mm == FRUIT
    if fr.any():
        h = s[None] - vdir[fr]
        h /= np.linalg.norm(h, axis=1, keepdims=True)
        spec = np.clip(np.einsum("ij,ij->i", nrm[fr], h), 0.0, None) ** 40 * shadow[fr] * (cos[fr] > 0)
        rad[fr] += 0.06 * spec[:, None] * sun[None]
    out[m] = rad
    return out


def rec709_luminance(rgb: Float[np.ndarray, "n 3"]) -> Float[np.ndarray, " n"]:
    """Relative luminance Y = 0.2126 R + 0.7152 G + 0.0722 B of linear RGB (Rec. 709 primaries), what the simulated
    event pixels respond to; not the BT.601 luma of gamma-encoded RGB of ``agrinerf_ns.model.losses.luminance``."""
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def temperature(scene: Scene, hits: Hits) -> Float[np.ndarray, " n"]:
    """Surface temperature per pixel in degrees Celsius (independent of visible lighting)."""
    mat = material_of(scene, hits)
    tp = scene.temps
    out = np.zeros(hits.t.shape[0])
    off = np.where(hits.prim >= 0, scene.temp_offset[np.clip(hits.prim, 0, None)], 0.0)
    sky = mat == SKY
    elev = np.clip(hits.dirs_world[sky, 2], 0.0, 1.0)
    out[sky] = tp["sky_horizon"] + (tp["sky_zenith"] - tp["sky_horizon"]) * elev**0.4
    m = mat == LEAF
    out[m] = tp["leaf"] + off[m] + 0.8 * (scene.noise.fbm(hits.points[m] * 8.0 + 3.0, 2) - 0.5)
    m = mat == FRUIT
    out[m] = tp["fruit"] + off[m]
    m = mat == BARK
    out[m] = tp["bark"]
    m = mat == STAKE
    out[m] = tp["stake"]
    m = mat == GROUND
    if m.any():
        p = hits.points[m]
        out[m] = tp["ground"] + 3.0 * (_ground_mix(scene, p) - 0.5) + 0.6 * (scene.noise(p * 4.0 + 8.0) - 0.5)
    return out
