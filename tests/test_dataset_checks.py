"""Datasets are checked before training: each bad ``transforms.json`` gets an AgriNeRFDataError naming the file
(and the frame) from the dataparser, and `ns-train agrinerf-lite` stops with it before the first step."""

from __future__ import annotations

import math
import os
import resource
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.dataset_fixtures import edit_transforms, write_tridata

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataError, AgriNeRFDataParserConfig


def _parse(root: Path) -> None:
    AgriNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split="train")


def _set_pose_entry(frame_index: int, row: int, col: int, value: float):
    def edit(meta: dict) -> None:
        meta["frames"][frame_index]["transform_matrix"][row][col] = value

    return edit


def test_truncated_json_names_the_file_line_and_column(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, num_frames=4)
    path = root / "transforms.json"
    text = path.read_text()
    path.write_text(text[: len(text) // 2])
    with pytest.raises(
        AgriNeRFDataError, match=r"transforms\.json: not valid JSON: it ends early, at line \d+, column \d+"
    ):
        _parse(root)


@pytest.mark.parametrize("value", [math.nan, math.inf], ids=["nan", "inf"])
def test_non_finite_pose_names_the_file_and_frame(tmp_path: Path, value: float) -> None:
    root = write_tridata(tmp_path, num_frames=4)
    edit_transforms(root, _set_pose_entry(2, 1, 3, value))  # json writes NaN / Infinity, which json reads back
    with pytest.raises(AgriNeRFDataError, match=r"transforms\.json: frame images/frame_00002\.png: .*non-finite"):
        _parse(root)


@pytest.mark.parametrize(
    "edit",
    [
        lambda m: m["frames"][1].update(transform_matrix=[[2 * v for v in r[:3]] + r[3:] for r in m["frames"][1]["transform_matrix"]]),
        lambda m: m["frames"][1]["transform_matrix"].__setitem__(3, [0.0, 0.0, 0.5, 1.0]),
        lambda m: m["frames"][1].update(transform_matrix=[[-v for v in r[:3]] + r[3:] for r in m["frames"][1]["transform_matrix"]]),
    ],
    ids=["scaled", "bottom-row", "reflection"],
)  # fmt: skip
def test_non_rigid_pose_names_the_frame(tmp_path: Path, edit) -> None:
    root = write_tridata(tmp_path, num_frames=4)
    edit_transforms(root, edit)
    with pytest.raises(AgriNeRFDataError, match=r"frame images/frame_00001\.png: 'transform_matrix' is not a rigid"):
        _parse(root)


def test_missing_rgb_image_names_the_file_and_frame(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, num_frames=4)
    (root / "images" / "frame_00003.png").unlink()
    with pytest.raises(
        AgriNeRFDataError,
        match=r"images/frame_00003\.png: file named by 'file_path' in .*transforms\.json does not exist",
    ):
        _parse(root)


def test_rgb_image_size_differs_from_w_h(tmp_path: Path) -> None:
    root = write_tridata(tmp_path, num_frames=4)
    edit_transforms(root, lambda m: m.update(w=m["w"] + 2))
    with pytest.raises(
        AgriNeRFDataError,
        match=r"images/frame_00000\.png: image is 64x48 but .*transforms\.json gives its frame w x h = 66x48",
    ):
        _parse(root)


@pytest.mark.parametrize(("key", "value"), [("fl_x", 0.0), ("fl_y", -3.0), ("cx", math.nan)])
def test_bad_intrinsics_name_the_key(tmp_path: Path, key: str, value: float) -> None:
    root = write_tridata(tmp_path, num_frames=4)
    edit_transforms(root, lambda m: m.update({key: value}))
    with pytest.raises(AgriNeRFDataError, match=rf"transforms\.json: frame images/frame_00000\.png: intrinsic '{key}'"):
        _parse(root)


@pytest.mark.slow
def test_ns_train_stops_on_a_nan_pose_before_training(tmp_path: Path) -> None:
    """As a user would run it: `ns-train agrinerf-lite --data DS` on a dataset with one NaN pose exits non-zero with
    the file and frame in its output, writes no checkpoint and spends little more than its imports' CPU time."""
    root = write_tridata(tmp_path / "scene", num_frames=6)
    edit_transforms(root, _set_pose_entry(4, 0, 0, math.nan))
    command = [
        str(Path(sys.executable).parent / "ns-train"), "agrinerf-lite", "--data", str(root),
        "--max-num-iterations", "5", "--output-dir", str(tmp_path / "outputs"), "--vis", "tensorboard",
        "--machine.device-type", "cpu", "--timestamp", "run",
    ]  # fmt: skip
    env = {**os.environ, "CUDA_VISIBLE_DEVICES": "", "COLUMNS": "200"}
    cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
    done = subprocess.run(
        command, check=False, env=env, capture_output=True, text=True, timeout=900, stdin=subprocess.DEVNULL
    )
    cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu_s = (cpu_after.ru_utime - cpu_before.ru_utime) + (cpu_after.ru_stime - cpu_before.ru_stime)
    output = done.stdout + done.stderr
    assert done.returncode != 0, output[-3000:]
    assert "error: " in output and "Traceback" not in output, output[
        -3000:
    ]  # one message (agrinerf_ns.dataparsers.user_errors)
    assert f"{root / 'transforms.json'}: frame images/frame_00004.png: 'transform_matrix' has non-finite" in output
    assert not list((tmp_path / "outputs").rglob("step-*.ckpt"))
    # quickly: the command's CPU time (wall time depends on the machine's other load) is about its imports
    assert cpu_s < 90, f"ns-train used {cpu_s:.0f} s of CPU before stopping"
