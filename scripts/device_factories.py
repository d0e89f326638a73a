"""List the tensor factories of the code a training step, a render or a count runs that may put a tensor on the wrong
device.

A tensor made without a device lands on the CPU; on a GPU run it then meets the model's CUDA tensors and the step dies
("Expected all tensors to be on the same device"), a bug no CPU test shows. Only a module's parameters and buffers
follow ``model.to(device)``: a tensor kept anywhere else (a plain attribute, even one set in an ``__init__``, or a
module-level constant) stays where it was made. This check reads every module of ``SCOPE`` (the model, the count, the
trajectory, the event stream, the fruit sampler and the helpers a step calls; ``tests/test_fake_device_step.py`` holds
that every project module with tensors that a step, an evaluation or a count's render calls lies in it or in
``HOST_SIDE``) and names every tensor factory (``FACTORIES``; called as ``torch.zeros``, through an alias such as
``import torch as th`` / ``from torch import zeros``, or as the ``torch.Tensor(...)`` constructors) that

- passes no ``device=`` (``device=None`` is the default device; ``device="cpu"`` is the CPU: neither counts), and
- is not moved at once to a device (``torch.<factory>(...).to(x.device)``, ``.to(device=...)``, ``.cuda()``, possibly
  through dtype or shape methods such as ``.float()``; ``.to(torch.float64)`` or ``.to(other_tensor)`` do not count:
  only an argument that names a device other than the CPU, ``.device`` / ``device`` / ``torch.device(...)`` /
  ``"cuda"``, does), and
- is not made into a parameter or buffer (inside ``nn.Parameter(...)`` / ``register_buffer(...)``, or assigned to a
  local name that one of them takes in the same function), which ``model.to`` moves, and
- carries no comment ``# cpu: <why>`` on one of its lines (CPU on purpose: data that lives on the CPU, a CPU generator
  for device-independent draws, ...).

``torch.from_numpy`` is named outside construction (``__init__`` / ``populate_modules``) even when moved at once: it
copies host memory to the device at every call; a call that has to (data that lives in host memory) says why with
``# host: <why>``. ``*_like`` and ``.new_*`` calls take their device from a tensor and are never named.

    python scripts/device_factories.py            # prints each offending line, exits 1 if any
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path
from typing import Dict, Iterable, List, Optional, Set, Tuple

FACTORIES = frozenset(
    """
    tensor as_tensor asarray scalar_tensor from_numpy frombuffer zeros ones empty empty_strided full eye arange range
    linspace logspace tril_indices triu_indices rand randn randint randperm normal poisson Generator Tensor FloatTensor
    DoubleTensor HalfTensor BFloat16Tensor LongTensor IntTensor ShortTensor CharTensor ByteTensor BoolTensor
    hann_window hamming_window bartlett_window blackman_window kaiser_window
    """.split()
)
"""Calls that make a tensor (or a generator) on the default device unless told otherwise. ``torch.normal`` and
``torch.poisson`` with tensor arguments follow them, but a reader cannot tell those calls from the factory forms."""
CONSTRUCTION = frozenset({"__init__", "populate_modules"})
"""Functions that run once when the model is built: a ``from_numpy`` there is one copy, not one per step."""
SCOPE = (
    "agrinerf_ns/model",
    "agrinerf_ns/count",
    "agrinerf_ns/trajectory.py",
    "agrinerf_ns/colour.py",
    "agrinerf_ns/cpu_memory.py",
    "agrinerf_ns/run_loading.py",
    "agrinerf_ns/views.py",
    "dataparsers/event_stream.py",
    "dataparsers/fruit_sampler.py",
)
"""The code a training step, a render or a count runs on the model's tensors (folders: every ``*.py`` in them)."""
HOST_SIDE = (
    "dataparsers/agrinerf_dataparser.py",
    "dataparsers/agrinerf_dataset.py",
    "dataparsers/dataset_checks.py",
    "dataparsers/fruit_masks.py",
    "dataparsers/sfm_points.py",
)
"""Modules that build the dataset on the host, outside the scan: Nerfstudio's datasets, their images and the
dataparser's metadata live on the CPU by design, and its datamanager moves a batch to the model's device. A step,
evaluation or count also runs them (the fake-device test checks their tensors where they meet the model's)."""
DEVICE_KEEPING = frozenset(
    """
    float double half bfloat16 long int short bool byte char view reshape flatten unsqueeze squeeze expand contiguous
    clone t T pin_memory requires_grad_
    """.split()
)
"""Methods between a factory and its ``.to(device)`` that leave the tensor where it is."""
OWNERS = frozenset({"Parameter", "register_buffer", "register_parameter"})
"""Calls that make a tensor part of a module, which ``model.to(device)`` moves."""
MARK = "# cpu:"
HOST_MARK = "# host:"


