"""agrinerf-synth sensors: dark vs bright RGB, thermal contrast independent of lighting, the event simulator."""

from __future__ import annotations

from pathlib import Path

import h5py
import numpy as np
import pytest
from PIL import Image

from agrinerf_ns.synth import SynthConfig, generate_capture
from agrinerf_ns.synth.camera_rig import THERMAL_DELAY, frame_times
from agrinerf_ns.synth.capture import event_luminance, event_times, make_scene
from agrinerf_ns.synth.raycast import cast
from agrinerf_ns.synth.scene import FRUIT, LEAF, LIGHTING_PRESETS, SKY, material_of
from agrinerf_ns.synth.sensors import EventSimulator

LIGHTINGS = ("bright", "shadowed", "dusk", "dark")
THERMAL = SynthConfig.tiny(seed=3, views=2, heldout=0, event_substeps=1, thermal_size=(128, 102))


@pytest.fixture(scope="module")
def by_lighting(tmp_path_factory: pytest.TempPathFactory) -> dict:
    root = tmp_path_factory.mktemp("synth_light")
    return {light: generate_capture(THERMAL.replace(lighting=light), root / light) for light in LIGHTINGS}


def _mean_rgb(raw: Path) -> float:
    return float(np.mean([np.asarray(Image.open(p)).mean() for p in sorted((raw / "rgb").glob("*.png"))]))


def test_dark_much_darker_than_bright(by_lighting: dict) -> None:
    bright, dark = _mean_rgb(by_lighting["bright"]), _mean_rgb(by_lighting["dark"])
    dusk = _mean_rgb(by_lighting["dusk"])
    assert bright > 60 and dark < 8 and bright / dark > 10
    assert dark < dusk < bright
    frame = np.asarray(Image.open(by_lighting["dark"] / "rgb" / "000000.png")).astype(np.float64)
    clean = np.asarray(Image.open(by_lighting["dark"] / "truth" / "rgb_clean" / "000000.png")).astype(np.float64)
    assert clean.mean() > 40  # the truth stays well exposed
    # noise-dominated: below the (brighter) night sky, the dark frame barely correlates with the scene
    scene_px = np.isfinite(np.load(by_lighting["dark"] / "truth" / "depth" / "000000.npy"))
    assert frame[scene_px].mean() < 5
    assert abs(np.corrcoef(frame[scene_px].ravel(), clean[scene_px].ravel())[0, 1]) < 0.6


def test_thermal_fruit_leaf_contrast_in_every_lighting(by_lighting: dict) -> None:
    scene, rig = make_scene(THERMAL)
    cam = rig.cams["thermal"]
    t = float(frame_times(THERMAL)[0]) + THERMAL_DELAY
    mat = material_of(scene, cast(scene.prims, cam, rig.pose(t, "thermal"))).reshape(cam.height, cam.width)

    def interior(m: np.ndarray) -> np.ndarray:
        out = m.copy()
        out[1:] &= m[:-1]
        out[:-1] &= m[1:]
        out[:, 1:] &= m[:, :-1]
        out[:, :-1] &= m[:, 1:]
        return out

    fruit, leaf = interior(mat == FRUIT), interior(mat == LEAF)
    assert fruit.sum() >= 3 and leaf.sum() >= 50
    delta_k = scene.temps["fruit"] - scene.temps["leaf"]
    images = {}
    for light, raw in by_lighting.items():
        counts = np.asarray(Image.open(raw / "thermal" / "000000.png")).astype(np.float64)
        diff = counts[fruit].mean() - counts[leaf].mean()
        assert np.sign(diff) == np.sign(delta_k), light
        assert abs(diff) > 30 * abs(delta_k), (light, diff, delta_k)  # blurred, but >= 0.3 x the true contrast
        sky = interior(mat == SKY)
        if sky.any():
            assert counts[sky].mean() < counts[leaf].mean() - 500  # cold sky
        images[light] = (raw / "thermal" / "000000.png").read_bytes()
    assert len(set(images.values())) == 1  # thermal does not depend on visible lighting


