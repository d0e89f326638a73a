"""Run Nerfstudio's own command-line tools (``ns-train``, ``ns-eval``, ``ns-render``) as subprocesses.

The benchmark, the demo and the tests drive Nerfstudio exactly as a user does, so what they measure is what users get.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Sequence, Tuple

RUN_TIMESTAMP = "run"
"""``ns-train --timestamp``: one run per experiment folder, at a path known before training."""
CHECKPOINTS_DIR = "nerfstudio_models"


def checkpoints(config: Path) -> List[Tuple[int, Path]]:
    """``(step, path)`` of every checkpoint of the run whose ``config.yml`` is ``config``, by step."""
    folder = Path(config).parent / CHECKPOINTS_DIR
    return sorted((int(p.stem.split("-")[1]), p) for p in folder.glob("step-*.ckpt"))


class NerfstudioCommandError(RuntimeError):
    """An ``ns-*`` command exited non-zero; the message holds the command and the tail of its output."""


def console_script(name: str) -> str:
    """The console script ``name`` (``ns-*``, ``agrinerf-*``) next to this interpreter (the active venv), else the one
    on PATH."""
    local = Path(sys.executable).parent / name
    if local.exists():
        return str(local)
    found = shutil.which(name)
    if found is None:
        package = "nerfstudio" if name.startswith("ns-") else "agrinerf-ns"
        raise NerfstudioCommandError(f"'{name}' not found: is {package} installed in this environment?")
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

    Output goes to ``log_path`` (a temporary file if None). Peak memory: see :class:`TreeMemory` (not ``ru_maxrss``,
    which on Linux starts from the parent's high-water mark: a child forked by a 3 GiB benchmark process reports at
    least 3 GiB).
    """
    command = [console_script(f"ns-{name}"), *map(str, args)]
    with tempfile.TemporaryDirectory() as tmp:
        log = log_path if log_path is not None else Path(tmp) / "ns.log"
        log.parent.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        with open(log, "w") as handle:
            handle.write(" ".join(command) + "\n")
            handle.flush()
            proc = subprocess.Popen([*_launcher(), *command], stdout=handle, stderr=subprocess.STDOUT,
                                    stdin=subprocess.DEVNULL)  # fmt: skip
            memory = TreeMemory(proc.pid)
            status = _wait(proc, timeout, memory)
        wall = time.perf_counter() - start
        output = log.read_text(errors="replace")
    code = os.waitstatus_to_exitcode(status)
    if code != 0:
        raise NerfstudioCommandError(f"{' '.join(command)} exited {code}:\n{output[-4000:]}")
    return CommandResult(output=output, wall_s=wall, peak_rss_mb=memory.peak_kib / 1024.0)


_DIE_WITH_PARENT = (
    "import ctypes, os, signal, sys\n"
    "ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))\n"  # 1: PR_SET_PDEATHSIG
    "os.getppid() == int(sys.argv[1]) or sys.exit(137)\n"  # the parent died before the prctl
    "os.execv(sys.argv[2], sys.argv[2:])"
)
"""Run as ``python -c _DIE_WITH_PARENT PARENT_PID COMMAND...``: exec COMMAND so that it receives SIGKILL when the
launching process dies (Linux ``PR_SET_PDEATHSIG``, kept across ``exec``). A killed benchmark or Ray worker then leaves
no ``ns-train`` writing into a run folder that a retry reuses. (Not a ``preexec_fn``: unsafe in a threaded process.)"""


def _launcher() -> List[str]:
    """The :data:`_DIE_WITH_PARENT` prefix of a command on Linux; none elsewhere."""
    return [sys.executable, "-c", _DIE_WITH_PARENT, str(os.getpid())] if sys.platform.startswith("linux") else []


