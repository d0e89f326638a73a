"""The order in which a benchmark runs its variants: rotated every round, so no variant always runs first (and gets
the cold caches, or the machine's other load at that moment, every time)."""

from __future__ import annotations

from typing import List, Sequence, TypeVar

T = TypeVar("T")


def rotated(items: Sequence[T], turn: int) -> List[T]:
    """``items`` starting at index ``turn mod len(items)`` and wrapping round (round 0 keeps the given order)."""
    shift = turn % len(items) if items else 0
    return list(items[shift:]) + list(items[:shift])
