"""scripts/install_system.sh (run by scripts/install.sh): as root with apt-get it installs the missing system packages
(the libraries of agrinerf_ns.system_deps.SYSTEM_LIBRARIES, Chromium with --dev), otherwise it says what to run. Run
against stub ``id``, ``ldconfig``, ``apt-get`` and ``chromium`` on an otherwise empty PATH, so nothing is installed."""

from __future__ import annotations

import re
import subprocess
from pathlib import Path
from typing import List, Tuple

import pytest

from agrinerf_ns import system_deps

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "install_system.sh"
SYSTEM_LIBS = ("libusb-1.0.so.0", "libEGL.so.1", "libGL.so.1", "libOpenGL.so.0")
"""What a machine set up for open3d and pymeshlab has in ldconfig's cache (a minimal Debian had none of them)."""
SYSTEM_PACKAGES = "libusb-1.0-0 libegl1 libgl1 libopengl0"


def test_the_script_installs_the_libraries_system_deps_checks() -> None:
    """The shell list (the script runs before and without the venv) is system_deps' table, entry for entry."""
    text = SCRIPT.read_text()
    entries = re.findall(r"(lib[\w.+-]+\.so\.\d+):([\w.+-]+):(\w+)", text)
    assert {soname: (debian, user) for soname, debian, user in entries} == {
        soname: (debian, user) for soname, (debian, _, user) in system_deps.SYSTEM_LIBRARIES.items()
    }
    assert SYSTEM_LIBS == tuple(system_deps.SYSTEM_LIBRARIES)
    assert SYSTEM_PACKAGES == " ".join(debian for debian, _, _ in system_deps.SYSTEM_LIBRARIES.values())


def _stub(folder: Path, name: str, body: str) -> None:
    path = folder / name
    path.write_text(f"#!/bin/bash\n{body}\n")
    path.chmod(0o755)


def _run(
    tmp_path: Path,
    *args: str,
    uid: int = 0,
    apt: bool = True,
    apt_fails: bool = False,
    libs: Tuple[str, ...] = (),
    chromium: bool = False,
) -> Tuple[int, str, List[str]]:
    """Run the script with stubs; returns (exit code, stderr, the apt-get calls as 'DEBIAN_FRONTEND=... args')."""
    stubs, log = tmp_path / "bin", tmp_path / "apt.log"
    stubs.mkdir()
    _stub(stubs, "id", f"echo {uid}")
    lines = "".join(f"; echo '\t{lib} (libc6,x86-64) => /lib/x86_64-linux-gnu/{lib}'" for lib in libs)
    _stub(stubs, "ldconfig", f"echo '{len(libs)} libs found in cache'{lines}")
    if apt:
        _stub(stubs, "apt-get", f'echo "DEBIAN_FRONTEND=${{DEBIAN_FRONTEND:-}} $*" >> {log}; exit {int(apt_fails)}')
    if chromium:
        _stub(stubs, "chromium", "true")
    command = ["/bin/bash", str(SCRIPT), *args]
    result = subprocess.run(command, env={"PATH": str(stubs)}, capture_output=True, text=True, timeout=30, check=False)
    return result.returncode, result.stderr, log.read_text().splitlines() if log.exists() else []


def test_root_with_apt_installs_what_is_missing(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, "--dev")
    assert rc == 0, err
    assert calls == [
        "DEBIAN_FRONTEND= update -qq",
        f"DEBIAN_FRONTEND=noninteractive install -y -qq --no-install-recommends {SYSTEM_PACKAGES} chromium",
    ]


@pytest.mark.parametrize(
    ("args", "chromium"),
    [(("--dev",), True), ((), False)],  # Chromium is only wanted with --dev
)
def test_nothing_missing_runs_no_apt_get(tmp_path: Path, args: Tuple[str, ...], chromium: bool) -> None:
    rc, err, calls = _run(tmp_path, *args, libs=SYSTEM_LIBS, chromium=chromium)
    assert (rc, err, calls) == (0, "", [])


def test_only_the_missing_packages_are_installed(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, "--dev", libs=SYSTEM_LIBS)
    assert rc == 0, err
    assert calls[-1].endswith("--no-install-recommends chromium")
    (tmp_path / "egl").mkdir()
    rc, err, calls = _run(tmp_path / "egl", libs=("libusb-1.0.so.0", "libGL.so.1", "libOpenGL.so.0"))  # no libEGL
    assert rc == 0, err
    assert calls[-1].endswith("--no-install-recommends libegl1")


def test_not_root_says_what_to_run(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, uid=1000)
    assert rc == 1 and calls == []
    assert f"run 'sudo apt-get install {SYSTEM_PACKAGES}'" in err


def test_without_apt_get_says_what_is_missing(tmp_path: Path) -> None:
    rc, err, _ = _run(tmp_path, "--dev", apt=False)
    assert rc == 1
    assert "missing libusb-1.0-0 (open3d: ns-export) libegl1 (open3d: ns-export) libgl1 (open3d: ns-export)" in err
    assert "libopengl0 (pymeshlab: ns-export)" in err
    assert "chromium (the viewer test)" in err


def test_failed_apt_get_is_reported(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, apt_fails=True)
    assert rc == 1 and calls == ["DEBIAN_FRONTEND= update -qq"]
    assert f"apt-get could not install {SYSTEM_PACKAGES}" in err
