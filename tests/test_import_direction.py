"""The direction of imports between the package's parts (issue 65): 2D fruit vision (``agrinerf_ns.fruit``) below the
data stage, the counter and the detector; the data stage (``process``) below everything that reads its datasets; the
detector above the counter, never both ways; and no loop between packages.

Every import counts: at module level, inside functions and under ``if TYPE_CHECKING`` (the graph of
test_static_checks.py, whose checks also hold that no two files import each other in a circle and that nothing
outside the lab imports the lab).
"""

from __future__ import annotations

import ast
from typing import Dict, Set

import pytest
from test_static_checks import _first_circle, _import_graph, _imports, _modules

PRODUCT_PACKAGES = ("process", "count", "detect", "fruit", "model", "dataparsers")
"""The packages whose order the issue fixes; every other subpackage and top-level module is a part too."""
MAY_NOT_REACH = {
    "fruit": ("process", "count", "detect", "model", "dataparsers", "method_configs", "lab", "survey", "orchestrate"),
    "process": ("count", "detect", "model", "dataparsers", "method_configs", "lab", "survey", "orchestrate"),
    "count": ("detect", "lab", "survey"),
}
"""Part -> the parts it reaches through no chain of imports."""


def _part(module: str, packages: Set[str]) -> str:
    """The part a module belongs to: its subpackage (``agrinerf_ns.fruit.blobs`` -> ``fruit``), or itself for a
    top-level module (``agrinerf_ns.images``)."""
    parts = module.split(".")
    if len(parts) > 2 or (len(parts) == 2 and module in packages):
        return parts[1]
    return module


def _part_graph(graph: Dict[str, Set[str]]) -> Dict[str, Set[str]]:
    """Part -> the other parts its modules import."""
    packages = {name for name, path in _modules().items() if path.name == "__init__.py"}
    parts: Dict[str, Set[str]] = {}
    for module, imported in graph.items():
        own = _part(module, packages)
        parts.setdefault(own, set()).update(_part(m, packages) for m in imported)
        parts[own].discard(own)
    for imported in list(parts.values()):
        for other in imported:
            parts.setdefault(other, set())
    return parts


def _reached(graph: Dict[str, Set[str]], part: str) -> Dict[str, str]:
    """Every module the modules of subpackage ``part`` reach through imports -> a module that imports it on the
    way (for the message)."""
    prefix = f"agrinerf_ns.{part}"
    todo = [m for m in graph if m == prefix or m.startswith(prefix + ".")]
    reached: Dict[str, str] = {}
    while todo:
        module = todo.pop()
        for other in sorted(graph[module]):
            if other not in reached:
                reached[other] = module
                todo.append(other)
    return reached


def _upward(graph: Dict[str, Set[str]], part: str) -> Dict[str, str]:
    """The modules of the parts ``part`` may not reach that it does reach -> a module importing them on the way."""
    banned = tuple(f"agrinerf_ns.{other}" for other in MAY_NOT_REACH[part])
    return {m: by for m, by in _reached(graph, part).items() if m in banned or m.startswith(tuple(b + "." for b in banned))}  # fmt: skip


def test_no_loop_between_packages():
    """The parts (each subpackage, each top-level module) import each other in no circle; the product's packages are
    all there."""
    parts = _part_graph(_import_graph(module_level=False))
    assert set(PRODUCT_PACKAGES) <= set(parts)
    cycle = _first_circle(parts)
    assert not cycle, "import loop between packages: " + " -> ".join(cycle)


@pytest.mark.parametrize("part", sorted(MAY_NOT_REACH))
def test_a_part_reaches_nothing_above_it(part: str):
    """fruit reaches none of the data stage, the counter, the detector or the model; the data stage nothing that
    reads its datasets (count, detect, the model and its dataparser, the lab, the survey); the counter not the
    detector (the detector reads the counter's render folders)."""
    upward = _upward(_import_graph(module_level=False), part)
    assert not upward, f"agrinerf_ns.{part} reaches " + ", ".join(
        f"{m} (imported by {by})" for m, by in sorted(upward.items())
    )


def test_the_checks_see_planted_upward_imports():
    """A function-level import of the counter in fruit vision and a type-only import of the detector in the counter
    (both invisible at import time) break the rules above: the checks can fail."""
    modules = _modules()
    graph = _import_graph(False, modules)
    planted = {"agrinerf_ns.fruit.contrast": "def f():\n    from agrinerf_ns.count import pipeline\n",
               "agrinerf_ns.count.lift": "if TYPE_CHECKING:\n    from agrinerf_ns.detect.boxes import FrameTruth\n"}  # fmt: skip
    for name, code in planted.items():
        assert not _imports(ast.parse(code), modules, module_level=True)
        graph[name] = graph[name] | _imports(ast.parse(code), modules, module_level=False)
    assert "agrinerf_ns.count.pipeline" in _upward(graph, "fruit")
    assert "agrinerf_ns.process.readers" not in _upward(graph, "count")  # the counter may read the data stage's files
    assert _upward(graph, "count")["agrinerf_ns.detect.boxes"] == "agrinerf_ns.count.lift"
    cycle = _first_circle(_part_graph(graph))
    assert {"count", "detect"} <= set(cycle), cycle
