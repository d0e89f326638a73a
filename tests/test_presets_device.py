"""The presets run without a GPU: `ns-train agrinerf*` without `--machine.device-type` trains on the CPU when no CUDA
device is present and says so in one line (README's usage lines, as written). `CUDA_VISIBLE_DEVICES=""` hides any
GPU, so the test means the same on a machine with one."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from helpers.model_scene import write_model_scene

pytestmark = pytest.mark.slow

CPU_LINE = "no CUDA device found, training on the CPU (--machine.device-type cpu)"


@pytest.mark.parametrize("method", ["agrinerf-lite", "agrinerf"])
def test_preset_without_cuda_trains_on_the_cpu_and_says_so(method: str, tmp_path: Path) -> None:
    data = write_model_scene(tmp_path / "scene", views=6)
    command = [
        str(Path(sys.executable).parent / "ns-train"), method, "--data", str(data),
        "--max-num-iterations", "2", "--output-dir", str(tmp_path / "outputs"), "--vis", "tensorboard",
        "--timestamp", "run",
    ]  # fmt: skip
    env = {**os.environ, "CUDA_VISIBLE_DEVICES": "", "COLUMNS": "200"}
    done = subprocess.run(
        command, check=False, env=env, capture_output=True, text=True, timeout=300, stdin=subprocess.DEVNULL
    )
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-3000:]
    assert "Found no NVIDIA driver" not in output
    lines = [line for line in output.splitlines() if CPU_LINE in line]
    assert lines == [f"{method}: {CPU_LINE}"], lines
    config = yaml.load((tmp_path / "outputs" / "scene" / method / "run" / "config.yml").read_text(), Loader=yaml.Loader)
    assert config.machine.device_type == "cpu"
    assert sorted(p.name for p in (config.get_checkpoint_dir()).glob("step-*.ckpt")) == ["step-000000001.ckpt"]
