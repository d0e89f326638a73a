"""Checkpoints of older runs: the state-dict names they used, and the state they did not save."""

from __future__ import annotations

from typing import Any, Dict

OLD_STATE_NAMES = {"log_event_threshold": "events.log_threshold", "event_crf.": "events.crf."}
"""State-dict names of runs before the event term became a part (old prefix -> new)."""


def load_old_state(model: Any, state_dict: Dict[str, Any], prefix: str, *args: Any) -> None:
    """Load the checkpoint of a run before the event term became a part: its learnt thresholds and event response
    under their new names, and the `noise` weighting's running means (not saved then) at their start."""
    for key in list(state_dict):
        for old, new in OLD_STATE_NAMES.items():
            if key.startswith(prefix + old):
                state_dict[prefix + new + key[len(prefix + old) :]] = state_dict.pop(key)
    if model.events is not None:
        for name, buffer in model.events.named_buffers():
            state_dict.setdefault(f"{prefix}events.{name}", buffer.clone())
