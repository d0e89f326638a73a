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
