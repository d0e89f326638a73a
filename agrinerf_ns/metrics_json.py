"""Metrics files as strict JSON: a metric without a value is ``null``, and its reason is written beside it.

Python's ``json`` writes a NaN as a bare ``NaN``, which strict JSON readers (JavaScript's ``JSON.parse``, ``jq``,
most non-Python tools) refuse. :func:`strict_dumps` writes it as ``null`` and adds, to the object that holds it, an
``"unavailable"`` object mapping the key to why (LPIPS without its weights; any other metric: not finite).
"""

from __future__ import annotations

import json
import math
from typing import Any, Dict

UNAVAILABLE_KEY = "unavailable"
"""Key of the object that gives, per ``null`` metric of the same object, why it has no value."""


def null_reason(key: str) -> str:
    """Why the metric ``key`` has no value."""
    if key.startswith("lpips"):
        from agrinerf_ns import compat

        if compat.lpips_shim_needed():
            return (
                f"LPIPS unavailable: its AlexNet weights ({compat.ALEXNET_WEIGHTS}) are not in "
                f"{compat.alexnet_weights_path().parent}, and nothing is downloaded unless {compat.DOWNLOAD_ENV}=1"
            )
    return "not finite (NaN or infinite) on the evaluated views"


def strict(value: Any) -> Any:
    """A copy of ``value`` (dicts, lists, numbers, strings) with every non-finite float replaced by None; each dict
    holding one gains :data:`UNAVAILABLE_KEY` with the reasons (:func:`null_reason`)."""
    if isinstance(value, dict):
        out: Dict[str, Any] = {}
        reasons: Dict[str, str] = dict(value.get(UNAVAILABLE_KEY) or {})
        for key, item in value.items():
            if isinstance(item, float) and not math.isfinite(item):
                out[key] = None
                reasons.setdefault(str(key), null_reason(str(key)))
            elif key != UNAVAILABLE_KEY:
                out[key] = strict(item)
        if reasons:
            out[UNAVAILABLE_KEY] = reasons
        return out
    if isinstance(value, (list, tuple)):
        return [None if isinstance(v, float) and not math.isfinite(v) else strict(v) for v in value]
    return value


def strict_dumps(value: Any, **kwargs: Any) -> str:
    """``json.dumps`` of :func:`strict` ``(value)``; never writes NaN or Infinity (``allow_nan=False``)."""
    return json.dumps(strict(value), allow_nan=False, **{k: v for k, v in kwargs.items() if k != "allow_nan"})
