"""Metrics files as strict JSON: a metric without a value is ``null``, and its reason is written beside it.

Python's ``json`` writes a NaN as a bare ``NaN``, which strict JSON readers (JavaScript's ``JSON.parse``, ``jq``,
most non-Python tools) refuse. :func:`strict_dumps` writes it as ``null`` and adds, to the object that holds it, an
``"unavailable"`` object mapping the key to why (the caller's reason, e.g.
:func:`agrinerf_ns.compat.metric_null_reason` for LPIPS without its weights; by default: not finite).
"""

from __future__ import annotations

import json
import math
from typing import Any, Callable, Dict

UNAVAILABLE_KEY = "unavailable"
"""Key of the object that gives, per ``null`` metric of the same object, why it has no value."""


NOT_FINITE = "not finite (NaN or infinite) on the evaluated views"
"""The reason given for a null metric when no better one is known."""


def not_finite(key: str) -> str:
    """The default reason for a null metric ``key``."""
    return NOT_FINITE


def strict(value: Any, reason: Callable[[str], str] = not_finite) -> Any:
    """A copy of ``value`` (dicts, lists, numbers, strings) with every non-finite float replaced by None; each dict
    holding one gains :data:`UNAVAILABLE_KEY` with the reasons (``reason(key)``)."""
    if isinstance(value, dict):
        out: Dict[str, Any] = {}
        reasons: Dict[str, str] = dict(value.get(UNAVAILABLE_KEY) or {})
        for key, item in value.items():
            if isinstance(item, float) and not math.isfinite(item):
                out[key] = None
                reasons.setdefault(str(key), reason(str(key)))
            elif key != UNAVAILABLE_KEY:
                out[key] = strict(item, reason)
        if reasons:
            out[UNAVAILABLE_KEY] = reasons
        return out
    if isinstance(value, (list, tuple)):
        return [None if isinstance(v, float) and not math.isfinite(v) else strict(v, reason) for v in value]
    return value


def strict_dumps(value: Any, reason: Callable[[str], str] = not_finite, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`strict` ``(value, reason)``; never writes NaN or Infinity (``allow_nan=False``)."""
    return json.dumps(strict(value, reason), allow_nan=False, **{k: v for k, v in kwargs.items() if k != "allow_nan"})
