"""The console ``agrinerf-process`` and its steps log to (stderr, so that stdout stays free for results)."""

from __future__ import annotations

from rich.console import Console

CONSOLE = Console(stderr=True)
