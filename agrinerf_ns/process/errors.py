"""The error every reader and step of ``agrinerf-process`` raises on bad raw input."""

from __future__ import annotations


class RawInputError(ValueError):
    """A raw capture file is missing, unreadable or inconsistent. The message names the file."""
