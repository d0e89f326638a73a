"""The executor a command's jobs run on: this process (:class:`~agrinerf_ns.orchestrate.jobs.LocalExecutor`) or Ray
tasks (:class:`~agrinerf_ns.orchestrate.ray_executor.RayExecutor`). Kept apart from both so that the import goes one
way: the Ray executor builds on the jobs module, which knows nothing of Ray."""

from __future__ import annotations

from contextlib import contextmanager
from typing import Any, Iterator, Optional, Union

from agrinerf_ns.orchestrate.jobs import LocalExecutor


@contextmanager
def executor_for(ray_address: Optional[str], **ray_options: Any) -> Iterator[Union[LocalExecutor, Any]]:
    """This process (``ray_address`` None) or Ray (:class:`~agrinerf_ns.orchestrate.ray_executor.RayExecutor`, options
    passed on), closed on leaving."""
    if ray_address is None:
        executor: Any = LocalExecutor()
    else:
        from agrinerf_ns.orchestrate.ray_executor import RayExecutor

        executor = RayExecutor(ray_address, **ray_options)
    try:
        yield executor
    finally:
        executor.close()