def test_simulator_static_and_ramps() -> None:
    rng = np.random.default_rng(0)
    sim = EventSimulator(8, 4, 0.2, 0.0, 0, 1e-6, rng)
    lum = np.full(32, 0.3)
    sim.reset(lum, 0.0)
    for k in range(1, 50):
        sim.step(lum, k * 0.01)
    x, _, _, _ = sim.finish(0.0, 0.49, 0.0, rng)
    assert x.size == 0  # static scene, no noise: no events

    sim = EventSimulator(8, 4, 0.2, 0.0, 0, 1e-6, rng)
    sim.reset(lum, 0.0)
    for k in range(1, 11):
        sim.step(lum * np.exp(0.11 * k), k * 0.01)  # log intensity +1.1 in total
    for k in range(1, 11):
        sim.step(lum * np.exp(1.1 - 0.12 * k), 0.1 + k * 0.01)  # down to -0.1
    x, y, t, p = sim.finish(0.0, 0.2, 0.0, rng)
    up = t <= 100_000
    assert np.all(p[up] == 1) and np.all(p[~up] == 0)
    assert up.sum() == 32 * 5 and (~up).sum() == 32 * 5  # five 0.2 crossings each way per pixel
    assert np.all(np.diff(t) >= 0)

    sim = EventSimulator(8, 4, 0.2, 0.0, 60_000, 1e-6, rng)
    sim.reset(lum, 0.0)
    for k in range(1, 11):
        sim.step(lum * np.exp(0.1 * k), k * 0.01)
    _, _, t, _ = sim.finish(0.0, 0.1, 0.0, rng)
    assert t.size <= 32 * 2  # the refractory period drops most crossings


def test_simulator_noise_rate() -> None:
    rng = np.random.default_rng(1)
    sim = EventSimulator(20, 10, 0.2, 0.03, 1000, 1e-6, rng)
    sim.reset(np.full(200, 0.5), 0.0)
    sim.step(np.full(200, 0.5), 10.0)
    x, _, t, p = sim.finish(0.0, 10.0, 2.0, rng)
    assert abs(x.size - 200 * 10 * 2.0) < 5 * np.sqrt(4000)
    assert 0.4 < p.mean() < 0.6 and t.min() >= 0 and t.max() <= 10_000_000


EVENTS = SynthConfig.tiny(seed=4, views=6, event_noise_hz=0.5)


@pytest.fixture(scope="module")
def event_capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_capture(EVENTS, tmp_path_factory.mktemp("synth_events") / "raw")


def _events(raw: Path) -> tuple:
    with h5py.File(raw / "events" / "events.h5", "r") as f:
        g = f["events"]
        return g["x"][:].astype(np.int64), g["y"][:].astype(np.int64), g["t"][:], g["p"][:]


def test_events_where_image_changes_not_in_static_sky(event_capture: Path) -> None:
    scene, rig = make_scene(EVENTS)
    cam = rig.cams["event"]
    times = event_times(EVENTS)
    always_sky = np.ones(cam.width * cam.height, bool)
    never_sky = np.ones_like(always_sky)
    for t in times:
        sky = material_of(scene, cast(scene.prims, cam, rig.pose(float(t), "event"))) == SKY
        always_sky &= sky
        never_sky &= ~sky
    always_sky = always_sky.reshape(cam.height, cam.width)
    core = always_sky.copy()
    core[1:] &= always_sky[:-1]
    core[:-1] &= always_sky[1:]
    core[:, 1:] &= always_sky[:, :-1]
    core[:, :-1] &= always_sky[:, 1:]
    assert core.sum() >= 20 and never_sky.sum() >= 200
    x, y, t, _ = _events(event_capture)
    per_px = np.bincount(y * cam.width + x, minlength=cam.width * cam.height)
    duration = times[-1] - times[0]
    noise_hz = EVENTS.event_noise_hz * LIGHTING_PRESETS[EVENTS.lighting].event_noise_scale
    sky_rate = per_px[core.ravel()].mean() / duration
    scene_rate = per_px[never_sky].mean() / duration
    assert sky_rate < 3 * noise_hz + 0.5  # noise rate only
    assert scene_rate > 30 * noise_hz  # the moving textured scene fires


