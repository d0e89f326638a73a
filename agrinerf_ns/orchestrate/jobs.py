"""Jobs, what each needs, and the driver loop that runs them on an executor (this process, or Ray tasks).

A job is a module-level function and its arguments, run on a worker (or in this process); a job may wait for the
results of others (``after``), which are passed after its own arguments. Only the driver sees results, in
``on_result`` (the one writer of a shared table); a job that fails is retried ``retries`` times and then reported with
its error and log, and the jobs waiting for it are reported as skipped. Every attempt appends a line to the job's
``attempts.log`` (session, host, process id, time): the driver counts a job as running once its attempt has started,
and a test can find the worker to kill.
"""

from __future__ import annotations

import json
import os
import socket
import time
import traceback
import uuid
from collections import deque
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import (
    Any,
    Callable,
    Deque,
    Dict,
    Iterator,
    List,
    Optional,
    Protocol,
    Sequence,
    Tuple,
    runtime_checkable,
)

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

ATTEMPTS_LOG = "attempts.log"
THREAD_VARIABLES = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS", "NUMEXPR_NUM_THREADS")
ERROR_CHARS = 4000
"""The tail of a failed job's error kept in the report (a failed ``ns-train`` carries the end of its output)."""


@dataclass(frozen=True)
class Resources:
    """What one job holds while it runs: Ray schedules it where these are free, so jobs never share a core or GPU."""

    cpus: Optional[int] = None
    """CPU cores, and the thread count of the job and the commands it starts (``OMP_NUM_THREADS``, torch). None:
    threads left as they are (one job at a time in this process); Ray then reserves one core."""
    gpus: float = 0.0
    """GPUs (Ray sets ``CUDA_VISIBLE_DEVICES`` to the ones it gives the job)."""
    memory_mb: Optional[int] = None
    """Memory Ray reserves for the job (MiB; None: none reserved)."""


@dataclass(frozen=True)
class Job:
    """One unit of work: ``fn(*args, *results of after)`` on a worker."""

    key: str
    """Unique name in reports (e.g. ``orchard-dark/nerfacto@s1``)."""
    fn: Callable[..., Any]
    """A module-level function (workers import it by name)."""
    args: Tuple[Any, ...]
    folder: Path
    """Where the job's ``attempts.log`` is appended to (on a filesystem every worker and the driver see)."""
    resources: Resources = field(default_factory=Resources)
    after: Tuple[str, ...] = ()
    """Keys of the jobs whose results this one needs; it starts when they have finished."""
    log: Optional[Path] = None
    """The job's own log, named when it fails."""
    retries: int = 1
    """Further attempts after a failure (an exception or a dead worker)."""


@dataclass(frozen=True)
class JobFailure:
    key: str
    error: str
    """The tail of the last attempt's error."""
    attempts: int
    """Attempts started in this session (``attempts.log``)."""
    log: Optional[Path]


@dataclass
class JobsReport:
    """What became of each job: its result, its failure, or why it never ran."""

    done: Dict[str, Any] = field(default_factory=dict)
    failed: Dict[str, JobFailure] = field(default_factory=dict)
    skipped: Dict[str, str] = field(default_factory=dict)
    """Key -> the failed job it waited for."""


DRIVER_LOCK = ".driver.lock"
"""The file a driver holds while it writes an output folder's tables (:func:`driver_lock`)."""


class FolderInUse(RuntimeError):
    """Another driver is writing the same output folder."""


@contextmanager
def driver_lock(folder: Path) -> Iterator[None]:
    """Hold ``folder/.driver.lock`` while this driver writes the folder's tables.

    A second driver on the same folder (the same command started twice, or a resume started while an interrupted
    driver still shuts down) stops at once with :class:`FolderInUse`, naming the holder, instead of both appending the
    same runs. The lock is the kernel's (``flock``, which Linux also takes on NFS): it ends with the process that holds
    it, however that process ends, so a killed driver never leaves a stale lock.
    """
    import fcntl

    folder.mkdir(parents=True, exist_ok=True)
    path = folder / DRIVER_LOCK
    with open(path, "a+") as handle:
        try:
            fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            handle.seek(0)
            holder = handle.read().strip() or "a process that has not written its id yet"
            raise FolderInUse(
                f"{folder} is being written by another driver ({holder}; lock {path}): wait for it to end, or stop "
                "it, then run this command again (finished runs are kept and not run again)"
            ) from None
        handle.seek(0)
        handle.truncate()
        handle.write(json.dumps({"pid": os.getpid(), "host": socket.gethostname(), "since": time.time()}))
        handle.flush()
        yield  # closing the file releases the lock


def limit_threads(cpus: Optional[int]) -> None:
    """Make this process and the commands it starts use ``cpus`` threads (no change when None)."""
    if cpus is None:
        return
    for name in THREAD_VARIABLES:
        os.environ[name] = str(cpus)
    import torch

    torch.set_num_threads(cpus)


def record_attempt(folder: Path, session: str) -> None:
    """Append this attempt (session, host, process id, time) to ``folder/attempts.log``."""
    folder.mkdir(parents=True, exist_ok=True)
    line = json.dumps({"session": session, "host": socket.gethostname(), "pid": os.getpid(), "time": time.time()})
    with open(folder / ATTEMPTS_LOG, "a") as handle:
        handle.write(line + "\n")
        handle.flush()
        os.fsync(handle.fileno())


