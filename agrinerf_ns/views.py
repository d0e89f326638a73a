"""Choosing a subset of a capture's views."""

from __future__ import annotations

from typing import List, Optional

import numpy as np


def evenly_spaced(total: int, count: Optional[int]) -> List[int]:
    """Indices of ``count`` of ``total`` views spread evenly from the first to the last (all when ``count`` is
    None or at least ``total``; at least one when ``total`` > 0)."""
    if total <= 0:
        return []
    count = total if count is None else max(1, min(count, total))
    return sorted({int(i) for i in np.linspace(0, total - 1, count).round()})
