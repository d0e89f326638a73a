"""agrinerf-synth: the raw folder's layout and formats, determinism, invalid arguments, CLI and preview."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import yaml
from PIL import Image

from agrinerf_ns.synth import SynthConfig, SynthConfigError, generate_capture
from agrinerf_ns.synth.preview import contact_sheet


@pytest.fixture(scope="module")
def tiny(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return generate_capture(SynthConfig.tiny(seed=5), tmp_path_factory.mktemp("synth") / "raw")


def _files(root: Path) -> dict:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def _tum(path: Path) -> np.ndarray:
    return np.loadtxt(path, ndmin=2)


def test_layout_and_formats(tiny: Path) -> None:
    cfg = SynthConfig.tiny()
    n = cfg.views
    names = [f"{i:06d}.png" for i in range(n)]
    for sub in ("rgb", "thermal", "truth/rgb_clean"):
        assert sorted(p.name for p in (tiny / sub).glob("*.png")) == names, sub
    rgb = Image.open(tiny / "rgb" / names[0])
    assert rgb.mode == "RGB" and rgb.size == (cfg.width, cfg.height)
    th = Image.open(tiny / "thermal" / names[0])
    assert th.mode == "I;16" and th.size == cfg.thermal_wh
    counts = np.asarray(th)
    assert 1500 < counts.min() and counts.max() < 9000  # raw radiometric-like counts, not an 8-bit image
    for sub in ("rgb", "thermal"):
        lines = (tiny / sub / "timestamps.txt").read_text().splitlines()
        assert [ln.split()[0] for ln in lines] == names
        t = np.array([float(ln.split()[1]) for ln in lines])
        assert np.all(np.diff(t) > 0)
    t_rgb = np.array([float(ln.split()[1]) for ln in (tiny / "rgb" / "timestamps.txt").read_text().splitlines()])
    np.testing.assert_allclose(np.diff(t_rgb), 1 / cfg.fps, atol=1e-6)

    with h5py.File(tiny / "events" / "events.h5", "r") as f:
        g = f["events"]
        assert g["x"].dtype == np.uint16 and g["y"].dtype == np.uint16
        assert g["t"].dtype == np.int64 and g["p"].dtype == np.uint8
        x, y, t, p = g["x"][:], g["y"][:], g["t"][:], g["p"][:]
    ew, eh = cfg.event_wh
    assert x.size > 1000 and x.max() < ew and y.max() < eh
    assert set(np.unique(p)) == {0, 1}
    assert np.all(np.diff(t) >= 0)
    assert t[0] >= (t_rgb[0] - 0.5 / cfg.fps) * 1e6 - 1 and t[-1] <= (t_rgb[-1] + 0.5 / cfg.fps) * 1e6 + 1

    calib = yaml.safe_load((tiny / "calib.yaml").read_text())
    assert [calib[c]["modality"] for c in ("cam0", "cam1", "cam2")] == ["rgb", "thermal", "event"]
    assert calib["cam0"]["resolution"] == [cfg.width, cfg.height]
    assert calib["cam1"]["resolution"] == list(cfg.thermal_wh)
    assert calib["cam2"]["resolution"] == list(cfg.event_wh)
    for c in ("cam1", "cam2"):
        T = np.array(calib[c]["T_cn_cnm1"])
        assert T.shape == (4, 4)
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
        assert 0.01 < np.linalg.norm(T[:3, 3]) < 0.3  # small rig offsets

    odo, truth = _tum(tiny / "odometry.txt"), _tum(tiny / "truth" / "poses.txt")
    assert odo.shape == truth.shape == (n, 8)
    np.testing.assert_allclose(odo[:, 0], t_rgb, atol=1e-6)
    err = np.linalg.norm(odo[:, 1:4] - truth[:, 1:4], axis=1)
    assert 0 < err.max() < 0.1  # drift and noise, but a usable odometry
    np.testing.assert_allclose(np.linalg.norm(truth[:, 4:], axis=1), 1.0, atol=1e-6)

    depth = np.load(tiny / "truth" / "depth" / "000000.npy")
    assert depth.dtype == np.float32 and depth.shape == (cfg.height, cfg.width)
    assert np.isinf(depth).any() and np.isfinite(depth).mean() > 0.5  # some sky, mostly scene
    held = sorted((tiny / "truth" / "heldout").glob("*.png"))
    assert len(held) == cfg.num_heldout
    assert _tum(tiny / "truth" / "heldout" / "poses.txt").shape == (cfg.num_heldout, 8)
    assert not list(tiny.parent.glob(".*synth-tmp*"))


def test_deterministic_by_seed(tiny: Path, tmp_path: Path) -> None:
    again = generate_capture(SynthConfig.tiny(seed=5), tmp_path / "again")
    a, b = _files(tiny), _files(again)
    assert a.keys() == b.keys()
    differing = [k for k in a if a[k] != b[k]]
    assert differing == []
    other = generate_capture(SynthConfig.tiny(seed=6), tmp_path / "other")
    c = _files(other)
    assert c["rgb/000000.png"] != a["rgb/000000.png"]
    assert c["events/events.h5"] != a["events/events.h5"]


@pytest.mark.parametrize(
    "changes, message",
    [
        (dict(views=0), "views"),
        (dict(width=-64), "resolution"),
        (dict(height=0), "resolution"),
        (dict(lighting="noon"), "lighting"),
        (dict(scene="vineyard"), "scene"),
        (dict(thermal_size=(4, 4)), "thermal"),
    ],
)
def test_invalid_arguments_write_nothing(tmp_path: Path, changes: dict, message: str) -> None:
    out = tmp_path / "raw"
    with pytest.raises(SynthConfigError, match=message):
        generate_capture(SynthConfig.tiny(**changes), out)
    assert list(tmp_path.iterdir()) == []


def test_non_empty_output_refused(tmp_path: Path) -> None:
    out = tmp_path / "raw"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    with pytest.raises(SynthConfigError, match="not empty"):
        generate_capture(SynthConfig.tiny(), out)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["raw"]


def test_cli_errors_and_preview(tmp_path: Path) -> None:
    env = dict(os.environ)
    cmd = [sys.executable, "-m", "agrinerf_ns.synth.cli"]
    tiny = ["--views", "3", "--width", "48", "--height", "36", "--heldout", "1", "--event-substeps", "2"]
    bad = subprocess.run(
        cmd + ["--out", str(tmp_path / "a"), "--lighting", "noon"], check=False, capture_output=True, text=True, env=env
    )
    assert bad.returncode != 0 and "noon" in bad.stderr
    bad = subprocess.run(
        cmd + ["--out", str(tmp_path / "a"), "--views", "0"], check=False, capture_output=True, text=True, env=env
    )
    assert bad.returncode == 2 and "views must be" in bad.stderr
    assert list(tmp_path.iterdir()) == []
    ok = subprocess.run(
        cmd + ["--out", str(tmp_path / "b"), "--preview", "--preview-rows", "2"] + tiny,
        check=False,
        capture_output=True,
        text=True,
        env=env,
    )
    assert ok.returncode == 0, ok.stderr
    sheet = Image.open(tmp_path / "b" / "preview.png")
    assert sheet.mode == "RGB" and sheet.height > 2 * 100
    assert np.asarray(sheet).std() > 20  # not a blank picture


def test_contact_sheet_rows(tiny: Path, tmp_path: Path) -> None:
    sheet = Image.open(contact_sheet(tiny, tmp_path / "sheet.png", rows=3, tile_height=60))
    assert sheet.height == 16 + 3 * 64


def test_garden_scene_and_motion_blur(tmp_path: Path) -> None:
    cfg = SynthConfig.tiny(scene="garden", lighting="dark", views=2, heldout=1, event_substeps=2, seed=1)
    sharp = generate_capture(cfg.replace(motion_blur=False), tmp_path / "sharp")
    depth = np.load(sharp / "truth" / "depth" / "000000.npy")
    assert np.isinf(depth).any() and np.isfinite(depth).mean() > 0.5
    assert np.nanmax(np.where(np.isfinite(depth), depth, np.nan)) < 15  # the hedge closes the view
    assert sum(len(p.read_text().splitlines()) for p in (sharp / "truth" / "boxes_yolo").glob("*.txt")) >= 2
    blurred = generate_capture(cfg, tmp_path / "blur")  # motion blur is on by default
    # same truth, different camera frames: the long dark exposure smears the noisy frame
    assert (blurred / "truth" / "rgb_clean" / "000001.png").read_bytes() == (
        sharp / "truth" / "rgb_clean" / "000001.png"
    ).read_bytes()
    a = np.asarray(Image.open(blurred / "rgb" / "000001.png")).astype(np.float64)
    b = np.asarray(Image.open(sharp / "rgb" / "000001.png")).astype(np.float64)
    assert not np.array_equal(a, b)


def test_a_narrower_field_of_view_shows_fruit_larger_and_a_bad_one_is_refused() -> None:
    """The count profile's fruit sizes come from the cameras' fields of view (docs/count.md)."""
    import pytest

    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.camera_rig import build_rig
    from agrinerf_ns.synth.config import SynthConfigError

    wide, narrow = build_rig(SynthConfig()), build_rig(SynthConfig(rgb_hfov_deg=22.0, thermal_hfov_deg=20.0))
    assert (
        narrow.cams["rgb"].fx > 3.0 * wide.cams["rgb"].fx and narrow.cams["thermal"].fx > 2.5 * wide.cams["thermal"].fx
    )
    for bad in (0.0, 180.0, float("nan")):
        with pytest.raises(SynthConfigError, match="rgb_hfov_deg"):
            SynthConfig(rgb_hfov_deg=bad).validate()
