"""The tiny agrinerf-synth scene through agrinerf-process (--poses given): alignment measured against the truth,
and stock `ns-train nerfacto` on the thermal transforms file."""

import json
from pathlib import Path

import pytest

from agrinerf_ns.process import ProcessConfig, align, process_capture, readers  # noqa: F401
from agrinerf_ns.process.evaluate import alignment_report, pose_report
from agrinerf_ns.synth import SynthConfig, generate_capture


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    raw = root / "raw"
    generate_capture(SynthConfig.tiny(), raw)
    out = process_capture(raw, root / "orchard", ProcessConfig(poses="given", show_progress=False))
    return raw, out


def test_fruit_centres_reproject_within_the_parallax_bound(tiny):
    raw, out = tiny
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb", "thermal", "events"]
    report = alignment_report(raw, float("inf"))
    calib = readers.read_calibration(raw / "calib.yaml")
    for name, cam in (("thermal", calib.thermal), ("event", calib.event)):
        r = report[name]
        assert r["count"] > 100
        # a few pixels at the default depth (inf): bounded by the parallax of the nearest fruit in view (~2 m)
        assert r["mean_px"] < 2.0 and r["max_px"] <= align.parallax_bound(calib.rgb, cam, 2.0) + 0.5, r
    # at a plane near the fruit the error drops
    near = alignment_report(raw, report["thermal"]["median_fruit_depth_m"])
    assert near["thermal"]["median_px"] < report["thermal"]["median_px"]


def test_given_poses_match_truth(tiny):
    raw, out = tiny
    err = pose_report(raw, out)
    assert err["frames"] == 8
    # odometry = truth + drift + noise (synth): small but non-zero
    assert 0 < err["rotation_deg_mean"] < 2.0 and err["translation_mean"] < 0.05, err


@pytest.mark.slow
def test_ns_train_nerfacto_on_thermal_transforms(tiny, tmp_path: Path):
    from agrinerf_ns.bench.ns_commands import ns_train

    _, out = tiny
    run = ns_train("nerfacto", out / "transforms_thermal.json", tmp_path / "outputs", "thermal", max_steps=2,
                   rays_per_batch=128)
    ckpts = list((run.config.parent / "nerfstudio_models").glob("*.ckpt"))
    assert ckpts, "ns-train wrote a checkpoint"
