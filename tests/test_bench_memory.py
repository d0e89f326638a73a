"""Peak memory of a benchmarked command is its own, not the benchmark process's (Linux fork+exec inherits maxrss)."""

from __future__ import annotations

import subprocess
import sys

import pytest

from agrinerf_ns.ns_commands import TreeMemory, _wait

pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")

_CHILD = "import time; x = bytearray({mib} * 2**20); time.sleep(1.0)"


def _peak_mib(code: str) -> float:
    proc = subprocess.Popen([sys.executable, "-c", code])
    memory = TreeMemory(proc.pid)
    assert _wait(proc, 60.0, memory) == 0
    return memory.peak_kib / 1024.0


def test_child_peak_ignores_the_parents_memory() -> None:
    ballast = bytearray(600 * 2**20)  # the parent's resident set: 600 MiB more than the child ever uses
    try:
        peak = _peak_mib(_CHILD.format(mib=150))
    finally:
        del ballast
    assert 150 <= peak < 400, peak


def test_grandchildren_count_towards_the_peak() -> None:
    grandchild = _CHILD.format(mib=200)
    code = f"import subprocess, sys; subprocess.run([sys.executable, '-c', {grandchild!r}], check=True)"
    assert _peak_mib(code) >= 200
