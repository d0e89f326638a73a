"""agrinerf-synth motion blur: exposure intervals in the raw capture, blur length, sub-frames, sharp truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from agrinerf_ns.synth import SynthConfig, SynthConfigError, generate_capture
from agrinerf_ns.synth.camera_rig import frame_times
from agrinerf_ns.synth.capture import make_scene
from agrinerf_ns.synth.motion_blur import blur_lengths_px, exposure_average, subframe_count
from agrinerf_ns.synth.raycast import cast
from agrinerf_ns.synth.scene import LIGHTING_PRESETS


def test_subframe_count_keeps_sub_frames_within_the_step() -> None:
    assert subframe_count(0.0, 1.0, 63) == 1
    assert subframe_count(0.9, 1.0, 63) == 1
    assert subframe_count(2.0, 1.0, 63) == 3
    assert subframe_count(3.7, 1.0, 63) == 5
    assert subframe_count(3.7, 0.5, 63) == 9
    assert subframe_count(1e4, 1.0, 63) == 63
    for blur in np.linspace(0.1, 20, 57):
        k = subframe_count(float(blur), 0.75, 63)
        assert k % 2 == 1 and blur / k <= 0.75 + 1e-9


def test_exposure_average_is_a_box_filter_over_the_interval() -> None:
    sharp = np.full((2, 3, 3), 1.0)
    times = []

    def render(t: float) -> np.ndarray:
        times.append(t)
        return np.full((2, 3, 3), t)

    out = exposure_average(render, sharp, 1.0, 0.1, 5)
    np.testing.assert_allclose(sorted(times), [0.96, 0.98, 1.02, 1.04])  # the middle sub-frame is the sharp render
    np.testing.assert_allclose(out, 1.0)
    assert exposure_average(render, sharp, 1.0, 0.0, 5) is sharp


def test_blur_length_is_the_parallax_of_the_rig_motion() -> None:
    config = SynthConfig.tiny(scene="garden", width=96, height=72)
    scene, rig = make_scene(config)
    cam, t, e = rig.cams["rgb"], float(frame_times(config)[3]), 0.08
    hits = cast(scene.prims, cam, rig.pose(t))
    blur = blur_lengths_px(cam, hits, rig.pose(t - e / 2), rig.pose(t + e / 2))
    near = np.isfinite(hits.zdepth)
    expected = cam.fx * config.speed * e / hits.zdepth[near]  # sideways translation at 0.75 m/s, seen at depth z
    ratio = blur[near] / expected
    assert 0.85 < np.median(ratio) < 1.15, np.median(ratio)
    assert np.median(blur[near]) > 2.0  # several pixels: the garden at 1.3-2 m, 96 px wide


@pytest.fixture(scope="module")
def pair(tmp_path_factory: pytest.TempPathFactory) -> tuple:
    root = tmp_path_factory.mktemp("blur")
    cfg = SynthConfig.tiny(scene="garden", lighting="bright", width=96, height=72, views=3, heldout=1,
                           event_substeps=2, exposure_s=0.08)  # fmt: skip
    return cfg, generate_capture(cfg, root / "blur"), generate_capture(cfg.replace(motion_blur=False), root / "sharp")


def _grad_energy(img: np.ndarray) -> tuple:
    g = img.astype(np.float64).mean(-1)
    return float(np.abs(np.diff(g, axis=1)).mean()), float(np.abs(np.diff(g, axis=0)).mean())


def test_blurred_frames_smear_along_the_motion_and_the_truth_stays_sharp(pair: tuple) -> None:
    cfg, blur, sharp = pair
    scene_json = json.loads((blur / "truth" / "scene.json").read_text())["rgb_motion_blur"]
    assert scene_json["enabled"] and scene_json["exposure_s"] == pytest.approx(0.08)
    assert all(k >= 3 and k % 2 == 1 for k in scene_json["subframes"])
    assert scene_json["blur_px_median"] > 2.0
    assert json.loads((sharp / "truth" / "scene.json").read_text())["rgb_motion_blur"]["subframes"] == [1, 1, 1]
    for i in range(cfg.views):
        name = f"{i:06d}.png"
        assert (blur / "truth" / "rgb_clean" / name).read_bytes() == (sharp / "truth" / "rgb_clean" / name).read_bytes()
        gx_b, gy_b = _grad_energy(np.asarray(Image.open(blur / "rgb" / name)))
        gx_s, gy_s = _grad_energy(np.asarray(Image.open(sharp / "rgb" / name)))
        # the rig moves along the image's x axis: horizontal detail goes, vertical detail mostly stays
        assert gx_b < 0.75 * gx_s, (gx_b, gx_s)
        assert gx_b / gx_s < gy_b / gy_s - 0.1, (gx_b / gx_s, gy_b / gy_s)


def test_exposure_intervals_in_the_raw_capture(pair: tuple) -> None:
    cfg, blur, sharp = pair
    t = frame_times(cfg)
    for folder, e in ((blur, 0.08), (sharp, 0.0)):
        rows = [ln.split() for ln in (folder / "rgb" / "exposures.txt").read_text().splitlines()]
        assert [r[0] for r in rows] == [f"{i:06d}.png" for i in range(cfg.views)]
        se = np.array([[float(r[1]), float(r[2])] for r in rows])
        np.testing.assert_allclose(se, np.stack([t - e / 2, t + e / 2], -1), atol=1e-6)


def test_dim_lightings_get_long_exposures_capped_by_the_frame_rate() -> None:
    def exposure(**kw: object) -> float:
        cfg = SynthConfig(**kw)  # type: ignore[arg-type]
        return cfg.rgb_exposure_s(LIGHTING_PRESETS[cfg.lighting].exposure_s)

    assert exposure(lighting="bright") == pytest.approx(0.002)
    assert exposure(lighting="dusk") == pytest.approx(0.06)
    assert exposure(lighting="dark") == pytest.approx(0.095)  # 95 % of the 100 ms frame interval at 10 fps
    assert exposure(lighting="dark", fps=30.0) == pytest.approx(0.95 / 30)
    assert exposure(lighting="dark", motion_blur=False) == 0.0  # instantaneous frames
    assert exposure(lighting="dark", exposure_s=0.01) == 0.01
    with pytest.raises(SynthConfigError, match="exposure_s"):
        SynthConfig(exposure_s=0.2)
    with pytest.raises(SynthConfigError, match="blur_subframes"):
        SynthConfig(blur_subframes=0)


def test_fixed_sub_frames(tmp_path: Path) -> None:
    cfg = SynthConfig.tiny(views=2, heldout=0, event_substeps=1, lighting="dusk", blur_subframes=2)
    out = generate_capture(cfg, tmp_path / "raw")
    assert json.loads((out / "truth" / "scene.json").read_text())["rgb_motion_blur"]["subframes"] == [2, 2]
