"""A checkout laid out as installed (`link_installed_layout`): its package and its own Nerfstudio entry points."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from agrinerf_ns.source_tree import link_installed_layout

REPO = Path(__file__).resolve().parents[1]

PROBE = """
import json
from importlib.metadata import entry_points
import agrinerf_ns
print(json.dumps({"methods": sorted(e.name for e in entry_points(group="nerfstudio.method_configs")),
                  "package": agrinerf_ns.__file__}))
"""


def test_a_checkout_layout_advertises_that_checkouts_methods(tmp_path: Path) -> None:
    """An older checkout that lacks a method the installed version has: Nerfstudio must not look for it there."""
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    pyproject = (REPO / "pyproject.toml").read_text()
    dropped = 'evdeblurnerf-windowed-lite = "agrinerf_ns.method_configs.agrinerf_methods:evdeblurnerf_windowed_lite"\n'
    assert dropped in pyproject
    (checkout / "pyproject.toml").write_text(pyproject.replace(dropped, ""))
    for name in ("agrinerf_ns", "dataparsers", "method_configs"):
        os.symlink(REPO / name, checkout / name)
    layout = link_installed_layout(checkout, tmp_path / "layout")
    env = dict(os.environ, PYTHONPATH=str(layout))
    probe = [sys.executable, "-c", PROBE]  # from tmp_path: a pip build leaves an egg-info in the checkout root
    out = subprocess.run(probe, env=env, cwd=tmp_path, capture_output=True, text=True, check=True).stdout
    found = json.loads(out.strip().splitlines()[-1])
    assert "evdeblurnerf-windowed-lite" not in found["methods"]
    assert {"agrinerf", "agrinerf-lite", "evdeblurnerf-windowed"} <= set(found["methods"])
    assert found["package"].startswith(str(layout))
