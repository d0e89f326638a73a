"""scripts/install_system.sh (run by scripts/install.sh): as root with apt-get it installs the missing system packages
(libusb for open3d, Chromium with --dev), otherwise it says what to run. Run against stub ``id``, ``ldconfig``,
``apt-get`` and ``chromium`` on an otherwise empty PATH, so nothing is installed."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import List, Tuple

import pytest

SCRIPT = Path(__file__).resolve().parents[1] / "scripts" / "install_system.sh"
LIBUSB_LINE = "\tlibusb-1.0.so.0 (libc6,x86-64) => /lib/x86_64-linux-gnu/libusb-1.0.so.0"


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
    libusb: bool = False,
    chromium: bool = False,
) -> Tuple[int, str, List[str]]:
    """Run the script with stubs; returns (exit code, stderr, the apt-get calls as 'DEBIAN_FRONTEND=... args')."""
    stubs, log = tmp_path / "bin", tmp_path / "apt.log"
    stubs.mkdir()
    _stub(stubs, "id", f"echo {uid}")
    _stub(stubs, "ldconfig", f"echo '1 libs found in cache'; {'echo ' + repr(LIBUSB_LINE) if libusb else ''}")
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
        "DEBIAN_FRONTEND=noninteractive install -y -qq --no-install-recommends libusb-1.0-0 chromium",
    ]


@pytest.mark.parametrize(
    ("args", "libusb", "chromium"),
    [(("--dev",), True, True), ((), True, False)],  # Chromium is only wanted with --dev
)
def test_nothing_missing_runs_no_apt_get(tmp_path: Path, args: Tuple[str, ...], libusb: bool, chromium: bool) -> None:
    rc, err, calls = _run(tmp_path, *args, libusb=libusb, chromium=chromium)
    assert (rc, err, calls) == (0, "", [])


def test_only_the_missing_package_is_installed(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, "--dev", libusb=True)
    assert rc == 0, err
    assert calls[-1].endswith("--no-install-recommends chromium")


def test_not_root_says_what_to_run(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, uid=1000)
    assert rc == 1 and calls == []
    assert "run 'sudo apt-get install libusb-1.0-0'" in err


def test_without_apt_get_says_what_is_missing(tmp_path: Path) -> None:
    rc, err, _ = _run(tmp_path, "--dev", apt=False)
    assert rc == 1
    assert "missing libusb-1.0-0 (open3d: ns-export) chromium (the viewer test)" in err


def test_failed_apt_get_is_reported(tmp_path: Path) -> None:
    rc, err, calls = _run(tmp_path, apt_fails=True)
    assert rc == 1 and calls == ["DEBIAN_FRONTEND= update -qq"]
    assert "apt-get could not install libusb-1.0-0" in err
