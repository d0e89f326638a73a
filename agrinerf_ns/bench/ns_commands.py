"""Run Nerfstudio's own command-line tools (``ns-train``, ``ns-eval``, ``ns-render``) as subprocesses.

The benchmark, the demo and the tests drive Nerfstudio exactly as a user does, so what they measure is what users get.
"""

from __future__ import annotations

import dataclasses
import json
import os
import re
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple


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


@dataclass
class CommandResult:
    """What one ``ns-*`` run printed and cost: wall seconds and the peak resident memory of its process tree."""

    output: str
    wall_s: float
    peak_rss_mb: float


def run_ns(
    name: str, args: Sequence[str], log_path: Optional[Path] = None, timeout: Optional[float] = None
) -> CommandResult:
    """Run ``ns-<name> args...``; raise :class:`NerfstudioCommandError` on failure.

    Output goes to ``log_path`` (a temporary file if None). Peak memory is the child's ``ru_maxrss`` from ``wait4``:
    the largest resident set of the command and of the worker processes it waited for.
    """
    command = [_ns_executable(f"ns-{name}"), *map(str, args)]
    with tempfile.TemporaryDirectory() as tmp:
        log = log_path if log_path is not None else Path(tmp) / "ns.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        with open(log, "w") as handle:
            handle.write(" ".join(command) + "\n")
            handle.flush()
            proc = subprocess.Popen(command, stdout=handle, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
            status, usage = _wait(proc, timeout)
        wall = time.perf_counter() - start
        output = log.read_text(errors="replace")
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise NerfstudioCommandError(f"{' '.join(command)} exited {code}:\n{output[-4000:]}")
    return CommandResult(output=output, wall_s=wall, peak_rss_mb=usage.ru_maxrss / 1024.0)


def _wait(proc: subprocess.Popen, timeout: Optional[float]) -> Tuple[int, resource.struct_rusage]:
    """Wait for ``proc`` with ``wait4`` (to get its own resource usage); kill it past ``timeout`` seconds."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        pid, status, usage = os.wait4(proc.pid, os.WNOHANG if deadline is not None else 0)
        if pid == proc.pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return status, usage
        if deadline is not None and time.monotonic() > deadline:
            proc.kill()
            _, status, usage = os.wait4(proc.pid, 0)
            proc.returncode = os.waitstatus_to_exitcode(status)
            raise NerfstudioCommandError(f"{proc.args} timed out after {timeout} s")
        time.sleep(0.2)


def headless_train_args(
    max_steps: int, rays_per_batch: int, output_dir: Path, experiment: str, steps_per_save: Optional[int] = None
) -> List[str]:
    """Common ``ns-train`` options for a headless run: device, steps, batch, where to write, no viewer, no
    evaluation during training (it would be timed as training), a checkpoint every ``steps_per_save`` steps (all kept)."""
    save_every = steps_per_save or max_steps
    no_eval = str(10 * max(max_steps, 1))
    return [
        "--machine.device-type", "cuda" if _cuda_available() else "cpu",
        "--max-num-iterations", str(max_steps),
        "--steps-per-save", str(save_every),
        "--save-only-latest-checkpoint", "False",
        "--steps-per-eval-batch", no_eval,
        "--steps-per-eval-image", no_eval,
        "--steps-per-eval-all-images", no_eval,
        "--pipeline.datamanager.train-num-rays-per-batch", str(rays_per_batch),
        "--output-dir", str(output_dir),
        "--experiment-name", experiment,
        "--timestamp", "run",
        "--vis", "tensorboard",
        "--viewer.quit-on-train-completion", "True",
    ]  # fmt: skip


def _cuda_available() -> bool:
    import torch

    return torch.cuda.is_available()


@dataclass
class TrainRun:
    """A finished ``ns-train`` run."""

    config: Path
    """The run's ``config.yml`` (for ``ns-eval``, ``ns-render``, ``eval_setup``)."""
    wall_s: float
    """Seconds from launching ``ns-train`` to its exit."""
    peak_rss_mb: float
    """Peak resident memory of the training process (MiB)."""
    started_at: float
    """``time.time()`` when ``ns-train`` was launched (checkpoint mtimes minus this give time-to-checkpoint)."""
    s_per_step: float
    """Mean seconds per training iteration, from Nerfstudio's own profiler (NaN if it printed none)."""

    def save(self, path: Path) -> None:
        """Write this record as JSON (atomically)."""
        record = {**dataclasses.asdict(self), "config": str(self.config)}
        tmp = path.with_suffix(".tmp")
        tmp.write_text(json.dumps(record, indent=2))
        tmp.replace(path)

    @staticmethod
    def load(path: Path) -> "TrainRun":
        """Read a record written by :meth:`save`."""
        record = json.loads(path.read_text())
        return TrainRun(**{**record, "config": Path(record["config"])})

    def checkpoints(self) -> List[Tuple[int, Path]]:
        """(step, path) of every checkpoint, by step."""
        found = [(int(p.stem.split("-")[1]), p) for p in (self.config.parent / "nerfstudio_models").glob("step-*.ckpt")]
        return sorted(found)


def _mean_iteration_seconds(output: str) -> float:
    match = re.search(r"Trainer\.train_iteration:\s*([0-9.eE+-]+)", output)
    return float(match.group(1)) if match else float("nan")


def ns_train(
    method: str,
    data: Path,
    output_dir: Path,
    experiment: str,
    max_steps: int,
    rays_per_batch: int = 1024,
    extra_args: Sequence[str] = (),
    dataparser_args: Sequence[str] = (),
    steps_per_save: Optional[int] = None,
    timeout: Optional[float] = None,
) -> TrainRun:
    """Train ``method`` on ``data`` with ``ns-train``.

    ``extra_args`` go before the dataparser subcommand, ``dataparser_args`` after it (e.g. ``["nerfstudio-data"]``).
    """
    args = [
        method,
        "--data",
        str(data),
        *headless_train_args(max_steps, rays_per_batch, output_dir, experiment, steps_per_save),
        *extra_args,
        *dataparser_args,
    ]
    started_at = time.time()
    result = run_ns("train", args, log_path=output_dir / experiment / f"{method}.train.log", timeout=timeout)
    config = output_dir / experiment / method / "run" / "config.yml"
    if not config.exists():
        raise NerfstudioCommandError(f"ns-train finished but wrote no {config}")
    return TrainRun(config, result.wall_s, result.peak_rss_mb, started_at, _mean_iteration_seconds(result.output))


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
