"""pycolmap SfM on synthetic captures: registration, auto's choice, pose error against truth after a similarity.

The default-scene figures (40 frames, 160x120) are in docs/process.md; here a small bright scene (RGB SfM) and the
default dark scene at 20 frames (auto must fall back to thermal) run for real.
"""

import json
from pathlib import Path

import numpy as np
import pytest
from helpers.bench_script import load_bench_script

from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.evaluate import pose_report
from agrinerf_ns.process.poses import apply_similarity, camera_similarity, opencv_to_opengl, pose_errors, umeyama
from agrinerf_ns.synth import SynthConfig, generate_capture


def test_umeyama_and_pose_errors_recover_a_similarity():
    rng = np.random.default_rng(0)
    true = np.tile(np.eye(4), (10, 1, 1))
    true[:, :3, 3] = np.c_[np.linspace(0, 3, 10), rng.normal(0, 0.02, 10), np.zeros(10)]  # nearly a line
    for i in range(10):
        true[i, :3, :3] = np.linalg.qr(rng.normal(size=(3, 3)))[0] * [1, 1, 1]
        if np.linalg.det(true[i, :3, :3]) < 0:
            true[i, :3, 0] *= -1
    R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
    R *= np.sign(np.linalg.det(R))
    s, t = 0.3, np.array([1.0, -2.0, 0.5])
    est = true.copy()
    est[:, :3, :3] = R @ true[:, :3, :3]
    est[:, :3, 3] = (s * (R @ true[:, :3, 3].T)).T + t
    s2, R2, t2 = umeyama(est[:, :3, 3], true[:, :3, 3])
    assert s2 == pytest.approx(1 / s, rel=1e-6)
    err = pose_errors(est, true)
    assert err["rotation_deg_max"] < 1e-5 and err["translation_max"] < 1e-6
    np.testing.assert_allclose(opencv_to_opengl(opencv_to_opengl(est)), est)


def test_camera_similarity_recovers_the_roll_about_a_straight_path():
    """Cameras on an exact line: their centres leave the rotation about the line free, their orientations do not."""
    rng = np.random.default_rng(1)
    true = np.tile(np.eye(4), (8, 1, 1))
    true[:, :3, 3] = np.c_[np.linspace(0, 2, 8), np.zeros(8), np.zeros(8)]
    for i in range(8):
        q = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        true[i, :3, :3] = q * np.sign(np.linalg.det(q))
    roll = np.radians(20.0)
    R = np.array([[1.0, 0.0, 0.0], [0.0, np.cos(roll), -np.sin(roll)], [0.0, np.sin(roll), np.cos(roll)]])
    est = apply_similarity(true, 0.4, R, np.array([0.3, -1.0, 2.0]))
    scale, rot, t, rms = camera_similarity(est, true)
    back = apply_similarity(est, scale, rot, t)
    assert scale == pytest.approx(2.5, rel=1e-9) and rms < 1e-9
    np.testing.assert_allclose(back, true, atol=1e-9)


@pytest.mark.slow
def test_sfm_rgb_registers_small_bright_scene(tmp_path: Path):
    raw = tmp_path / "raw"
    generate_capture(SynthConfig.tiny(lighting="bright", views=12, width=96, height=72), raw)
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="sfm-rgb", show_progress=False))
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["poses"]["source"] == "sfm-rgb"
    assert len(meta["frames"]) >= 11  # >= 90 %
    err = pose_report(raw, out)
    path_len = 0.75 / 10 * 11  # speed x frame interval x intervals
    assert err["rotation_deg_mean"] < 2.0 and err["translation_mean"] < 0.05 * path_len, err


@pytest.mark.slow
def test_auto_picks_thermal_on_the_default_dark_scene(tmp_path: Path):
    """The default dark scene at half its length (20 of 40 frames, to keep the suite short; the 40-frame
    figures are in docs/process.md)."""
    raw = tmp_path / "raw"
    generate_capture(SynthConfig(lighting="dark", views=20, heldout=2), raw)
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="auto", show_progress=False))
    meta = json.loads((out / "transforms.json").read_text())
    poses = meta["agrinerf"]["poses"]
    assert poses["source"] == "sfm-thermal", poses
    assert poses["registered"]["sfm-thermal"] > poses["registered"]["sfm-rgb"]
    assert len(meta["frames"]) >= 18  # >= 90 %
    err = pose_report(raw, out)
    assert err["rotation_deg_mean"] < 3.0 and err["translation_mean"] < 0.1, err


