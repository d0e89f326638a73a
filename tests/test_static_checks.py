"""Static checks as part of the test command: ruff over the repository and mypy over ``agrinerf_ns`` (through
scripts/typecheck.py, configured in pyproject.toml), each clean, and each shown to catch an undefined name."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
SCRATCH = '"""A scratch module."""\n\n\ndef area(width: float) -> float:\n    return width * heigth\n'
"""A module with an undefined name (``heigth``) that both checkers must report."""


def _run(command: list, cwd: Path, stdin: str | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(command, cwd=cwd, input=stdin, capture_output=True, text=True, timeout=600, check=False)


def test_ruff_check_is_clean():
    result = _run([sys.executable, "-m", "ruff", "check", "--no-cache", "."], REPO)
    assert result.returncode == 0, f"ruff check . failed:\n{result.stdout}\n{result.stderr}"


def test_ruff_catches_an_undefined_name():
    """The project's ruff settings, applied to a module inside the package, report F821."""
    command = [sys.executable, "-m", "ruff", "check", "--no-cache", "--stdin-filename", "agrinerf_ns/scratch.py", "-"]
    result = _run(command, REPO, stdin=SCRATCH)
    assert result.returncode == 1 and "F821" in result.stdout and "heigth" in result.stdout, result.stdout


def test_mypy_is_clean():
    result = _run([sys.executable, str(REPO / "scripts" / "typecheck.py")], REPO)
    assert result.returncode == 0, (
        f"scripts/typecheck.py (mypy on agrinerf_ns) failed:\n{result.stdout}\n{result.stderr}"
    )


def test_mypy_catches_an_undefined_name(tmp_path):
    """The project's mypy settings report an undefined name in a scratch module."""
    (tmp_path / "scratch.py").write_text(SCRATCH)
    command = [sys.executable, "-m", "mypy", "--config-file", str(REPO / "pyproject.toml")]
    command += ["--cache-dir", str(tmp_path / "cache"), "scratch.py"]
    result = _run(command, tmp_path)
    assert result.returncode == 1, f"mypy passed a module with an undefined name:\n{result.stdout}\n{result.stderr}"
    assert 'Name "heigth" is not defined  [name-defined]' in result.stdout, result.stdout


# --- the house: room sizes and import directions ------------------------------------------------------------

MAX_LINES = 500
"""No source file is longer: a module past this does several jobs (split it by job, as agrinerf_ns/model/)."""

FOLDERS = {"agrinerf_ns": "agrinerf_ns", "dataparsers": "agrinerf_ns.dataparsers", "method_configs": "agrinerf_ns.method_configs"}  # fmt: skip
"""Source folders and the package each installs as (pyproject.toml's package-dir)."""


def _modules() -> dict:
    """Module name -> file, for every module the package installs."""
    found = {}
    for folder, package in FOLDERS.items():
        for path in sorted((REPO / folder).rglob("*.py")):
            parts = list(path.relative_to(REPO / folder).with_suffix("").parts)
            if parts[0] in ("dataparsers", "method_configs") and folder == "agrinerf_ns":
                continue  # a checkout's git-ignored links to the mapped folders
            if parts[-1] == "__init__":
                parts = parts[:-1]
            found[".".join([package, *parts])] = path
    return found


