"""The Event Camera Dataset importer on a fixture in that text layout (made here from the hand-made raw capture):
it converts to a raw capture with the ground truth interpolated at the frame times, which runs through
agrinerf-process --poses given; a folder missing a file is refused before anything is written."""

import json
import shutil
from pathlib import Path

import cv2
import h5py
import numpy as np
import pytest
from helpers.process_raw_fixture import RGB_K, make_raw_capture
from scipy.spatial.transform import Rotation

from agrinerf_ns.process import ProcessConfig, process_capture, readers
from agrinerf_ns.process.ecd import ECD_FILES, ecd_to_raw
from agrinerf_ns.process.poses import opencv_to_opengl
from agrinerf_ns.process.readers import RawInputError
from agrinerf_ns.trajectory import read_tum


def truth_pose(t: np.ndarray) -> np.ndarray:
    """A path with constant velocity and constant angular velocity about one axis (exact under lerp + slerp)."""
    c2w = np.tile(np.eye(4), (len(t), 1, 1))
    c2w[:, :3, :3] = Rotation.from_rotvec(np.outer(t, [0.0, 0.3, 0.1])).as_matrix()
    c2w[:, :3, 3] = np.outer(t, [0.5, 0.0, 0.1]) + [1.0, 2.0, 0.0]
    return c2w


def make_ecd(root: Path, n: int = 8) -> Path:
    raw = make_raw_capture(root / "src", n=n, with_thermal=False)
    ecd = root / "ecd"
    (ecd / "images").mkdir(parents=True)
    frames = readers.read_timestamps(raw / "rgb")
    lines = []
    for i, (path, t) in enumerate(zip(frames.paths, frames.times, strict=True)):
        gray = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2GRAY)
        cv2.imwrite(str(ecd / "images" / f"frame_{i:08d}.png"), gray)
        lines.append(f"{t:.6f} images/frame_{i:08d}.png")
    (ecd / "images.txt").write_text("\n".join(lines) + "\n")
    with h5py.File(raw / "events" / "events.h5") as f:
        x, y, t, p = (f["events"][k][:] for k in "xytp")
    (ecd / "events.txt").write_text(
        "".join(f"{a / 1e6:.6f} {b} {c} {d}\n" for a, b, c, d in zip(t, x, y, p, strict=True))
    )
    # ground truth at 200 Hz, ending before the last frame (which then has no pose)
    gt_t = np.arange(frames.times[0] - 0.05, frames.times[-1] - 0.02, 0.005)
    gt = truth_pose(gt_t)
    q = Rotation.from_matrix(gt[:, :3, :3]).as_quat()
    (ecd / "groundtruth.txt").write_text(
        "".join(
            " ".join(f"{v:.9f}" for v in (tt, *T[:3, 3], *qq)) + "\n" for tt, T, qq in zip(gt_t, gt, q, strict=True)
        )
    )
    K = RGB_K
    (ecd / "calib.txt").write_text(f"{K[0, 0]} {K[1, 1]} {K[0, 2]} {K[1, 2]} 0.01 -0.002 0.0 0.0 0.0\n")
    return ecd


def test_ecd_folder_runs_through_agrinerf_process(tmp_path: Path):
    ecd = make_ecd(tmp_path)
    raw = ecd_to_raw(ecd, tmp_path / "raw")
    calib = readers.read_calibration(raw / "calib.yaml")
    assert (calib.rgb.width, calib.rgb.height) == (64, 48) and calib.event is not None
    np.testing.assert_allclose(calib.rgb.dist, [0.01, -0.002, 0, 0])
    times = readers.read_timestamps(raw / "rgb").times
    t_odo, c2w = read_tum(raw / "odometry.txt")
    assert len(t_odo) == len(times) - 1  # the last frame is after the ground truth
    np.testing.assert_allclose(c2w, truth_pose(t_odo), atol=1e-6)
    src = [readers.iter_event_chunks(ecd / "events.txt"), readers.iter_event_chunks(raw / "events" / "events.h5")]
    a, b = (np.concatenate([np.stack([c.x, c.y, c.t, c.p], 1) for c in it]) for it in src)
    np.testing.assert_array_equal(a, b)

    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False))
    meta = json.loads((out / "transforms.json").read_text())
    assert meta["agrinerf"]["modalities"] == ["rgb", "events"]
    assert len(meta["frames"]) == len(times) - 1
    assert [d["reason"] for d in meta["agrinerf"]["poses"]["dropped_frames"]] == ["no pose"]
    got = np.array([f["transform_matrix"] for f in meta["frames"]])
    np.testing.assert_allclose(got, opencv_to_opengl(truth_pose(t_odo)), atol=1e-6)


@pytest.mark.parametrize("missing", ECD_FILES)
def test_ecd_folder_missing_a_file_is_refused(missing: str, tmp_path: Path):
    ecd = make_ecd(tmp_path, n=3)
    target = ecd / missing
    shutil.rmtree(target) if target.is_dir() else target.unlink()
    with pytest.raises(RawInputError, match=rf"{missing}: missing \(an ECD folder has"):
        ecd_to_raw(ecd, tmp_path / "raw")
    assert not (tmp_path / "raw").exists() and not list(tmp_path.glob(".raw.tmp-*"))


def test_ecd_bad_calibration_and_events_leave_nothing(tmp_path: Path):
    ecd = make_ecd(tmp_path, n=3)
    (ecd / "calib.txt").write_text("80 80 31.5 23.5 0 0 0 0 0.3\n")
    with pytest.raises(RawInputError, match=r"calib\.txt: k3 = 0\.3 is not supported"):
        ecd_to_raw(ecd, tmp_path / "raw")
    (ecd / "calib.txt").write_text("80 80 31.5 23.5 0 0 0 0 0\n")
    (ecd / "events.txt").write_text("0.1 10 10 1\n0.2 99 10 1\n")  # x = 99 outside the 64x48 frames
    with pytest.raises(RawInputError, match=r"events\.txt: event 1 at \(x=99, y=10\) is outside the 64x48 sensor"):
        ecd_to_raw(ecd, tmp_path / "raw")
    assert not (tmp_path / "raw").exists() and not list(tmp_path.glob(".raw.tmp-*"))
