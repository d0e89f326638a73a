"""A user's broken dataset is refused before training with one message that names the file and the fault, no
traceback (``AGRINERF_DEBUG=1`` keeps it), and no run folder left behind (``dataparsers/user_errors.py``)."""

from __future__ import annotations

import copy
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from helpers.dataset_fixtures import edit_transforms, write_tridata
from helpers.fruit_masks import add_fruit_masks
from PIL import Image

from agrinerf_ns.dataparsers import user_errors
from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataError, AgriNeRFDataParserConfig


def _cut(path: Path, size: int = 100) -> None:
    path.write_bytes(path.read_bytes()[:size])


def _truncated_rgb(root: Path) -> str:
    _cut(root / "images" / "frame_00002.png")
    return r"images/frame_00002\.png: the image named by 'file_path' in .*transforms\.json is truncated or corrupt"


def _truncated_fruit_mask(root: Path) -> str:
    add_fruit_masks(root)
    _cut(root / "fruit_masks" / "frame_00001.png")
    return r"fruit_masks/frame_00001\.png: the image named by 'fruit_mask_file_path' in .* is truncated or corrupt"


def _wrong_size_thermal(root: Path) -> str:
    Image.new("L", (32, 24)).save(root / "thermal" / "frame_00003.png")
    return r"thermal/frame_00003\.png: image is 32x24 but its RGB frame images/frame_00003\.png is 64x48"


def _json_syntax_error(root: Path) -> str:
    path = root / "transforms.json"
    path.write_text(path.read_text().replace('"frames":', '"frames"', 1))  # a missing colon, not a cut
    return r"transforms\.json: not valid JSON: syntax error at line \d+, column \d+: Expecting ':' delimiter"


def _truncated_json(root: Path) -> str:
    path = root / "transforms.json"
    path.write_text(path.read_text()[:300])
    return r"transforms\.json: not valid JSON: it ends early, at line \d+, column \d+ .*: the file is truncated"


FAULTS = {
    "truncated-rgb": _truncated_rgb,
    "truncated-fruit-mask": _truncated_fruit_mask,
    "wrong-size-thermal": _wrong_size_thermal,
    "json-syntax-error": _json_syntax_error,
    "truncated-json": _truncated_json,
}


@pytest.mark.parametrize("fault", FAULTS)
def test_dataparser_names_the_file_and_the_fault(tmp_path: Path, fault: str) -> None:
    root = write_tridata(tmp_path / "scene", num_frames=5)
    expected = FAULTS[fault](root)
    with pytest.raises(AgriNeRFDataError, match=expected):
        AgriNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split="train")


def test_a_whole_dataset_passes_and_a_cut_tail_is_caught(tmp_path: Path) -> None:
    """The check passes whole files and catches a PNG cut anywhere, even in its last bytes (IEND)."""
    root = write_tridata(tmp_path / "scene", num_frames=5)
    AgriNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split="train")
    path = root / "event_masks" / "frame_00004.png"
    path.write_bytes(path.read_bytes()[:-4])
    with pytest.raises(AgriNeRFDataError, match=r"event_masks/frame_00004\.png: .*'event_mask_path'.* truncated"):
        AgriNeRFDataParserConfig(data=root).setup().get_dataparser_outputs(split="train")


def _train_config(data: Path, outputs: Path):
    """``ns-train agrinerf-lite --data DATA`` as its parser makes it (headless, CPU, one step)."""
    from nerfstudio.configs.method_configs import all_methods

    config = copy.deepcopy(all_methods["agrinerf-lite"])
    config.data, config.output_dir, config.vis, config.timestamp = data, outputs, "tensorboard", "run"
    config.machine.device_type, config.max_num_iterations = "cpu", 1
    return config


def _report(error: BaseException, capsys: pytest.CaptureFixture) -> str:
    """What the hook prints for ``error`` (alone: what the command printed before is read off first)."""
    capsys.readouterr()
    user_errors.report(type(error), error, error.__traceback__)
    captured = capsys.readouterr()
    return captured.out + captured.err


