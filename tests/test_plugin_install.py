"""The installed distribution: entry points, namespace, import cost, and the cv2 it gets."""

from __future__ import annotations

import hashlib
import importlib.metadata as metadata
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _entry_points(group: str):
    return [ep for ep in metadata.entry_points(group=group) if ep.dist is not None and ep.dist.name == "agrinerf-ns"]


def test_method_entry_points_are_method_specifications() -> None:
    from nerfstudio.plugins.types import MethodSpecification

    eps = _entry_points("nerfstudio.method_configs")
    assert {"agrinerf", "agrinerf-lite", "evdeblurnerf", "evdeblurnerf-lite"} <= {ep.name for ep in eps}
    for ep in eps:
        spec = ep.load()
        assert isinstance(spec, MethodSpecification), ep
        assert spec.config.method_name == ep.name


def test_dataparser_entry_points_are_dataparser_specifications() -> None:
    from nerfstudio.plugins.registry_dataparser import DataParserSpecification

    eps = _entry_points("nerfstudio.dataparser_configs")
    assert eps, "the package registers its dataparser"
    for ep in eps:
        assert isinstance(ep.load(), DataParserSpecification), ep


def test_entry_point_modules_are_light_and_activate_the_shims(tmp_path: Path) -> None:
    """Every ns-* command imports these modules: they must not pull heavy optional stacks, and must apply the shims."""
    modules = sorted(
        {
            ep.value.split(":")[0]
            for group in ("nerfstudio.method_configs", "nerfstudio.dataparser_configs")
            for ep in _entry_points(group)
        }
    )
    code = (
        "import sys, importlib\n"
        f"for m in {modules!r}: importlib.import_module(m)\n"
        "from agrinerf_ns import compat\n"
        "heavy = [m for m in ('pycolmap', 'h5py', 'ultralytics', 'agrinerf_ns.synth.scene', 'agrinerf_ns.process.poses')"
        " if m in sys.modules]\n"
        "print('HEAVY', heavy)\n"
        "print('LPIPS_PATCHED', compat.lpips_patched() or not compat.lpips_shim_needed())\n"
    )
    # run outside the checkout, so that `python -c` imports the installed package, not the source tree
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = proc.stdout
    assert "HEAVY []" in out, out
    assert "LPIPS_PATCHED True" in out, out


def test_a_checkout_on_sys_path_imports_its_mapped_subpackages() -> None:
    """With the checkout root first on sys.path (a Ray worker beside the driver, `python -c` in the root), the
    package and the subpackages pyproject.toml maps from other folders all come from the checkout."""
    code = (
        "import agrinerf_ns, agrinerf_ns.dataparsers.agrinerf_dataparser as d, agrinerf_ns.method_configs as m\n"
        "print(agrinerf_ns.__file__); print(d.__file__); print(m.__file__)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=False, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-3000:]
    package, parser, configs = [Path(line).resolve() for line in proc.stdout.split()]
    assert package == ROOT / "agrinerf_ns" / "__init__.py"
    assert parser == ROOT / "dataparsers" / "agrinerf_dataparser.py"
    assert configs == ROOT / "method_configs" / "__init__.py"


def test_ns_train_lists_agrinerf() -> None:
    out = subprocess.run(["ns-train", "--help"], capture_output=True, text=True, check=True).stdout
    assert "agrinerf" in out and "nerfacto" in out


@pytest.mark.slow
def test_wheel_adds_no_generic_top_level_modules(tmp_path: Path) -> None:
    """A non-editable build installs dataparsers/ and method_configs/ under agrinerf_ns only, and every module of the
    package (built from a copy of the sources: a checkout's stale build/ folder would fill in what pyproject.toml
    leaves out)."""
    source = tmp_path / "source"
    for name in ("agrinerf_ns", "dataparsers", "method_configs"):
        shutil.copytree(ROOT / name, source / name, ignore=shutil.ignore_patterns("__pycache__"))
    for name in ("pyproject.toml", "README.md"):
        shutil.copy2(ROOT / name, source / name)
    subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "wheel",
            "--no-deps",
            "--no-build-isolation",
            "-q",
            "-w",
            str(tmp_path),
            str(source),
        ],
        check=True,
    )
    (wheel,) = tmp_path.glob("agrinerf_ns-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top_level = {name.split("/")[0] for name in names}
    assert top_level <= {"agrinerf_ns", next(n.split("/")[0] for n in names if ".dist-info/" in n)}, top_level
    assert "agrinerf_ns/dataparsers/agrinerf_dataparser.py" in names
    checkout = {str(path.relative_to(ROOT)) for path in (ROOT / "agrinerf_ns").rglob("*.py")}
    missing = sorted(checkout - set(names))
    assert not missing, f"modules the wheel leaves out (add their package to pyproject.toml's packages): {missing}"
    assert "agrinerf_ns/method_configs/agrinerf_methods.py" in names
    entry_points = next(n for n in names if n.endswith("entry_points.txt"))
    text = zipfile.ZipFile(wheel).read(entry_points).decode()
    assert "[nerfstudio.method_configs]" in text and "[nerfstudio.dataparser_configs]" in text
    assert "[torch.backends]" in text and "agrinerf_ns.quiet_warnings:torch_import_hook" in text  # quiet ns-* consoles


def test_cv2_is_the_contrib_build_with_what_the_package_uses() -> None:
    import cv2

    for name in ("ximgproc", "createCLAHE", "warpPerspective", "initUndistortRectifyMap", "undistortPoints", "remap"):
        assert hasattr(cv2, name), name
    # The compiled module on disk is the one the contrib wheel recorded (not a file from opencv-python-headless).
    dist = metadata.distribution("opencv-contrib-python-headless")
    records = {str(f): f.hash.value for f in dist.files or [] if f.hash is not None}
    binary = next(Path(cv2.__file__).parent.glob("cv2.*.so"), None) or next(Path(cv2.__file__).parent.glob("cv2*.pyd"))
    key = next(k for k in records if k.endswith(binary.name) and k.startswith("cv2/"))
    digest = hashlib.sha256(binary.read_bytes()).digest()
    import base64

    assert base64.urlsafe_b64encode(digest).rstrip(b"=").decode() == records[key]


def test_ci_runs_the_readme_test_command() -> None:
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"<!-- test-command -->\s*```(?:bash)?\n(.+?)\n```", readme, re.S)
    assert block, "README marks its test command with <!-- test-command -->"
    command = block.group(1).strip()
    lines = [ln for ln in (ROOT / ".ci" / "run").read_text().splitlines() if ln and not ln.startswith("#")]
    # CI installs nothing of its own (install.sh brings the system packages too): a fresh .venv, then the command
    assert lines[-2:] == ["rm -rf .venv", command]
