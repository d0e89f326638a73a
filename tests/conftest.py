"""Test-session setup: the ``ns-*`` and ``agrinerf-*`` scripts of the interpreter running the tests come first on PATH,
so ``.venv/bin/pytest`` works without activating the venv (as README's test command runs it)."""

import os
import sys
from pathlib import Path

import pytest

# One thread per test process: pyproject.toml runs two test workers, and torch processes of 2 threads each on 2 cores
# slow each other several times over. Set before any worker (or the commands the tests start) imports torch.
os.environ.setdefault("OMP_NUM_THREADS", "1")

_BIN = str(Path(sys.executable).parent)
if os.environ.get("PATH", "").split(os.pathsep)[0] != _BIN:
    os.environ["PATH"] = _BIN + os.pathsep + os.environ.get("PATH", "")


@pytest.fixture(scope="session")
def tiny_run_config(tmp_path_factory) -> Path:
    """config.yml of a tiny trained AgriNeRF run (20 steps of the shrunk agrinerf-lite), shared by
    the tests of the commands that load a run (ns-export, ns-render, ns-viewer)."""
    from helpers.tiny_run import train_tiny_run

    return train_tiny_run(tmp_path_factory.mktemp("tiny_run"))
