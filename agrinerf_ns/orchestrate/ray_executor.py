"""Jobs as Ray tasks: the one module of the package that imports Ray (the optional ``[ray]`` extra).

Each job becomes a task that declares its CPUs, GPUs and memory (:class:`~agrinerf_ns.orchestrate.jobs.Resources`), so
Ray starts it only where they are free; Ray retries it ``job.retries`` times when it raises or its worker process dies.
The driver submits a job once the jobs it waits for are done and reads each result back (only the driver writes the
shared tables). Files are passed as paths: every node must see the output folder at the same path (a shared
filesystem, as on a Slurm cluster).
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Any, Dict, List, Optional, Tuple

from agrinerf_ns.orchestrate.jobs import Job, error_text, execute

LOCAL = "local"
"""``--ray local``: start a Ray instance on this machine (stopped at the end)."""
START_ATTEMPTS = 3
"""Starts of a local Ray tried: its processes must register within fixed times (about 15 s for its agents), which a
machine busy with other work can miss."""


def ray_init(
    address: str,
    num_cpus: Optional[int] = None,
    num_gpus: Optional[int] = None,
    object_store_mb: Optional[int] = None,
    temp_dir: Optional[Path] = None,
) -> bool:
    """Connect to Ray at ``address`` (``local``: start one here with ``num_cpus``/``num_gpus``, an object store of
    ``object_store_mb`` and its files under ``temp_dir``; ``auto``: the cluster this machine belongs to; else a
    ``HOST:PORT`` or ``ray://`` address). Returns whether this call started or joined it (False: already connected)."""
    import ray

    if ray.is_initialized():
        return False
    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")  # nothing leaves the machine
    if address == LOCAL:
        options = dict(num_cpus=num_cpus, num_gpus=num_gpus, include_dashboard=False, log_to_driver=False,
                       configure_logging=False,
                       object_store_memory=None if object_store_mb is None else object_store_mb * 2**20)  # fmt: skip
        for attempt in range(1, START_ATTEMPTS + 1):
            try:
                ray.init(**options, _temp_dir=str(temp_dir) if temp_dir else tempfile.mkdtemp(prefix="ray-"))
                break
            except Exception as err:  # Ray's start-up has fixed time limits, which a busy machine can miss
                ray.shutdown()
                if attempt == START_ATTEMPTS or "timed out during startup" not in str(err):
                    raise
    else:
        ray.init(address=address, log_to_driver=False, configure_logging=False)
    return True


class RayExecutor:
    """Submit jobs as Ray tasks and collect them as they finish (connects on creation; :meth:`close` disconnects, and
    stops a ``local`` instance, unless Ray was already connected)."""

    def __init__(self, address: str, num_cpus: Optional[int] = None, num_gpus: Optional[int] = None,
                 object_store_mb: Optional[int] = None, temp_dir: Optional[Path] = None) -> None:  # fmt: skip
        import ray

        self._owner = ray_init(address, num_cpus, num_gpus, object_store_mb, temp_dir)
        self._task = ray.remote(execute)
        self._refs: Dict[Any, Any] = {}

    def submit(self, job: Job, args: Tuple[Any, ...], session: str) -> Any:
        res = job.resources
        options: Dict[str, Any] = {
            "num_cpus": res.cpus if res.cpus is not None else 1,
            "num_gpus": res.gpus,
            "max_retries": job.retries,
            "retry_exceptions": True,
            "name": job.key,
        }
        if res.memory_mb is not None:
            options["memory"] = res.memory_mb * 2**20
        ref = self._task.options(**options).remote(job.fn, args, res.cpus or 1, job.folder, session)
        self._refs[ref] = ref
        return ref

    def poll(self, timeout: float) -> List[Tuple[Any, bool, Any]]:
        import ray

        if not self._refs:
            return []
        ready, _ = ray.wait(list(self._refs), num_returns=len(self._refs), timeout=timeout)
        finished = []
        for ref in ready:
            del self._refs[ref]
            try:
                finished.append((ref, True, ray.get(ref)))
            except Exception as err:  # the task's error, or its worker's death after the last retry
                finished.append((ref, False, error_text(err)))
        return finished

    def close(self) -> None:
        import ray

        for ref in self._refs:
            try:
                ray.cancel(ref, force=True)
            except Exception:  # finished meanwhile, or the cluster is gone: nothing left to stop
                pass
        self._refs.clear()
        if self._owner:
            ray.shutdown()
