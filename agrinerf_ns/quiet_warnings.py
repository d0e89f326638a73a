"""Keep third-party warnings that a user cannot act on off the console of the plugin's commands.

Nerfstudio 1.1.5 on current PyTorch prints screens of deprecation warnings (``torch.jit.script is deprecated``,
``torch.cuda.amp.custom_fwd(args...) is deprecated``, DataLoader worker counts, ...) before the first useful line of
every ``ns-*`` and ``agrinerf-*`` command. They concern code the user does not own; they bury what the command says.

:func:`quiet_third_party` hides exactly those: warnings of the deprecation categories attributed to a module outside
``agrinerf_ns``, and the few named third-party :class:`UserWarning`\\ s in :data:`THIRD_PARTY_MESSAGES`. The
project's own warnings, and every other warning, still show. It applies only where a console command starts
(:func:`quiet_console_command`): never in a test run (pytest sees every warning), and never when the user chose warning
filters (``-W``, ``PYTHONWARNINGS``) or sets ``AGRINERF_SHOW_WARNINGS=1``.

Where it runs: the ``agrinerf-*`` entry points call :func:`quiet_console_command` first; ``ns-*`` commands reach it
through the plugin's entry points (:func:`agrinerf_ns.compat.activate`) and, for the warnings Nerfstudio raises while
importing itself before any plugin loads, through the ``torch.backends`` entry point (:func:`torch_import_hook`),
which PyTorch calls while ``import torch`` runs (``TORCH_DEVICE_BACKEND_AUTOLOAD=0`` turns that off).

This module imports nothing beyond the standard library: :func:`torch_import_hook` runs inside ``import torch``.
"""

from __future__ import annotations

import os
import sys
import warnings
from typing import Optional, Sequence

DEPRECATIONS = (DeprecationWarning, PendingDeprecationWarning, FutureWarning)
"""The categories hidden when a module outside ``agrinerf_ns`` raises them."""

THIRD_PARTY_MODULE = r"(?!agrinerf_ns(\.|$)|__main__$)"
"""Any module but the plugin's own (and a script run as ``__main__``), as a :func:`warnings.filterwarnings` regex."""

THIRD_PARTY_MESSAGES = (
    # torch.utils.data: Nerfstudio's data loaders pick their worker count, not the user
    (r"This DataLoader will create \d+ worker processes", r"torch\.utils\.data"),
    # torch's deprecation of Nerfstudio's list indexing in cameras.py, raised as a UserWarning
    (r"Using a non-tuple sequence for multidimensional indexing is deprecated", r"nerfstudio\."),
    # Nerfstudio's writer logs loss tensors as scalars
    (r"Converting a tensor with requires_grad=True to a scalar", r"nerfstudio\."),
)
"""(message regex, module regex) of third-party :class:`UserWarning`\\ s hidden as well."""

COMMAND_PREFIXES = ("ns-", "agrinerf-")
"""Console scripts whose console is kept clear: Nerfstudio's and the plugin's."""


def quiet_third_party() -> None:
    """Install the filters (at the front, so that they win over Python's defaults). Safe to call more than once."""
    for category in DEPRECATIONS:
        warnings.filterwarnings("ignore", category=category, module=THIRD_PARTY_MODULE)
    for message, module in THIRD_PARTY_MESSAGES:
        warnings.filterwarnings("ignore", message=message, category=UserWarning, module=module)


def is_console_command(argv: Optional[Sequence[str]] = None) -> bool:
    """Whether this process is an ``ns-*`` or ``agrinerf-*`` console script (not pytest, not ``python -c``)."""
    args = sys.argv if argv is None else argv
    return bool(args) and os.path.basename(args[0]).startswith(COMMAND_PREFIXES)


def user_chose_filters() -> bool:
    """Whether the user asked for warnings: ``-W``/``PYTHONWARNINGS`` given, or ``AGRINERF_SHOW_WARNINGS=1``."""
    return bool(sys.warnoptions) or os.environ.get("AGRINERF_SHOW_WARNINGS") == "1"


def quiet_console_command(argv: Optional[Sequence[str]] = None) -> bool:
    """Apply :func:`quiet_third_party` where a console command runs and the user chose no filters. Returns True if
    applied."""
    if not is_console_command(argv) or user_chose_filters() or "pytest" in sys.modules:
        return False
    quiet_third_party()
    return True


def torch_import_hook() -> None:
    """The ``torch.backends`` entry point: :func:`quiet_console_command` as ``import torch`` runs. Never raises (an
    error here would fail ``import torch`` in every program of the environment)."""
    try:
        quiet_console_command()
    except Exception:  # noqa: BLE001 - a warning filter is never worth a failed import
        pass