def attempts(folder: Path, session: Optional[str] = None) -> List[Dict[str, Any]]:
    """The attempts recorded in ``folder/attempts.log`` (of one session, or all), oldest first."""
    path = Path(folder) / ATTEMPTS_LOG
    if not path.exists():
        return []
    records = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return [r for r in records if session is None or r["session"] == session]


def execute(fn: Callable[..., Any], args: Tuple[Any, ...], cpus: Optional[int], folder: Path, session: str) -> Any:
    """A job's body on its worker: set its thread count, record the attempt, run it."""
    limit_threads(cpus)
    record_attempt(Path(folder), session)
    return fn(*args)


def error_text(err: BaseException) -> str:
    """A failure's type, message and (for an error raised here) traceback, last :data:`ERROR_CHARS` characters."""
    text = "".join(traceback.format_exception(type(err), err, err.__traceback__))
    return text[-ERROR_CHARS:]


@runtime_checkable
class Executor(Protocol):
    """Runs submitted jobs and hands back the finished ones."""

    def submit(self, job: Job, args: Tuple[Any, ...], session: str) -> Any:
        """Start ``job`` with its full arguments; returns a handle."""
        ...

    def poll(self, timeout: float) -> List[Tuple[Any, bool, Any]]:
        """Finished jobs since the last poll, waiting up to ``timeout`` s: (handle, succeeded, result or error)."""
        ...


class LocalExecutor:
    """One job after another in this process, in the order submitted, each retried ``job.retries`` times."""

    def __init__(self) -> None:
        self._queue: Deque[Tuple[int, Job, Tuple[Any, ...], str]] = deque()
        self._next = 0

    def submit(self, job: Job, args: Tuple[Any, ...], session: str) -> int:
        self._next += 1
        self._queue.append((self._next, job, args, session))
        return self._next

    def poll(self, timeout: float) -> List[Tuple[Any, bool, Any]]:
        if not self._queue:
            return []
        handle, job, args, session = self._queue.popleft()
        for attempt in range(job.retries + 1):
            try:
                return [(handle, True, execute(job.fn, args, job.resources.cpus, job.folder, session))]
            except Exception as err:  # a job's failure is reported, not raised; KeyboardInterrupt still stops all
                if attempt == job.retries:
                    return [(handle, False, error_text(err))]
        raise AssertionError("unreachable")

    def close(self) -> None:
        self._queue.clear()


def run_jobs(
    jobs: Sequence[Job],
    executor: Executor,
    on_result: Callable[[Job, Any], None],
    label: str,
    console: Optional[Console] = None,
) -> JobsReport:
    """Run ``jobs`` (each once its ``after`` jobs are done) on ``executor``, calling ``on_result`` on the driver for each
    success; a progress bar counts jobs done, running and failed."""
    by_key = {job.key: job for job in jobs}
    if len(by_key) != len(jobs):
        raise ValueError("job keys must be unique")
    unknown = [(job.key, a) for job in jobs for a in job.after if a not in by_key]
    if unknown:
        raise ValueError(f"jobs wait for jobs not in the list: {unknown}")
    session = uuid.uuid4().hex[:12]
    report = JobsReport()
    waiting = {job.key: job for job in jobs}
    running: Dict[Any, Job] = {}

    def submit_ready() -> None:
        changed = True
        while changed:  # a skip may unblock (skip) the jobs that wait for the skipped one
            changed = False
            for key, job in list(waiting.items()):
                blocked = [a for a in job.after if a in report.failed or a in report.skipped]
                if blocked:
                    report.skipped[key] = blocked[0]
                elif all(a in report.done for a in job.after):
                    args = (*job.args, *(report.done[a] for a in job.after))
                    running[executor.submit(job, args, session)] = job
                else:
                    continue
                del waiting[key]
                changed = True

    columns = (TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn())
    with Progress(*columns, console=console) as progress:
        bar = progress.add_task(label, total=len(jobs))
        while True:
            submit_ready()
            if not running:
                if waiting:
                    raise ValueError(f"jobs wait for each other in a cycle: {sorted(waiting)}")
                break
            for handle, ok, value in executor.poll(timeout=0.5):
                job = running.pop(handle)
                if ok:
                    report.done[job.key] = value
                    on_result(job, value)
                else:
                    tries = len(attempts(job.folder, session))
                    report.failed[job.key] = JobFailure(job.key, str(value), tries, job.log)
            started = sum(1 for job in running.values() if attempts(job.folder, session))
            finished = len(report.done) + len(report.failed) + len(report.skipped)
            progress.update(
                bar,
                completed=finished,
                description=f"{label}: {len(report.done)} done, {started} running, "
                f"{len(report.failed) + len(report.skipped)} failed",
            )
    return report


def failures_markdown(report: JobsReport, title: str) -> str:
    """The failed and skipped jobs with their attempts, logs and errors, as Markdown ('' when none)."""
    if not report.failed and not report.skipped:
        return ""
    lines = [f"# {title}\n"]
    for failure in report.failed.values():
        log = f", log `{failure.log}`" if failure.log is not None else ""
        lines.append(
            f"## {failure.key}\n\nFailed after {failure.attempts} attempt(s){log}:\n\n```\n{failure.error}\n```\n"
        )
    for key, blocker in report.skipped.items():
        lines.append(f"## {key}\n\nNot run: it needs `{blocker}`, which failed.\n")
    return "\n".join(lines)


def write_failures(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` atomically, or remove ``path`` when ``text`` is empty."""
    if not text:
        path.unlink(missing_ok=True)
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(path)
