"""The parser of the capture's time lists: one file name and its time(s) in seconds per line.

``rgb/timestamps.txt`` ("<file name> <time>"), ``rgb/exposures.txt`` ("<file name> <exposure start> <exposure end>")
and an ECD folder's ``images.txt`` ("<time> <image path>") are such lists. Blank lines and lines starting with ``#``
are skipped; every other line must have the listed columns, and its times must be finite numbers.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import List, Sequence, Tuple

import numpy as np

from agrinerf_ns.process.errors import RawInputError


@dataclass(frozen=True)
class TimeListLine:
    """One line of a time list: its number in the file (from 1), the file name and the times (seconds)."""

    lineno: int
    name: str
    times: Tuple[float, ...]


def read_time_list(path: Path, columns: Sequence[str], name_column: int = 0, what: str = "time") -> List[TimeListLine]:
    """The lines of the time list ``path``, whose columns are ``columns`` (their names, for messages), the file name
    being column ``name_column`` and every other column a time; ``what`` names the times in messages."""
    layout = " ".join(f"<{c}>" for c in columns)
    rows: List[TimeListLine] = []
    for lineno, line in enumerate(Path(path).read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        if len(parts) != len(columns):
            raise RawInputError(f"{path}:{lineno}: expected '{layout}', got {line!r}")
        fields = [p for k, p in enumerate(parts) if k != name_column]
        quoted = " ".join(repr(f) for f in fields)
        try:
            times = tuple(float(f) for f in fields)
        except ValueError as err:
            verb = "is not a number" if len(fields) == 1 else "are not numbers"
            raise RawInputError(f"{path}:{lineno}: {what} {quoted} {verb}") from err
        if not np.all(np.isfinite(times)):
            raise RawInputError(f"{path}:{lineno}: {what} {quoted} {'is' if len(fields) == 1 else 'are'} not finite")
        rows.append(TimeListLine(lineno, parts[name_column], times))
    return rows
