"""Training on a CPU without paying the kernel for every large tensor, every step.

glibc serves each allocation above its mmap threshold (at most 32 MiB) with a fresh ``mmap`` and returns it with
``munmap`` when freed. A training step at the paper's grids allocates and frees hundreds of such tensors (the blurred and
event renders' samples), so every step faults about a million fresh pages in and zero-fills them: on a 2-core CPU more
than half of a step was system time (docs/benchmark.md, CPU allocator). `keep_freed_memory` tells glibc to serve large
blocks from its heap and to keep what is freed there, so later steps reuse the pages already mapped. The price is a
higher resident peak (the heap does not shrink back), measured beside the speed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
from functools import lru_cache

import torch

M_TRIM_THRESHOLD = -1
"""glibc ``mallopt`` parameter: free heap top kept before it is returned to the system (-1 in malloc.h)."""
M_MMAP_MAX = -4
"""glibc ``mallopt`` parameter: how many blocks may be served by mmap at once (0: none)."""
NEVER = -1
"""As glibc reads it (a size_t), the largest threshold: freed heap memory is never trimmed."""


def keep_freed_memory(device: torch.device) -> bool:
    """When `device` is the CPU: make this process's glibc allocator keep freed memory for reuse (large blocks from
    the heap, no trimming), once per process; the setting lasts for the process's life.

    Returns whether it is in effect: False for another device, or where the C library is not glibc (musl, macOS),
    which keeps its default."""
    return device.type == "cpu" and _set_glibc_options()


@lru_cache(maxsize=1)
def _set_glibc_options() -> bool:
    name = ctypes.util.find_library("c")
    if name is None:
        return False
    try:
        libc = ctypes.CDLL(name)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = [ctypes.c_int, ctypes.c_int]
    mallopt.restype = ctypes.c_int
    trimmed = mallopt(M_TRIM_THRESHOLD, NEVER) == 1
    return bool(mallopt(M_MMAP_MAX, 0) == 1 and trimmed)
