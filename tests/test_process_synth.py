"""The tiny agrinerf-synth scene through agrinerf-process (--poses given): alignment measured against the truth,
and stock `ns-train nerfacto` on the thermal transforms file."""

import json
from pathlib import Path

import numpy as np
import pytest

from agrinerf_ns.process import ProcessConfig, align, process_capture, readers  # noqa: F401
from agrinerf_ns.process.evaluate import alignment_report, pose_report, visible_fruit_depth
from agrinerf_ns.process.poses import match_times
from agrinerf_ns.synth import SynthConfig, generate_capture
from agrinerf_ns.trajectory import read_tum


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
    from agrinerf_ns.ns_commands import ns_train

    _, out = tiny
    run = ns_train(
        "nerfacto", out / "transforms_thermal.json", tmp_path / "outputs", "thermal", max_steps=2, rays_per_batch=128
    )
    ckpts = list((run.config.parent / "nerfstudio_models").glob("*.ckpt"))
    assert ckpts, "ns-train wrote a checkpoint"


def test_visible_fruit_depth_agrees_with_the_fruit_centres(tiny):
    raw, _ = tiny
    coco = json.loads((raw / "truth" / "boxes_coco.json").read_text())
    fruits = {f["id"]: f for f in json.loads((raw / "truth" / "fruits.json").read_text())}
    depth = visible_fruit_depth(raw, min_pixels=3)
    counted = [a for a in coco["annotations"] if a["area"] >= 3]
    assert depth["count"] == len(counted) > 5
    assert depth["p25"] <= depth["median"] <= depth["p75"]
    # independently: each counted fruit's centre in its frame's camera, minus its radius (the visible near side)
    times = readers.read_timestamps(raw / "rgb").times
    t, c2w = read_tum(raw / "truth" / "poses.txt")
    frame_pose = {i: c2w[j] for i, j in enumerate(match_times(times, t, 1e-3))}
    near_side = []
    for a in counted:
        fruit = fruits[a["fruit_id"]]
        w2c = np.linalg.inv(frame_pose[a["image_id"]])
        centre = w2c[:3, :3] @ np.asarray(fruit["center"]) + w2c[:3, 3]
        near_side.append(centre[2] - min(fruit["radii"]))
    assert abs(depth["median"] - float(np.median(near_side))) < 0.05, (depth, np.median(near_side))
    assert visible_fruit_depth(raw, min_pixels=10**9)["count"] == 0


def test_exposures_times_and_trajectory_reach_the_dataparser(tiny):
    import torch

    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
    from agrinerf_ns.trajectory import exposure_subtimes

    raw, out = tiny
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["exposure"]["source"] == "rgb/exposures.txt"
    assert meta["agrinerf"]["trajectory"] == {"file": "trajectory.txt", "source": "odometry.txt", "samples": 8}
    rows = {r.split()[0]: (float(r.split()[1]), float(r.split()[2]))
            for r in (raw / "rgb" / "exposures.txt").read_text().splitlines()}  # fmt: skip
    for f in meta["frames"]:
        assert (f["exposure_start"], f["exposure_end"]) == rows[Path(f["raw_rgb"]).name]
        assert f["exposure_start"] < f["timestamp"] < f["exposure_end"]
    by_image = {out / f["file_path"]: f for f in meta["frames"]}

    parser = AgriNeRFDataParserConfig(data=out).setup()
    for split in ("train", "test"):
        outputs = parser.get_dataparser_outputs(split)
        md = outputs.metadata
        kept = [by_image[p] for p in outputs.image_filenames]
        n = len(kept)
        assert md["times"].dtype == md["exposure"].dtype == torch.float64
        assert md["times"].shape == (n,) and md["exposure"].shape == (n, 2)
        np.testing.assert_array_equal(md["times"].numpy(), [f["timestamp"] for f in kept])
        np.testing.assert_array_equal(md["exposure"].numpy(), [[f["exposure_start"], f["exposure_end"]] for f in kept])
        # the trajectory (the odometry, in the dataparser's frame and scale) gives each camera at its own time ...
        traj = md["trajectory"]
        c2w = outputs.cameras.camera_to_worlds.double()
        np.testing.assert_allclose(traj.poses_at(md["times"].numpy()), c2w.numpy(), atol=1e-5)
        # ... and sub-poses across each exposure, between the neighbouring frames' poses
        sub = traj.poses_at_tensor(torch.from_numpy(exposure_subtimes(md["exposure"].numpy(), 5)))
        assert sub.shape == (n, 5, 3, 4) and torch.isfinite(sub).all()
        step = (sub[:, -1, :, 3] - sub[:, 0, :, 3]).norm(dim=-1)
        gap = (c2w[1:, :, 3] - c2w[:-1, :, 3]).norm(dim=-1).min() if n > 1 else 1.0
        assert (step > 0).all() and (step < gap).all()


def test_well_seen_fruit_measures_each_fruit_against_its_own_disc(tmp_path):
    from dataclasses import replace

    from agrinerf_ns.count.fruit_score import disc_shares, read_truth_fruit, visible_fruit, well_seen_fruit

    raw = tmp_path / "raw"  # a narrow view, so that fruit span many pixels and a disc's area is not a pixel count's
    generate_capture(replace(SynthConfig.tiny(), rgb_hfov_deg=20.0, thermal_hfov_deg=20.0), raw)
    truth = read_truth_fruit(raw)
    stems = sorted(p.stem for p in (raw / "truth" / "fruit_ids").glob("*.png"))
    k = readers.read_calibration(raw / "calib.yaml").rgb.K
    shares = [s for stem in stems for s in disc_shares(raw, stem, truth, 0.5 * (k[0, 0] + k[1, 1])).values()]
    # a fruit never shows more than its disc: radius, depth and focal length are in matching units (a diameter taken
    # for a radius would put the largest share near 4 or 0.25)
    assert 0.4 < max(shares) < 1.6, sorted(shares)[-5:]
    # at a zero share and one view the well-seen fruit are the visible ones; the bar only removes fruit
    assert (well_seen_fruit(raw, stems, truth, 0.0, 1) == visible_fruit(raw, stems, truth, 1)).all()
    loose, strict = well_seen_fruit(raw, stems, truth, 0.1, 1), well_seen_fruit(raw, stems, truth, 0.5, 2)
    assert strict.sum() < loose.sum() and not (strict & ~loose).any()
    assert not well_seen_fruit(raw, stems, truth, 10.0, 1).any()
