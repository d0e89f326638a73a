"""The CPU allocator setting that training turns on: freed large blocks are reused, not faulted in again."""

from __future__ import annotations

import json
import platform
import subprocess
import sys

import pytest
import torch

from agrinerf_ns.cpu_memory import keep_freed_memory

PROBE = """
import json, resource, torch
from agrinerf_ns.cpu_memory import keep_freed_memory

def faults():  # five rounds of two 48 MiB tensors and their sum, as a training step's temporaries
    start = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    for _ in range(5):
        a = torch.ones(12 * 2**20)
        b = torch.ones(12 * 2**20) + a
        del a, b
    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - start

default = faults()
kept = keep_freed_memory(torch.device("cpu"))
faults()  # the first round after the setting maps the heap once
# the least of three rounds: a busy machine's reclaim can add faults to one round (a fault never goes missing)
print(json.dumps({"default": default, "kept": kept, "after": min(faults() for _ in range(3))}))
"""


@pytest.mark.skipif(platform.libc_ver()[0] != "glibc", reason="the setting is glibc's")
def test_freed_large_tensors_are_reused_without_page_faults() -> None:
    """In a fresh process: each 48 MiB tensor costs about 12k page faults by default, none once memory is kept."""
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, check=True).stdout
    result = json.loads(out.strip().splitlines()[-1])
    assert result["kept"] is True
    assert result["default"] > 15 * 10_000, result
    assert result["after"] < result["default"] / 50, result


def test_other_devices_are_left_alone() -> None:
    assert keep_freed_memory(torch.device("meta")) is False