def _torch_names(tree: ast.Module) -> Tuple[Set[str], Dict[str, str]]:
    """Names bound to the torch module (``torch``, ``th``) and names bound to one of its factories (``tensor``)."""
    modules, factories = {"torch"}, {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "torch":
                    modules.add(alias.asname or "torch")
        elif isinstance(node, ast.ImportFrom) and node.module == "torch" and not node.level:
            for alias in node.names:
                if alias.name in FACTORIES:
                    factories[alias.asname or alias.name] = alias.name
    return modules, factories


def _factory_name(node: ast.Call, modules: Set[str], factories: Dict[str, str]) -> Optional[str]:
    func = node.func
    if isinstance(func, ast.Attribute) and isinstance(func.value, ast.Name) and func.value.id in modules:
        return func.attr if func.attr in FACTORIES else None
    if isinstance(func, ast.Name):
        return factories.get(func.id)
    return None


def _names_the_cpu(node: ast.expr) -> bool:
    """``None`` (the default device), ``"cpu"`` or ``torch.device("cpu")``."""
    if isinstance(node, ast.Constant):
        return node.value is None or (isinstance(node.value, str) and node.value.startswith("cpu"))
    return isinstance(node, ast.Call) and bool(node.args) and _names_the_cpu(node.args[0])


def _names_a_device(node: ast.expr) -> bool:
    """Whether an argument reads as a device other than the CPU: ``x.device``, a name with ``device`` in it,
    ``torch.device(...)``, a device string or index, or a call that returns one (``get_device()``)."""
    if _names_the_cpu(node):
        return False
    if isinstance(node, ast.Constant):
        return isinstance(node.value, (str, int)) and not isinstance(node.value, bool)
    if isinstance(node, ast.Attribute):
        return "device" in node.attr.lower()
    if isinstance(node, ast.Name):
        return "device" in node.id.lower()
    if isinstance(node, ast.Call):
        return _names_a_device(node.func)
    return False


def _passes_device(node: ast.Call) -> bool:
    return any(k.arg == "device" and not _names_the_cpu(k.value) for k in node.keywords)


def _moved_at_once(node: ast.Call, parents: Dict[ast.AST, ast.AST]) -> bool:
    """``factory(...)[.float()...].to(<a device>)`` or ``.cuda()``."""
    current: ast.AST = node
    while True:
        up = parents.get(current)
        if not isinstance(up, ast.Attribute):
            return False
        call = parents.get(up)
        if up.attr == "T" and not isinstance(call, ast.Call):
            current = up
            continue
        if not (isinstance(call, ast.Call) and call.func is up):
            return False
        if up.attr == "cuda":
            return True
        if up.attr == "to":
            return _passes_device(call) or bool(call.args and _names_a_device(call.args[0]))
        if up.attr not in DEVICE_KEEPING:
            return False
        current = call


def _owner_call(node: ast.AST) -> bool:
    if not isinstance(node, ast.Call):
        return False
    func = node.func
    name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else None
    return name in OWNERS


def _made_a_module_tensor(node: ast.Call, parents: Dict[ast.AST, ast.AST], function: Optional[ast.AST]) -> bool:
    """Inside ``nn.Parameter(...)`` / ``register_buffer(...)``, or assigned to a local name that one of them takes later
    in the same function."""
    up = parents.get(node)
    while up is not None and not isinstance(up, ast.stmt):
        if _owner_call(up):
            return True
        up = parents.get(up)
    if function is None or not isinstance(up, (ast.Assign, ast.AnnAssign)):
        return False
    targets = up.targets if isinstance(up, ast.Assign) else [up.target]
    names = {t.id for t in targets if isinstance(t, ast.Name)}
    for call in ast.walk(function):
        if _owner_call(call) and call.lineno > up.lineno:  # type: ignore[attr-defined]
            args = [*call.args, *(k.value for k in call.keywords)]  # type: ignore[attr-defined]
            if any(isinstance(n, ast.Name) and n.id in names for a in args for n in ast.walk(a)):
                return True
    return False


def _enclosing_function(node: ast.AST, parents: Dict[ast.AST, ast.AST]) -> Optional[ast.AST]:
    up = parents.get(node)
    while up is not None and not isinstance(up, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
        up = parents.get(up)
    return up


def _marked(lines: List[str], node: ast.AST, mark: str) -> bool:
    end = getattr(node, "end_lineno", None) or node.lineno  # type: ignore[attr-defined]
    return any(mark in lines[i - 1] for i in range(node.lineno, end + 1))  # type: ignore[attr-defined]


def offending_calls(source: str) -> List[Tuple[int, str]]:
    """(line, call) of each factory call in `source` that the rules above do not clear."""
    tree = ast.parse(source)
    lines = source.splitlines()
    modules, factories = _torch_names(tree)
    parents = {child: node for node in ast.walk(tree) for child in ast.iter_child_nodes(node)}
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _factory_name(node, modules, factories)
        if name is None or _marked(lines, node, MARK):
            continue
        function = _enclosing_function(node, parents)
        if name == "from_numpy":
            if _marked(lines, node, HOST_MARK):
                continue
            if getattr(function, "name", None) in CONSTRUCTION and _moved_at_once(node, parents):
                continue
            found.append((node.lineno, ast.get_source_segment(source, node) or f"{name}(...)"))
            continue
        if _passes_device(node) or _moved_at_once(node, parents) or _made_a_module_tensor(node, parents, function):
            continue
        found.append((node.lineno, ast.get_source_segment(source, node) or f"{name}(...)"))
    return sorted(found)


def scope_files(root: Path) -> Iterable[Path]:
    """Every module of `SCOPE` under `root`."""
    for entry in SCOPE:
        path = root / entry
        yield from [path] if path.suffix == ".py" else sorted(path.rglob("*.py"))


def report(root: Path) -> List[str]:
    """One line per offending call under `root`: ``path:line: call``."""
    out = []
    for path in scope_files(root):
        for line, call in offending_calls(path.read_text()):
            first = call.splitlines()[0]
            why = (
                f"copies host memory per call (mark '{HOST_MARK} why' where the data lives on the host)"
                if "from_numpy" in first
                else f"names no device (pass device=, move it at once, use *_like / .new_*, or mark '{MARK} why')"
            )
            out.append(f"{path.relative_to(root)}:{line}: {first} {why}")
    return out


def main() -> int:
    lines = report(Path(__file__).resolve().parent.parent)
    print("\n".join(lines) if lines else "device factories: every tensor factory in scope names its device")
    return 1 if lines else 0


if __name__ == "__main__":
    sys.exit(main())
