"""The machine a measurement ran on, in one line, for the reports of the benchmarks and the detection tables."""

from __future__ import annotations

import os
import platform
from pathlib import Path
from typing import Literal, Optional, Sequence


def torch_device_type() -> Literal["cuda", "cpu"]:
    """``cuda`` where PyTorch sees a CUDA device, else ``cpu``: where the presets, the bench and the counter run."""
    import torch

    return "cuda" if torch.cuda.is_available() else "cpu"


def yolo_device(device: str = "auto") -> str:
    """An Ultralytics ``device`` argument: ``auto`` gives the first CUDA device (``"0"``) where there is one, else
    ``"cpu"``; anything else is passed through."""
    if device != "auto":
        return device
    return "0" if torch_device_type() == "cuda" else "cpu"


def device_name() -> str:
    """The CUDA device's name, or the CPU model and core count (``/proc/cpuinfo``'s "model name", as ``lscpu``)."""
    import torch

    if torch.cuda.is_available():
        return torch.cuda.get_device_name(0)
    model = platform.processor() or "CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{model} ({os.cpu_count()} cores, CPU)"


def software_versions() -> str:
    """Python and torch versions, e.g. "Python 3.10.12, torch 2.5.1"."""
    import torch

    return f"Python {platform.python_version()}, torch {torch.__version__}"


def machine_note(devices: Optional[Sequence[str]] = None) -> str:
    """``Machine: <arch>, <devices>; Python ..., torch ...`` (devices: those the rows were measured on, default this
    machine's)."""
    names = ", ".join(devices) if devices else device_name()
    return f"Machine: {platform.machine()}, {names}; {software_versions()}"
