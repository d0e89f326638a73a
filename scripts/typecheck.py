"""Type-check the installed package ``agrinerf_ns`` with mypy (configured in pyproject.toml's [tool.mypy]).

Usage: ``.venv/bin/python scripts/typecheck.py [extra mypy options]``; exits with mypy's status.

``dataparsers/`` and ``method_configs/`` install as ``agrinerf_ns.dataparsers`` and ``agrinerf_ns.method_configs``
([tool.setuptools.package-dir]), a layout mypy cannot read from the source tree (nor through setuptools' editable
finder). So this builds the installed layout as a tree of symbolic links under ``.mypy_cache/src`` and checks it
there: mypy reports ``agrinerf_ns/dataparsers/x.py`` for ``dataparsers/x.py``; every other path is the repository's.
The cache (``.mypy_cache``) makes a second run take seconds.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

try:
    import tomllib
except ImportError:  # Python 3.10: mypy depends on tomli there
    import tomli as tomllib

REPO = Path(__file__).resolve().parent.parent
CACHE = REPO / ".mypy_cache"
PACKAGE = "agrinerf_ns"


def link_tree(repo: Path, root: Path) -> Path:
    """``root/agrinerf_ns``, rebuilt: a link to each entry of the package's folder, plus one per subpackage that
    pyproject.toml maps to another folder. Returns ``root``."""
    package_dir = tomllib.loads((repo / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    if root.exists():
        shutil.rmtree(root)
    top = root / PACKAGE
    top.mkdir(parents=True)
    mapped = {
        name.split(".", 1)[1]: repo / folder for name, folder in package_dir.items() if name.startswith(PACKAGE + ".")
    }
    for entry in (repo / package_dir[PACKAGE]).iterdir():
        if entry.name not in mapped and entry.name != "__pycache__":
            os.symlink(entry, top / entry.name)
    for name, folder in mapped.items():
        if "." in name:
            raise ValueError(
                f"{repo / 'pyproject.toml'}: nested package-dir entry {PACKAGE}.{name} is not handled here"
            )
        os.symlink(folder, top / name)
    return root


def main(argv: list[str]) -> int:
    root = link_tree(REPO, CACHE / "src")
    command = [sys.executable, "-m", "mypy", "--config-file", str(REPO / "pyproject.toml")]
    command += ["--cache-dir", str(CACHE), "-p", PACKAGE, *argv]
    return subprocess.run(command, cwd=root, check=False).returncode


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
