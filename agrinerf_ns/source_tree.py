"""A checkout of this repository laid out as the installed package, for tools that import from a source tree.

``dataparsers/`` and ``method_configs/`` sit at the top of the repository but install as ``agrinerf_ns.dataparsers``
and ``agrinerf_ns.method_configs`` ([tool.setuptools.package-dir] in pyproject.toml). Neither mypy nor an interpreter
with the checkout on PYTHONPATH can read that mapping, so `link_installed_layout` builds it as symbolic links.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib

PACKAGE = "agrinerf_ns"


def link_installed_layout(repo: Path, root: Path) -> Path:
    """``root/agrinerf_ns``, rebuilt: a link to each entry of checkout ``repo``'s package folder, plus one per
    subpackage that its pyproject.toml maps to another folder. Returns ``root`` (the folder to import from)."""
    pyproject = repo / "pyproject.toml"
    if not pyproject.is_file():
        raise FileNotFoundError(f"{repo}: not a checkout of agrinerf-ns (no pyproject.toml)")
    package_dir = tomllib.loads(pyproject.read_text())["tool"]["setuptools"]["package-dir"]
    if root.exists():
        shutil.rmtree(root)
    top = root / PACKAGE
    top.mkdir(parents=True)
    mapped = {
        name.split(".", 1)[1]: repo / folder for name, folder in package_dir.items() if name.startswith(PACKAGE + ".")
    }
    for entry in (repo / package_dir[PACKAGE]).iterdir():
        if entry.name not in mapped and entry.name != "__pycache__":
            os.symlink(entry.resolve(), top / entry.name)
    for name, folder in mapped.items():
        if "." in name:
            raise ValueError(f"{pyproject}: nested package-dir entry {PACKAGE}.{name} is not handled here")
        os.symlink(folder.resolve(), top / name)
    return root
