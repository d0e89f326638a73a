"""A user's error stops an ``ns-*`` command with one message, not a traceback, and ``ns-train`` leaves no run folder
for a run that never trained.

Installed by the dataparser package (its ``__init__``), which every ``ns-*`` command loads with the plugin:

- ``sys.excepthook``: an uncaught :data:`USER_ERRORS` exception (a dataset that breaks its contract; its message
  names the file and the fault) prints ``error: MESSAGE`` on stderr and the command exits with status 1. Any other
  exception keeps Python's traceback. With ``AGRINERF_DEBUG=1`` every exception keeps its traceback.
- ``ns-train``: the dataset is checked (:func:`agrinerf_ns.dataparsers.dataset_checks.check_dataset`) before the
  command prints its config and writes the run folder, so a bad dataset is refused in a second and writes nothing.
  If the command fails later, the run folder it created is removed while it holds no checkpoint (no ``ns-eval``,
  ``ns-viewer`` or ``ns-render`` can load such a folder, so it is no run); with ``AGRINERF_DEBUG=1`` it is kept.
"""

from __future__ import annotations

import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, Callable, Optional, Tuple, Type

DEBUG_ENV = "AGRINERF_DEBUG"
"""Set to 1 for the full traceback of a user's error (and to keep a failed run's folder)."""


def user_error_types() -> Tuple[Type[BaseException], ...]:
    """The exceptions that report a user's input, whose message alone says what to fix."""
    from agrinerf_ns.dataparsers.dataset_checks import AgriNeRFDataError
    from agrinerf_ns.dataparsers.event_stream import EventStreamError

    return (AgriNeRFDataError, EventStreamError)


def debugging() -> bool:
    """Whether ``AGRINERF_DEBUG=1`` asks for tracebacks."""
    return os.environ.get(DEBUG_ENV, "") not in ("", "0")


@dataclass
class _State:
    original_hook: Optional[Callable[..., Any]] = None
    new_run_folder: Optional[Path] = None
    """The outermost folder ``ns-train``'s ``save_config`` created in this process (None: it created none)."""


_STATE = _State()


def report(kind: Type[BaseException], error: BaseException, traceback: Optional[TracebackType]) -> None:
    """``sys.excepthook``: one line for a user's error, the usual traceback for anything else; a new run folder
    without a checkpoint is removed first."""
    if not debugging():
        remove_new_run_folder()
    original = _STATE.original_hook or sys.__excepthook__
    if issubclass(kind, user_error_types()) and not debugging():
        print(f"error: {error}\n(set {DEBUG_ENV}=1 for the traceback)", file=sys.stderr)
        return
    original(kind, error, traceback)


def remove_new_run_folder() -> Optional[Path]:
    """Remove the run folder this process's ``ns-train`` created if it holds no checkpoint; returns what was removed."""
    folder = _STATE.new_run_folder
    if folder is None or not folder.is_dir() or any(folder.rglob("*.ckpt")):
        return None
    shutil.rmtree(folder, ignore_errors=True)
    _STATE.new_run_folder = None
    return folder


def _outermost_missing(path: Path) -> Optional[Path]:
    """The outermost folder of ``path`` (itself or an ancestor) that does not exist yet; None if it exists."""
    missing = None
    for folder in (path, *path.parents):
        if folder.exists():
            break
        missing = folder
    return missing


def _dataset_of(config: Any) -> Optional[Path]:
    """The dataset an ``ns-train`` config reads with the AgriNeRF dataparser; None for any other dataparser."""
    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig

    datamanager = getattr(getattr(config, "pipeline", None), "datamanager", None)
    parser = getattr(datamanager, "dataparser", None)
    if not isinstance(parser, AgriNeRFDataParserConfig):
        return None
    data = getattr(datamanager, "data", None) or parser.data
    return Path(data) if data is not None else None


def patch_train_config() -> bool:
    """Wrap ``ExperimentConfig.print_to_terminal`` (``ns-train``'s first step after parsing its arguments) to check
    the dataset first, and ``save_config`` (which creates the run folder) to note the folder it creates. Returns True
    if installed: only once Nerfstudio has defined the class (the plugin's entry points load while Nerfstudio's
    modules import, and importing it then would be circular; ``ns-train`` has it when it loads the method configs)."""
    module = sys.modules.get("nerfstudio.configs.experiment_config")
    ExperimentConfig = getattr(module, "ExperimentConfig", None)
    if ExperimentConfig is None:
        return False
    if getattr(ExperimentConfig.save_config, "_agrinerf", False):
        return True
    print_to_terminal, save_config = ExperimentConfig.print_to_terminal, ExperimentConfig.save_config

    def checked_print_to_terminal(self: Any) -> None:
        from agrinerf_ns.dataparsers.dataset_checks import check_dataset

        data = _dataset_of(self)
        if data is not None:
            check_dataset(data)
        print_to_terminal(self)

    def noted_save_config(self: Any) -> None:
        _STATE.new_run_folder = _outermost_missing(Path(self.get_base_dir()))
        save_config(self)

    for wrapper, original in ((checked_print_to_terminal, print_to_terminal), (noted_save_config, save_config)):
        wrapper.__doc__ = original.__doc__
        wrapper._agrinerf = True  # type: ignore[attr-defined]
    ExperimentConfig.print_to_terminal = checked_print_to_terminal  # type: ignore[method-assign]
    ExperimentConfig.save_config = noted_save_config  # type: ignore[method-assign]
    return True


def install() -> bool:
    """Install :func:`report` as ``sys.excepthook`` and :func:`patch_train_config`. Returns True if both are."""
    if sys.excepthook is not report:
        _STATE.original_hook = sys.excepthook
        sys.excepthook = report
    return patch_train_config()
