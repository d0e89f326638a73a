"""Run Nerfstudio's own command-line tools (``ns-train``, ``ns-eval``, ``ns-render``) as subprocesses.

The benchmark, the demo and the tests drive Nerfstudio exactly as a user does, so what they measure is what users get.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Dict, List, Optional, Sequence


class NerfstudioCommandError(RuntimeError):
    """An ``ns-*`` command exited non-zero; the message holds the command and the tail of its output."""


def _ns_executable(name: str) -> str:
    """The ``ns-*`` script next to this interpreter (the active venv), else the one on PATH."""
    local = Path(sys.executable).parent / name
    if local.exists():
        return str(local)
    found = shutil.which(name)
    if found is None:
        raise NerfstudioCommandError(f"'{name}' not found: is nerfstudio installed in this environment?")
    return found


def run_ns(name: str, args: Sequence[str], log_path: Optional[Path] = None, timeout: Optional[float] = None) -> str:
    """Run ``ns-<name> args...``; return its combined output, raise :class:`NerfstudioCommandError` on failure."""
    command = [_ns_executable(f"ns-{name}"), *map(str, args)]
    proc = subprocess.run(
        command, check=False, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL
    )
    output = proc.stdout + proc.stderr
    if log_path is not None:
        log_path.parent.mkdir(parents=True, exist_ok=True)
        log_path.write_text(" ".join(command) + "\n" + output)
    if proc.returncode != 0:
        raise NerfstudioCommandError(f"{' '.join(command)} exited {proc.returncode}:\n{output[-4000:]}")
    return output


def cpu_train_args(max_steps: int, rays_per_batch: int, output_dir: Path, experiment: str) -> List[str]:
    """Common ``ns-train`` options for a headless run: device, steps, batch, where to write, no viewer."""
    return [
        "--machine.device-type",
        "cpu" if not _cuda_available() else "cuda",
        "--max-num-iterations",
        str(max_steps),
        "--steps-per-save",
        str(max_steps),
        "--steps-per-eval-batch",
        str(max(max_steps, 1)),
        "--steps-per-eval-image",
        str(max(max_steps, 1)),
        "--steps-per-eval-all-images",
        str(10 * max(max_steps, 1)),
        "--pipeline.datamanager.train-num-rays-per-batch",
        str(rays_per_batch),
        "--output-dir",
        str(output_dir),
        "--experiment-name",
        experiment,
        "--timestamp",
        "run",
        "--vis",
        "tensorboard",
        "--viewer.quit-on-train-completion",
        "True",
    ]


def _cuda_available() -> bool:
    import torch

    return torch.cuda.is_available()


def ns_train(
    method: str,
    data: Path,
    output_dir: Path,
    experiment: str,
    max_steps: int,
    rays_per_batch: int = 1024,
    extra_args: Sequence[str] = (),
    dataparser_args: Sequence[str] = (),
    timeout: Optional[float] = None,
) -> Path:
    """Train ``method`` on ``data`` with ``ns-train``; return the run's ``config.yml``.

    ``extra_args`` go before the dataparser subcommand, ``dataparser_args`` after it (e.g. ``["nerfstudio-data"]``).
    """
    args = [
        method,
        "--data",
        str(data),
        *cpu_train_args(max_steps, rays_per_batch, output_dir, experiment),
        *extra_args,
        *dataparser_args,
    ]
    run_ns("train", args, log_path=output_dir / experiment / f"{method}.train.log", timeout=timeout)
    config = output_dir / experiment / method / "run" / "config.yml"
    if not config.exists():
        raise NerfstudioCommandError(f"ns-train finished but wrote no {config}")
    return config


def ns_eval(config: Path, output_json: Path, timeout: Optional[float] = None) -> Dict[str, float]:
    """Evaluate a trained run on its eval split with ``ns-eval``; return the ``results`` dict (NaN where unavailable)."""
    run_ns(
        "eval",
        ["--load-config", str(config), "--output-path", str(output_json)],
        log_path=output_json.with_suffix(".log"),
        timeout=timeout,
    )
    return json.loads(output_json.read_text())["results"]


def ns_render_dataset(
    config: Path,
    output_dir: Path,
    outputs: Sequence[str] = ("rgb",),
    split: str = "test",
    timeout: Optional[float] = None,
) -> Path:
    """Render the ``split`` cameras of a trained run with ``ns-render dataset``; return the output folder."""
    run_ns(
        "render",
        [
            "dataset",
            "--load-config",
            str(config),
            "--output-path",
            str(output_dir),
            "--split",
            split,
            "--rendered-output-names",
            *outputs,
        ],
        log_path=output_dir / "render.log",
        timeout=timeout,
    )
    return output_dir