def test_event_polarity_follows_log_intensity_change(event_capture: Path) -> None:
    scene, rig = make_scene(EVENTS)
    cam = rig.cams["event"]
    light = LIGHTING_PRESETS[EVENTS.lighting]
    times = event_times(EVENTS)
    x, y, t, p = _events(event_capture)
    agree = total = 0
    for k in range(2, len(times) - 1, 3):
        ta, tb = float(times[k]), float(times[k + 1])
        la, lb = (event_luminance(EVENTS, scene, rig, light, tt) for tt in (ta, tb))
        dlog = np.log(lb + 1e-6) - np.log(la + 1e-6)
        m = (t > round(ta * 1e6)) & (t <= round(tb * 1e6))
        net = np.zeros(cam.width * cam.height)
        np.add.at(net, y[m] * cam.width + x[m], np.where(p[m] > 0, 1.0, -1.0))
        strong = np.abs(dlog) > 2.5 * EVENTS.event_threshold
        total += int(strong.sum())
        agree += int((np.sign(net[strong]) == np.sign(dlog[strong])).sum())
    assert total > 50
    assert agree / total > 0.95


def _event_residual(config: SynthConfig) -> tuple:
    """Squared residual and correlation of the event camera's C (N_on - N_off) against the truth log change of its
    pixels over 6 random windows of 30-100 ms, and the renders per frame interval (the simulator alone)."""
    from agrinerf_ns.synth.event_fidelity import event_fidelity

    f = event_fidelity(config, windows=6, min_window_s=0.03)
    return f.squared_residual, f.correlation, f.substeps


def test_ideal_event_camera_counts_the_truth_log_change() -> None:
    """Sampled finely enough (``event_step_px``), an ideal event camera's counts times its threshold follow the truth
    log-intensity change over any window; six renders per frame interval at a tractor's speed (about 1 px of motion
    between renders) miss texture that crosses a pixel between two renders and fall far behind."""
    cfg = SynthConfig(scene="orchard", lighting="dusk", views=4, heldout=1, width=64, height=48, speed=2.0,
                      event_refractory_us=0, event_noise_hz=0.0, event_threshold_sigma=0.0, event_supersample=1,
                      event_step_px=0.1)  # fmt: skip
    fine_sq, fine_corr, substeps = _event_residual(cfg)
    coarse_sq, coarse_corr, _ = _event_residual(cfg.replace(event_substeps=6))
    assert substeps > 6
    assert fine_corr > 0.97 and fine_sq < 0.08, (fine_corr, fine_sq)
    assert coarse_sq > 2 * fine_sq and coarse_corr < fine_corr, (coarse_sq, fine_sq)


def test_event_pixels_integrate_over_their_area_so_the_refractory_period_keeps_the_counts() -> None:
    """With the default 1 ms refractory period, point-sampled event pixels see an edge as a jump whose events all fall
    inside one refractory period (most are lost); pixels that integrate over their area (``event_supersample``) see a
    ramp and keep most of them."""
    cfg = SynthConfig(scene="orchard", lighting="dusk", views=4, heldout=1, width=64, height=48, speed=2.0)
    area_sq, area_corr, _ = _event_residual(cfg)
    point_sq, point_corr, _ = _event_residual(cfg.replace(event_supersample=1))
    assert area_corr > point_corr + 0.05 and area_sq < 0.7 * point_sq, (area_corr, point_corr, area_sq, point_sq)