def _imports(tree, modules: dict, module_level: bool) -> set:
    """Modules of this package that ``tree`` imports: at import time only (module level, not under ``if
    TYPE_CHECKING``) or anywhere (``module_level`` False)."""
    import ast

    names = set()

    def visit(node, top: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                if not module_level:
                    visit(child, False)
                continue
            if isinstance(child, ast.If) and "TYPE_CHECKING" in ast.unparse(child.test):
                if not module_level:
                    visit(child, top)
                for other in child.orelse:
                    visit(ast.Module(body=[other], type_ignores=[]), top)
                continue
            if isinstance(child, ast.Import):
                names.update(alias.name for alias in child.names)
            elif isinstance(child, ast.ImportFrom) and child.module and child.level == 0:
                for alias in child.names:
                    full = f"{child.module}.{alias.name}"
                    names.add(full if full in modules else child.module)
            visit(child, top)

    visit(tree, True)
    return {name for name in names if name in modules}


def test_no_source_file_is_over_500_lines():
    long = {
        str(p.relative_to(REPO)): n for p in _modules().values() if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    long.update({str(p.relative_to(REPO)): n for p in sorted((REPO / "benchmarks").glob("*.py"))
                 if (n := len(p.read_text().splitlines())) > MAX_LINES})  # fmt: skip
    assert not long, f"source files over {MAX_LINES} lines: {long}"


def _first_circle(graph: dict) -> list:
    """A cycle of ``graph`` (module -> the modules it imports) as a path that ends where it starts; [] when none."""
    state: dict = {}
    stack: list = []

    def visit(name: str) -> list:
        state[name] = "open"
        stack.append(name)
        for other in sorted(graph[name]):
            if state.get(other) == "open":
                return stack[stack.index(other) :] + [other]
            if other not in state and (cycle := visit(other)):
                return cycle
        state[name] = "done"
        stack.pop()
        return []

    for name in sorted(graph):
        if name not in state and (cycle := visit(name)):
            return cycle
    return []


def _import_graph(module_level: bool, modules: dict | None = None) -> dict:
    import ast

    modules = _modules() if modules is None else modules
    return {name: _imports(ast.parse(path.read_text()), modules, module_level) for name, path in modules.items()}


def test_the_import_graph_has_no_circle():
    """Counting every import between the package's modules (at module level, inside functions and under ``if
    TYPE_CHECKING``: a reader follows them all), they form no cycle."""
    cycle = _first_circle(_import_graph(module_level=False))
    assert not cycle, "import cycle: " + " -> ".join(cycle)


def test_the_circle_check_finds_a_planted_circle():
    """The check above sees a circle made only of a function-level and a type-only import, which a check of
    module-level imports alone would miss."""
    import ast

    modules = _modules()
    graph = _import_graph(False, modules)
    planted = {"agrinerf_ns.count.sources": "def f():\n    from agrinerf_ns.count import auto_path\n",
               "agrinerf_ns.count.auto_path": "if TYPE_CHECKING:\n    from agrinerf_ns.count.sources import RunOutputs\n"}  # fmt: skip
    for name, code in planted.items():
        graph[name] = graph[name] | _imports(ast.parse(code), modules, module_level=False)
        assert not _imports(ast.parse(code), modules, module_level=True)  # invisible to the module-level check
    assert _first_circle(graph) in (
        ["agrinerf_ns.count.auto_path", "agrinerf_ns.count.sources", "agrinerf_ns.count.auto_path"],
        ["agrinerf_ns.count.sources", "agrinerf_ns.count.auto_path", "agrinerf_ns.count.sources"],
    )


def test_the_product_imports_nothing_of_the_lab():
    """The lab (``agrinerf_ns.lab``: bench profiles, runners, grids, tables, oracles, diagnostics, the paper tables)
    imports the product; no module outside it imports the lab, not even inside a function or for types only."""
    import ast

    modules = _modules()
    planted = ast.parse("def f():\n    from agrinerf_ns.lab import results\n")  # seen inside a function too
    assert _imports(planted, modules, module_level=False) == {"agrinerf_ns.lab.results"}
    for name, path in sorted(modules.items()):
        if name == "agrinerf_ns.lab" or name.startswith("agrinerf_ns.lab."):
            continue
        lab = sorted(m for m in _imports(ast.parse(path.read_text()), modules, module_level=False)
                     if m == "agrinerf_ns.lab" or m.startswith("agrinerf_ns.lab."))  # fmt: skip
        assert not lab, f"{path.relative_to(REPO)} imports {lab}"


def test_the_data_stage_imports_nothing_of_the_model():
    """dataparsers/ (dataparser, dataset, event stream) reads data for the model and never imports it, not even
    inside a function."""
    import ast

    modules = _modules()
    for path in sorted((REPO / "dataparsers").glob("*.py")):
        model = sorted(m for m in _imports(ast.parse(path.read_text()), modules, module_level=False)
                       if m == "agrinerf_ns.model" or m.startswith("agrinerf_ns.model."))  # fmt: skip
        assert not model, f"{path.relative_to(REPO)} imports {model}"
