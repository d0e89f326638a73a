"""Test-session setup: the ``ns-*`` and ``agrinerf-*`` scripts of the interpreter running the tests come first on PATH,
so ``.venv/bin/pytest`` works without activating the venv (as README's test command runs it)."""

import os
import sys
from pathlib import Path

_BIN = str(Path(sys.executable).parent)
if os.environ.get("PATH", "").split(os.pathsep)[0] != _BIN:
    os.environ["PATH"] = _BIN + os.pathsep + os.environ.get("PATH", "")