def test_auto_matching_is_exhaustive_for_short_sequences_only():
    from agrinerf_ns.process.poses import SfmConfig, sfm_matching

    cfg = SfmConfig()
    assert sfm_matching(cfg, cfg.exhaustive_max_frames) == "exhaustive"
    assert sfm_matching(cfg, cfg.exhaustive_max_frames + 1) == "sequential"
    assert sfm_matching(SfmConfig(matching="sequential"), 3) == "sequential"


@pytest.mark.slow
def test_sfm_scaling_benchmark_with_sequential_matching(tmp_path: Path):
    """The scaling benchmark at toy sizes: sequential matching registers >= 90 % of each sequence with small pose
    error with the incremental and the global mapper, and the table and plot are written."""
    import dataclasses

    bench = load_bench_script("bench_sfm_scaling")
    args = bench.Args(
        out=tmp_path / "out",
        work=tmp_path / "work",
        sizes=(12, 24),
        modes=("sequential",),
        sfm_overrides={"sequential_overlap": 5},
    )
    rows = bench.main(args)
    assert [r["frames"] for r in rows] == [12, 24]
    for r in rows:
        assert r["registered_frac"] >= 0.9 and r["rotation_deg_mean"] < 3.0 and r["translation_mean_frac"] < 0.05, r
    assert "| 24 | sequential |" in (tmp_path / "out" / "results.md").read_text()
    assert (tmp_path / "out" / "scaling.png").stat().st_size > 0
    # pycolmap's global mapper (GLOMAP) on the same frames
    glob = bench.main(dataclasses.replace(args, out=tmp_path / "out_global", sizes=(12,), mapper="global"))
    assert glob[0]["mapper"] == "global" and glob[0]["registered_frac"] >= 0.9, glob
    assert glob[0]["rotation_deg_mean"] < 3.0 and glob[0]["translation_mean_frac"] < 0.05, glob


@pytest.mark.slow
def test_sfm_on_odometry_keeps_the_odometry_frame_and_metres_and_falls_back_when_sfm_drifts(tmp_path: Path):
    raw = tmp_path / "raw"
    generate_capture(SynthConfig.tiny(lighting="bright", views=12, width=96, height=72), raw)
    odometry = {round(float(line.split()[0]), 4): np.array(line.split()[1:4], float)
                for line in (raw / "odometry.txt").read_text().splitlines() if line.strip()}  # fmt: skip
    for limit, kept in ((1e9, "sfm"), (0.0, "odometry")):  # any disagreement allowed; none
        config = ProcessConfig(poses="sfm-on-odometry", sfm_max_disagreement_deg=limit, show_progress=False)
        out = process_capture(raw, tmp_path / f"ds_{kept}", config)
        meta = json.loads((out / "transforms.json").read_text())
        poses = meta["agrinerf"]["poses"]
        assert poses["odometry"]["kept"] == kept and poses["odometry"]["frames"] >= 11
        assert poses["source"] == ("sfm-on-odometry" if kept == "sfm" else "given")
        assert meta["agrinerf"]["trajectory"]["source"] == "odometry.txt"  # the odometry shares the poses' frame
        centres = np.array([np.asarray(f["transform_matrix"])[:3, 3] for f in meta["frames"]])
        near = np.array([odometry[round(f["timestamp"], 4)] for f in meta["frames"]])
        off = np.sqrt(np.mean(np.sum((centres - near) ** 2, axis=1)))
        assert off < (0.03 if kept == "sfm" else 1e-5)  # metres, in the odometry's frame; its very poses
    (raw / "odometry.txt").unlink()
    with pytest.raises(RawInputError, match="odometry.txt: missing; --poses sfm-on-odometry"):
        process_capture(raw, tmp_path / "ds2", ProcessConfig(poses="sfm-on-odometry", show_progress=False))
    assert not (tmp_path / "ds2").exists()


@pytest.mark.slow
def test_sfm_on_odometry_keeps_the_odometry_where_sfm_cannot_place_dark_frames(tmp_path: Path):
    raw = tmp_path / "raw"
    generate_capture(SynthConfig.tiny(lighting="dark", views=12, width=96, height=72), raw)
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="sfm-on-odometry", show_progress=False))
    meta = json.loads((out / "transforms.json").read_text())["agrinerf"]
    poses = meta["poses"]
    assert poses["source"] == "given" and poses["odometry"]["kept"] == "odometry"
    assert poses["odometry"]["why"].startswith("SfM registered") and poses["registered"]["sfm-rgb"] < 6, poses
    given = json.loads(
        (
            process_capture(raw, tmp_path / "given", ProcessConfig(poses="given", show_progress=False))
            / "transforms.json"
        ).read_text()
    )
    assert [f["transform_matrix"] for f in json.loads((out / "transforms.json").read_text())["frames"]] == [
        f["transform_matrix"] for f in given["frames"]
    ]