@pytest.mark.parametrize("fault", ["truncated-rgb", "truncated-fruit-mask", "wrong-size-thermal", "json-syntax-error"])
def test_ns_train_refuses_before_writing_anything(
    tmp_path: Path, fault: str, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """ns-train's own main on a broken dataset: the check runs before the config is printed and the run folder made;
    the hook prints one line naming the file and the fault."""
    from nerfstudio.scripts import train

    monkeypatch.delenv(user_errors.DEBUG_ENV, raising=False)
    assert user_errors.install()
    root = write_tridata(tmp_path / "scene", num_frames=5)
    expected = FAULTS[fault](root)
    with pytest.raises(AgriNeRFDataError) as caught:
        train.main(_train_config(root, tmp_path / "outputs"))
    output = _report(caught.value, capsys)
    lines = [line for line in output.splitlines() if line.strip()]
    assert len(lines) == 2 and lines[0].startswith("error: "), output  # the message, and how to get the traceback
    assert user_errors.DEBUG_ENV in lines[1] and "Traceback" not in output
    assert re.search(expected, lines[0]), lines[0]
    assert not (tmp_path / "outputs").exists()


def test_debug_keeps_the_traceback(capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(user_errors.DEBUG_ENV, "1")
    try:
        raise AgriNeRFDataError("some/file.png: planted")
    except AgriNeRFDataError as error:
        output = _report(error, capsys)
    assert "Traceback (most recent call last)" in output and "some/file.png: planted" in output


def _thermal_in_some_frames(meta: dict) -> None:
    del meta["frames"][1]["thermal_file_path"], meta["frames"][1]["thermal_mask_path"]


@pytest.mark.parametrize("existing", [False, True], ids=["new-folder", "existing-folder"])
def test_a_run_that_fails_before_training_leaves_no_folder(
    tmp_path: Path, existing: bool, capsys: pytest.CaptureFixture, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A fault found only by the dataparser (after ns-train wrote config.yml): the folder ns-train made is removed;
    a folder that was there before (a rerun into the same --timestamp) is left as it was."""
    from nerfstudio.scripts import train

    monkeypatch.delenv(user_errors.DEBUG_ENV, raising=False)
    assert user_errors.install()
    root = write_tridata(tmp_path / "scene", num_frames=5)
    edit_transforms(root, _thermal_in_some_frames)
    config = _train_config(root, tmp_path / "outputs")
    run_folder = tmp_path / "outputs" / "scene" / "agrinerf-lite" / "run"
    if existing:
        run_folder.mkdir(parents=True)
        (run_folder / "kept.txt").write_text("an earlier run's file")
    with pytest.raises(AgriNeRFDataError, match="'thermal_file_path' is given in 4 of 5 frames") as caught:
        train.main(config)
    assert (run_folder / "config.yml").is_file(), "the fault is found after ns-train wrote its run folder"
    output = _report(caught.value, capsys)
    assert output.startswith("error: ") and "Traceback" not in output
    if existing:
        assert (run_folder / "kept.txt").is_file() and (run_folder / "config.yml").is_file()
    else:
        assert not (tmp_path / "outputs").exists()


@pytest.mark.slow
def test_ns_train_command_prints_one_message(tmp_path: Path) -> None:
    """As a user runs it: `ns-train agrinerf-lite` on a dataset with one RGB image cut to 100 bytes exits 1 with one
    error line naming the file and the fault, no traceback, and no output folder."""
    root = write_tridata(tmp_path / "scene", num_frames=5)
    expected = _truncated_rgb(root)
    command = [
        str(Path(sys.executable).parent / "ns-train"), "agrinerf-lite", "--data", str(root), "--max-num-iterations",
        "5", "--output-dir", str(tmp_path / "outputs"), "--vis", "tensorboard", "--machine.device-type", "cpu",
    ]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != user_errors.DEBUG_ENV}
    done = subprocess.run(command, capture_output=True, text=True, timeout=300, env={**env, "COLUMNS": "200"},
                          stdin=subprocess.DEVNULL, check=False)  # fmt: skip
    output = done.stdout + done.stderr
    assert done.returncode == 1, output[-3000:]
    errors = [line for line in output.splitlines() if line.startswith("error: ")]
    assert len(errors) == 1, output[-3000:]
    assert re.search(expected, errors[0]) and "Traceback" not in output, output[-3000:]
    assert not (tmp_path / "outputs").exists()
