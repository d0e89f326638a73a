"""Where a render may branch on its data.

Pruning empty samples (``x[mask]``, ``bool(mask.all())``, the share of selected samples) reads a result back to the
host. On the CPU that costs nothing and saves the work on the pruned samples; on a GPU every read-back stalls the
queue of kernels until it drains, and the work it saves is cheap there. So the renders prune on the CPU only and run
every sample, masked after, elsewhere: the same values either way (a masked sample contributes zero).
"""

from __future__ import annotations

from torch import Tensor


def prune_on(like: Tensor) -> bool:
    """Whether renders on `like`'s device prune samples by their data (the CPU: yes; a GPU: no)."""
    return like.device.type == "cpu"
