"""List the tensor factories of per-step code that may put a tensor on the wrong device.

A tensor made without ``device=`` lands on the CPU; on a GPU run it then meets the model's CUDA tensors and the step
dies ("Expected all tensors to be on the same device"), a bug no CPU test shows. This check reads the code that runs at
each step (``agrinerf_ns/model``, ``agrinerf_ns/count``; module construction in ``__init__`` / ``populate_modules`` and
module-level constants aside) and names every ``torch.<factory>(...)`` call that neither

- passes ``device=``, nor
- is moved at once (``torch.<factory>(...).to(...)``), nor
- carries a comment ``# cpu: <why>`` on one of its lines (CPU on purpose: data that lives on the CPU, a CPU
  generator for device-independent draws, ...).

``*_like`` and ``.new_*`` calls take their device from a tensor and are never named.

    python scripts/device_factories.py            # prints each offending line, exits 1 if any
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from typing import Iterable, List, Tuple

FACTORIES = frozenset(
    {
        "tensor",
        "as_tensor",
        "zeros",
        "ones",
        "empty",
        "full",
        "arange",
        "linspace",
        "logspace",
        "eye",
        "rand",
        "randn",
        "randint",
        "randperm",
        "from_numpy",
    }  # fmt: skip
)
CONSTRUCTION = frozenset({"__init__", "populate_modules"})
PER_STEP_DIRS = ("agrinerf_ns/model", "agrinerf_ns/count")
MARK = "# cpu:"


def _is_factory(node: ast.Call) -> bool:
    func = node.func
    return (
        isinstance(func, ast.Attribute)
        and func.attr in FACTORIES
        and isinstance(func.value, ast.Name)
        and func.value.id == "torch"
    )


def offending_calls(source: str) -> List[Tuple[int, str]]:
    """(line, call) of each factory call in `source` that the rules above do not clear."""
    tree = ast.parse(source)
    lines = source.splitlines()
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    found = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and _is_factory(node)):
            continue
        if any(k.arg == "device" for k in node.keywords):
            continue
        up = parents.get(node)
        if isinstance(up, ast.Attribute) and up.attr == "to" and isinstance(parents.get(up), ast.Call):
            continue  # moved at once
        end = node.end_lineno or node.lineno
        if any(MARK in lines[i - 1] for i in range(node.lineno, end + 1)):
            continue
        scope, inside = parents.get(node), None
        while scope is not None:
            if isinstance(scope, (ast.FunctionDef, ast.AsyncFunctionDef)):
                inside = inside or scope.name
                if scope.name in CONSTRUCTION:
                    break
            scope = parents.get(scope)
        if inside is None or (scope is not None and scope.name in CONSTRUCTION):  # type: ignore[attr-defined]
            continue  # module level, or module construction
        found.append((node.lineno, ast.get_source_segment(source, node) or f"torch.{node.func.attr}(...)"))  # type: ignore[attr-defined]
    return sorted(found)


def per_step_files(root: Path) -> Iterable[Path]:
    for folder in PER_STEP_DIRS:
        yield from sorted((root / folder).glob("*.py"))


def report(root: Path) -> List[str]:
    """One line per offending call under `root`: ``path:line: call``."""
    out = []
    for path in per_step_files(root):
        for line, call in offending_calls(path.read_text()):
            first = call.splitlines()[0]
            out.append(f"{path.relative_to(root)}:{line}: {first} passes no device= (pass it, use *_like / "
                       f".new_*, or mark '{MARK} why')")  # fmt: skip
    return out


def main() -> int:
    lines = report(Path(__file__).resolve().parent.parent)
    print("\n".join(lines) if lines else "device factories: every per-step tensor factory names its device")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
