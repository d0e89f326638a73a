"""A checkout of this repository imported or checked as the installed package.

``dataparsers/`` and ``method_configs/`` sit at the top of the repository but install as ``agrinerf_ns.dataparsers``
and ``agrinerf_ns.method_configs`` ([tool.setuptools.package-dir] in pyproject.toml). An interpreter that imports
``agrinerf_ns`` from a checkout gets that mapping from `map_checkout_subpackages` (called by the package itself);
mypy, and checkouts older than that, read it from the symbolic links that `link_installed_layout` builds.
"""

from __future__ import annotations

import importlib.abc
import importlib.machinery
import importlib.util
import os
import shutil
import sys
from pathlib import Path
from typing import Dict, Iterable, Optional

try:
    import tomllib
except ImportError:  # Python 3.10
    import tomli as tomllib  # type: ignore[no-redef]

PACKAGE = "agrinerf_ns"


def mapped_subpackages(repo: Path) -> Dict[str, Path]:
    """The subpackages of checkout ``repo`` that its pyproject.toml installs from another folder: name -> folder."""
    pyproject = repo / "pyproject.toml"
    if not pyproject.is_file():
        raise FileNotFoundError(f"{repo}: not a checkout of agrinerf-ns (no pyproject.toml)")
    package_dir = tomllib.loads(pyproject.read_text())["tool"]["setuptools"]["package-dir"]
    mapped = {}
    for name, folder in package_dir.items():
        if not name.startswith(PACKAGE + "."):
            continue
        if name.count(".") > 1:
            raise ValueError(f"{pyproject}: nested package-dir entry {name} is not handled here")
        mapped[name] = repo / folder
    return mapped


class _CheckoutSubpackages(importlib.abc.MetaPathFinder):
    """Finds exactly the mapped subpackages (``agrinerf_ns.dataparsers`` -> ``<repo>/dataparsers``); their modules
    are then found through the subpackage's own search path."""

    def __init__(self, mapped: Dict[str, Path]) -> None:
        self.mapped = mapped

    def find_spec(
        self, fullname: str, path: Optional[Iterable[str]] = None, target: object = None
    ) -> Optional[importlib.machinery.ModuleSpec]:
        folder = self.mapped.get(fullname)
        if folder is None:
            return None
        return importlib.util.spec_from_file_location(
            fullname, folder / "__init__.py", submodule_search_locations=[str(folder)]
        )


def map_checkout_subpackages(repo: Path) -> None:
    """Make ``import agrinerf_ns.dataparsers`` (and every other mapped subpackage) work when ``agrinerf_ns`` was
    imported from checkout ``repo`` itself. Appended after the path finders, so an installed layout still wins."""
    if not any(isinstance(finder, _CheckoutSubpackages) for finder in sys.meta_path):
        sys.meta_path.append(_CheckoutSubpackages(mapped_subpackages(repo)))


def link_installed_layout(repo: Path, root: Path) -> Path:
    """``root/agrinerf_ns``, rebuilt: a link to each entry of checkout ``repo``'s package folder, plus one per
    subpackage that its pyproject.toml maps to another folder. Returns ``root`` (the folder to import from)."""
    mapped = {name.split(".", 1)[1]: folder for name, folder in mapped_subpackages(repo).items()}
    if root.exists():
        shutil.rmtree(root)
    top = root / PACKAGE
    top.mkdir(parents=True)
    for entry in (repo / PACKAGE).iterdir():
        if entry.name not in mapped and entry.name != "__pycache__":
            os.symlink(entry.resolve(), top / entry.name)
    for name, folder in mapped.items():
        os.symlink(folder.resolve(), top / name)
    write_entry_points(repo, root)
    return root


def write_entry_points(repo: Path, root: Path) -> None:
    """``root/agrinerf_ns-<version>.dist-info`` with checkout ``repo``'s entry points, so that Nerfstudio, importing
    from ``root`` ahead of site-packages, discovers that checkout's methods rather than the installed version's (the
    first distribution of a name on the path wins)."""
    project = tomllib.loads((repo / "pyproject.toml").read_text())["project"]
    info = root / f"{PACKAGE}-{project['version']}.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {project['name']}\nVersion: {project['version']}\n")
    groups = project.get("entry-points", {})
    lines = [f"[{group}]\n" + "".join(f"{k} = {v}\n" for k, v in entries.items()) for group, entries in groups.items()]
    (info / "entry_points.txt").write_text("\n".join(lines))
