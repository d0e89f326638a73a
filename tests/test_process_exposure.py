"""agrinerf-process: RGB exposure intervals from rgb/exposures.txt or --exposure-time; bad files fail early."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import tyro

from agrinerf_ns.process import ProcessConfig, RawInputError, process_capture
from agrinerf_ns.process.cli import ProcessArgs
from agrinerf_ns.process.exposure import exposures_from_time, frame_exposures, read_exposures
from agrinerf_ns.process.readers import read_timestamps
from agrinerf_ns.synth import SynthConfig, generate_capture


@pytest.fixture(scope="module")
def raw(tmp_path_factory: pytest.TempPathFactory) -> Path:
    cfg = SynthConfig.tiny(views=3, heldout=0, event_substeps=1, lighting="dusk")
    return generate_capture(cfg, tmp_path_factory.mktemp("exposure") / "raw")


def _copy(raw: Path, tmp_path: Path) -> Path:
    out = tmp_path / "raw"
    shutil.copytree(raw, out)
    return out


def test_exposures_from_the_capture_and_from_the_option(raw: Path, tmp_path: Path) -> None:
    frames = read_timestamps(raw / "rgb")
    exp, meta = frame_exposures(raw, frames, None, "middle")
    np.testing.assert_allclose(exp, np.stack([frames.times - 0.03, frames.times + 0.03], -1), atol=1e-6)
    assert meta["source"] == "rgb/exposures.txt" and meta["median_s"] == pytest.approx(0.06)

    exp, meta = frame_exposures(raw, frames, 0.02, "start")  # the option overrides the file
    np.testing.assert_allclose(exp, np.stack([frames.times, frames.times + 0.02], -1))
    assert meta["source"] == "--exposure-time" and meta["overrides"] == "rgb/exposures.txt"
    np.testing.assert_allclose(exposures_from_time(frames.times, 0.02, "end")[:, 1], frames.times)

    bare = _copy(raw, tmp_path)
    (bare / "rgb" / "exposures.txt").unlink()
    assert frame_exposures(bare, frames, None, "middle") == (None, {"source": "none"})
    assert read_exposures(bare / "rgb", frames) is None
    with pytest.raises(ValueError, match="exposure-time"):
        exposures_from_time(frames.times, -1.0, "middle")


@pytest.mark.parametrize(
    "text, message",
    [
        ("000000.png 0.1\n", "expected '<file name> <exposure start> <exposure end>'"),
        ("000000.png 0.1 x\n", "not numbers"),
        ("000000.png 0.2 0.1\n", "must be finite and >= its start"),
        ("000000.png 0.1 0.2\n000000.png 0.1 0.2\n", "listed twice"),
        ("000000.png 0.1 0.2\n", "no exposure for 2 of the 3 frames"),
    ],
)
def test_bad_exposures_file_fails_before_any_output(raw: Path, tmp_path: Path, text: str, message: str) -> None:
    bad = _copy(raw, tmp_path)
    (bad / "rgb" / "exposures.txt").write_text(text)
    out = tmp_path / "data"
    with pytest.raises(RawInputError, match=message) as err:
        process_capture(bad, out, ProcessConfig(poses="given", show_progress=False))
    assert str(bad / "rgb" / "exposures.txt") in str(err.value)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == ["raw"]


def test_cli_option_names() -> None:
    args = tyro.cli(ProcessArgs, args=["--raw", "r", "--out", "o", "--exposure-time", "0.03",
                                       "--exposure-timestamp", "start"])  # fmt: skip
    assert args.config.exposure_time == 0.03 and args.config.exposure_timestamp == "start"
