"""The static device check (``scripts/device_factories.py``) names each kind of CPU-on-CUDA factory it claims to, in
source strings and planted in a copy of a real module, and passes the real tree."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "scripts"))
try:
    from device_factories import HOST_SIDE, SCOPE, offending_calls, report, scope_files
finally:
    sys.path.pop(0)

PLANTED = {
    "dtype-only move": "import torch\ndef f(x):\n    return x + torch.zeros(3).to(torch.float64)\n",
    "device=None": "import torch\ndef f(x):\n    return x + torch.ones(3, device=None)\n",
    "from torch import": "from torch import tensor\ndef f(x):\n    return x + tensor([1.0, 2.0, 3.0])\n",
    "module alias": "import torch as th\ndef f(x):\n    return x + th.ones(3)\n",
    "torch.Tensor constructor": "import torch\ndef f(x):\n    return x + torch.Tensor([1.0, 2.0, 3.0])\n",
    "torch.normal": "import torch\ndef f(x):\n    return x + torch.normal(0.0, 1.0, (3,))\n",
    "plain attribute in __init__": (
        "import torch\nclass Part(torch.nn.Module):\n    def __init__(self):\n        super().__init__()\n"
        "        self.offset = torch.zeros(3)\n    def forward(self, x):\n        return x + self.offset\n"
    ),
    "device='cpu' spelt out": "import torch\ndef f(x):\n    return x + torch.ones(3, device='cpu').to('cpu')\n",
    "per-step from_numpy moved": (
        "import numpy as np\nimport torch\ndef f(x, a):\n    return x + torch.from_numpy(np.asarray(a)).to(x.device)\n"
    ),
}
"""The planted cases of issue 61 (and a CPU device spelt out), each a bug on a GPU run (or a host copy per step) that
the old check let pass."""

CLEARED = (
    "import numpy as np\nimport torch\nfrom torch import nn\n"
    "class Part(nn.Module):\n"
    "    def __init__(self, a):\n"
    "        super().__init__()\n"
    "        self.register_buffer('b', torch.zeros(3))\n"
    "        w = torch.randn(4)\n"
    "        self.w = nn.Parameter(torch.cat([w, w]))\n"
    "        self.c = torch.from_numpy(np.asarray(a)).to(self.b.device)\n"  # construction: one copy
    "    def forward(self, x):\n"
    "        y = torch.zeros(2, device=x.device)\n"
    "        z = torch.rand(2).float().to(x.device)\n"
    "        v = torch.ones(2, dtype=torch.bool).to(device=x.device)\n"
    "        u = torch.ones(2)  # cpu: on purpose\n"
    "        return x.new_zeros(2) + torch.zeros_like(x) + y + z + v + u\n"
)
"""Calls the rules clear: a device given or moved to at once, a buffer or parameter, a mark."""


@pytest.mark.parametrize("case", sorted(PLANTED))
def test_each_planted_case_is_named(case: str) -> None:
    found = offending_calls(PLANTED[case])
    assert len(found) == 1, found


def test_cleared_forms_are_not_named() -> None:
    assert offending_calls(CLEARED) == []


def test_a_call_over_several_lines_and_a_module_constant_are_named() -> None:
    source = (
        "import torch\nSCALE = torch.tensor([1.0, 2.0])\ndef f(x):\n    return x * torch.linspace(\n        0, 1, 5)\n"
    )
    assert [line for line, _ in offending_calls(source)] == [2, 4]


@pytest.mark.parametrize("case", sorted(PLANTED))
def test_each_planted_case_fails_the_check_of_a_copied_tree(case: str, tmp_path: Path) -> None:
    """Planted at the end of a copy of a real per-step module (the event stream, which the old check did not read),
    the report over the copied tree names exactly the planted line."""
    for entry in (*SCOPE, *HOST_SIDE):
        source = ROOT / entry
        target = tmp_path / entry
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, target, dirs_exist_ok=True)
        else:
            shutil.copy(source, target)
    assert report(tmp_path) == []
    module = tmp_path / "dataparsers" / "event_stream.py"
    planted = PLANTED[case].replace("def f(", "def planted_f(").replace("class Part", "class PlantedPart")
    module.write_text(module.read_text() + "\n\n" + planted)
    lines = report(tmp_path)
    assert len(lines) == 1 and lines[0].startswith("dataparsers/event_stream.py:"), lines


def test_the_real_tree_passes_and_the_scope_holds_the_per_step_modules() -> None:
    assert report(ROOT) == []
    files = {p.relative_to(ROOT).as_posix() for p in scope_files(ROOT)}
    assert {"dataparsers/event_stream.py", "agrinerf_ns/trajectory.py", "agrinerf_ns/model/model.py"} <= files
    assert "agrinerf_ns/count/render.py" in files
