"""Choosing a subset of a capture's views, and how many of a view's rays to render at once."""

from __future__ import annotations

from typing import List, Optional

import numpy as np

CPU_RAYS_PER_CHUNK = 1024
"""Rays rendered at once when a whole view is rendered for evaluation on a CPU (``eval_num_rays_per_chunk``; the image
does not depend on it): smaller than the configs' GPU-sized chunks because on a CPU it renders faster and with far
less memory (measured with ``benchmarks/bench_render_chunks.py``: results/render-chunks/README.md)."""


def rays_per_chunk(requested: Optional[int] = None) -> Optional[int]:
    """``requested`` if given; else :data:`CPU_RAYS_PER_CHUNK` without a GPU, and None (the run config's, sized for
    a GPU) with one."""
    if requested is not None:
        return requested
    import torch

    return None if torch.cuda.is_available() else CPU_RAYS_PER_CHUNK


def evenly_spaced(total: int, count: Optional[int]) -> List[int]:
    """Indices of ``count`` of ``total`` views spread evenly from the first to the last (all when ``count`` is
    None or at least ``total``; at least one when ``total`` > 0)."""
    if total <= 0:
        return []
    count = total if count is None else max(1, min(count, total))
    return sorted({int(i) for i in np.linspace(0, total - 1, count).round()})