def _proc_status_kib(pid: int, key: str) -> int:
    """A ``VmRSS``/``VmHWM``-style field of ``/proc/PID/status`` in KiB (0 when the process is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return int(line.split()[1])
    except (OSError, ValueError, IndexError):
        pass
    return 0


def _children(pid: int) -> List[int]:
    """Direct children of ``pid`` (from ``/proc/PID/task/*/children``)."""
    kids: List[int] = []
    for task in Path(f"/proc/{pid}/task").glob("*/children"):
        try:
            kids.extend(int(k) for k in task.read_text().split())
        except (OSError, ValueError):
            continue
    return kids


class TreeMemory:
    """Peak resident memory of a process and its descendants, sampled from ``/proc`` while it runs.

    The peak is the larger of (a) the largest sum of ``VmRSS`` over the process tree seen at any sample and (b) the
    main process's own ``VmHWM`` (its exact high-water mark since ``exec``, read at every sample). Samples are
    0.2 s apart; on a system without ``/proc`` the peak stays 0.
    """

    def __init__(self, pid: int) -> None:
        self.pid = pid
        self.peak_kib = 0

    def sample(self) -> None:
        tree, todo = [], [self.pid]
        while todo:
            pid = todo.pop()
            tree.append(pid)
            todo.extend(_children(pid))
        total = sum(_proc_status_kib(p, "VmRSS") for p in tree)
        self.peak_kib = max(self.peak_kib, total, _proc_status_kib(self.pid, "VmHWM"))


def _wait(proc: subprocess.Popen, timeout: Optional[float], memory: TreeMemory) -> int:
    """Wait for ``proc``, sampling its memory; kill it past ``timeout`` seconds. Returns the wait status."""
    deadline = None if timeout is None else time.monotonic() + timeout
    while True:
        memory.sample()  # before reaping: /proc/PID still exists (a zombie reads as 0 and changes nothing)
        pid, status = os.waitpid(proc.pid, os.WNOHANG)
        if pid == proc.pid:
            proc.returncode = os.waitstatus_to_exitcode(status)
            return status
        if deadline is not None and time.monotonic() > deadline:
            proc.kill()
            _, status = os.waitpid(proc.pid, 0)
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
        "--timestamp", RUN_TIMESTAMP,
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
    """Seconds per training step in steady state: wall time between the first and the last checkpoint over the steps
    between them, which leaves out start-up and the first iterations (Nerfstudio's ``tensorf`` spends 10-20 s in its
    first one on a CPU); Nerfstudio's profiler mean when the run saved fewer than two checkpoints."""
    profiler_s_per_step: float = float("nan")
    """Mean seconds per iteration from Nerfstudio's own profiler: every iteration, the first included (NaN if none)."""

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
        return checkpoints(self.config)


def steady_seconds_per_step(checkpoints: Sequence[Tuple[int, Path]]) -> Optional[float]:
    """Seconds per step between the first and last of ``(step, path)`` checkpoints (by file mtime); None if < 2."""
    if len(checkpoints) < 2:
        return None
    (first_step, first), (last_step, last) = checkpoints[0], checkpoints[-1]
    if last_step <= first_step:
        return None
    return (last.stat().st_mtime - first.stat().st_mtime) / (last_step - first_step)


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
    config = output_dir / experiment / method / RUN_TIMESTAMP / "config.yml"
    if not config.exists():
        raise NerfstudioCommandError(f"ns-train finished but wrote no {config}")
    profiler = _mean_iteration_seconds(result.output)
    run = TrainRun(config, result.wall_s, result.peak_rss_mb, started_at, profiler, profiler)
    steady = steady_seconds_per_step(run.checkpoints())
    if steady is not None:
        run.s_per_step = steady
    return run


def ns_eval(config: Path, output_json: Path, timeout: Optional[float] = None) -> Dict[str, float]:
    """Evaluate a trained run on its eval split with ``ns-eval``; return the ``results`` dict's metrics (NaN where
    unavailable: the file, strict JSON, holds null there and the reason under ``unavailable``)."""
    from agrinerf_ns.metrics_json import UNAVAILABLE_KEY

    run_ns(
        "eval",
        ["--load-config", str(config), "--output-path", str(output_json)],
        log_path=output_json.with_suffix(".log"),
        timeout=timeout,
    )
    results = json.loads(output_json.read_text())["results"]
    return {k: math.nan if v is None else v for k, v in results.items() if k != UNAVAILABLE_KEY}


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
