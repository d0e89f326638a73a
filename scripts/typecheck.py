"""Type-check the installed package ``agrinerf_ns`` with mypy (configured in pyproject.toml's [tool.mypy]).

Usage: ``.venv/bin/python scripts/typecheck.py [extra mypy options]``; exits with mypy's status.

``dataparsers/`` and ``method_configs/`` install as ``agrinerf_ns.dataparsers`` and ``agrinerf_ns.method_configs``
([tool.setuptools.package-dir]), a layout mypy cannot read from the source tree (nor through setuptools' editable
finder). So this checks the installed layout, built as symbolic links under ``.mypy_cache/src``
(`agrinerf_ns.source_tree`): mypy reports ``agrinerf_ns/dataparsers/x.py`` for ``dataparsers/x.py``; every other
path is the repository's.
The cache (``.mypy_cache``) makes a second run take seconds.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from agrinerf_ns.source_tree import PACKAGE, link_installed_layout

REPO = Path(__file__).resolve().parent.parent
CACHE = REPO / ".mypy_cache"


def main(argv: list[str]) -> int:
    root = link_installed_layout(REPO, CACHE / "src")
    command = [sys.executable, "-m", "mypy", "--config-file", str(REPO / "pyproject.toml")]
    command += ["--cache-dir", str(CACHE), "-p", PACKAGE, *argv]
    return subprocess.run(command, cwd=root, check=False).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
