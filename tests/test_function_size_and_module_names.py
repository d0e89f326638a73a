"""Two rules of the house (issue 65): a function is at most 80 lines unless its docstring says why it is longer, and
no two modules share a file name, except the names every command-line part has (``__init__``, ``cli``, ``config``,
``errors``). Both hold over the package (``agrinerf_ns``, ``dataparsers/``, ``method_configs/``), ``benchmarks/``
and ``scripts/``.

A function's length runs from its ``def`` line to its last line, docstring included, decorators not. The stated reason
is a sentence of its docstring that starts with ``Long because`` (e.g. "Long because the steps share every local and
read best in order.").
"""

from __future__ import annotations

import ast
from collections import defaultdict
from pathlib import Path
from typing import Dict, Iterator, List, Tuple

from test_static_checks import REPO, _modules

MAX_FUNCTION_LINES = 80
REASON_MARKER = "Long because"
"""How a docstring states why its function is longer than MAX_FUNCTION_LINES."""
SHARED_BASENAMES = {"__init__", "cli", "config", "errors"}
"""File names several parts may each have: a package's own, its command line, its options and its errors."""

WAITING_TO_BE_SPLIT: Dict[str, str] = {}
"""Functions over the limit, without a reason, that are being split now (path::name -> the work splitting it). The
test fails when an entry is no longer over the limit, states its reason, or is gone: remove it then, so that the list
cannot outlive its reason. Nothing is added here: split a new long function, or state why it is long."""


def _source_files() -> List[Path]:
    """The package's modules, then the benchmarks and scripts."""
    files = sorted(set(_modules().values()))
    for folder in ("benchmarks", "scripts"):
        files += sorted((REPO / folder).glob("*.py"))
    return files


def _functions(tree: ast.AST, prefix: str = "") -> Iterator[Tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    """(qualified name, node) of every function and method in ``tree``, nested ones included (``outer.inner``)."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            yield prefix + node.name, node
            yield from _functions(node, f"{prefix}{node.name}.")
        elif isinstance(node, ast.ClassDef):
            yield from _functions(node, f"{prefix}{node.name}.")
        else:
            yield from _functions(node, prefix)


def long_functions(source: str) -> Dict[str, Tuple[int, bool]]:
    """Qualified name -> (lines, whether its docstring states a reason) of every function of ``source`` over
    MAX_FUNCTION_LINES lines."""
    found = {}
    for name, node in _functions(ast.parse(source)):
        lines = (node.end_lineno or node.lineno) - node.lineno + 1
        if lines > MAX_FUNCTION_LINES:
            found[name] = (lines, REASON_MARKER in (ast.get_docstring(node) or ""))
    return found


def _repo_long_functions() -> Dict[str, Tuple[int, bool]]:
    """``path::qualified name`` -> (lines, reason stated) over every source file of the check."""
    found = {}
    for path in _source_files():
        for name, record in long_functions(path.read_text()).items():
            found[f"{path.relative_to(REPO).as_posix()}::{name}"] = record
    return found


def shared_basenames(paths: List[Path]) -> Dict[str, List[str]]:
    """File name -> the files of ``paths`` that have it, for every name held by more than one file and not in
    SHARED_BASENAMES."""
    by_name = defaultdict(list)
    for path in paths:
        by_name[path.stem].append(path.relative_to(REPO).as_posix() if path.is_absolute() else path.as_posix())
    return {name: sorted(files) for name, files in sorted(by_name.items())
            if len(files) > 1 and name not in SHARED_BASENAMES}  # fmt: skip


def test_no_function_is_over_80_lines_without_a_stated_reason() -> None:
    unexplained = {name: lines for name, (lines, reason) in _repo_long_functions().items()
                   if not reason and name not in WAITING_TO_BE_SPLIT}  # fmt: skip
    assert not unexplained, (
        f"functions over {MAX_FUNCTION_LINES} lines (split them, or say why in the docstring with "
        f"{REASON_MARKER!r}): {unexplained}"
    )


def test_every_function_waiting_to_be_split_still_is() -> None:
    """Each entry of WAITING_TO_BE_SPLIT is still a function over the limit with no stated reason."""
    found = _repo_long_functions()
    done = sorted(name for name in WAITING_TO_BE_SPLIT if name not in found or found[name][1])
    assert not done, f"remove from WAITING_TO_BE_SPLIT (split, explained or gone): {done}"


def test_the_length_check_counts_lines_and_reads_the_reason() -> None:
    """An 81-line function is found, an 80-line one is not, a method and a nested function are named by their
    owner, and a docstring that says why is read as the reason."""

    def function(name: str, lines: int, docstring: str = "", indent: str = "") -> str:
        body = [f'{indent}    """{docstring}"""'] if docstring else []
        body += [f"{indent}    x = {k}" for k in range(lines - 1 - len(body))]
        return "\n".join([f"{indent}def {name}():", *body]) + "\n"

    assert len(function("f", 81).splitlines()) == 81
    source = function("at_limit", 80) + function("over", 81) + function("why", 90, "Long because it reads in order.")
    source += "class C:\n" + function("method", 81, indent="    ")
    source += "def outer():\n" + function("inner", 81, indent="    ")
    assert long_functions(source) == {
        "over": (81, False),
        "why": (90, True),
        "C.method": (81, False),
        "outer": (82, False),
        "outer.inner": (81, False),
    }


def test_no_module_name_is_used_twice() -> None:
    shared = shared_basenames(_source_files())
    assert not shared, f"module file names used more than once (name each module for what it does): {shared}"


def test_the_name_check_finds_a_planted_twin() -> None:
    """Two ``pipeline.py`` in different folders are reported; two ``cli.py`` are allowed."""
    paths = [Path(p) for p in ("a/pipeline.py", "b/pipeline.py", "a/cli.py", "b/cli.py", "a/rig.py")]
    assert shared_basenames(paths) == {"pipeline": ["a/pipeline.py", "b/pipeline.py"]}
