"""Reader of TUM odometry files ("t tx ty tz qx qy qz qw" per line: the capture's ``odometry.txt`` and
``truth/poses.txt``)."""

from __future__ import annotations

from pathlib import Path
from typing import Tuple

import numpy as np
from jaxtyping import Float

from agrinerf_ns.process.errors import RawInputError

_TUM_FIELDS = ("t", "tx", "ty", "tz", "qx", "qy", "qz", "qw")
"""The names of a TUM line's eight values, in order (for error messages)."""


def read_tum(path: Path) -> Tuple[Float[np.ndarray, " n"], Float[np.ndarray, "n 4 4"]]:
    """Read a TUM trajectory "t tx ty tz qx qy qz qw" -> (times, 4x4 camera-to-world matrices).

    Raises :class:`RawInputError` naming the file and the 1-based line of a malformed row: not 8 numbers, a NaN or
    infinite value (``float()`` accepts "nan" and "inf", which would otherwise become a NaN pose), or a zero
    quaternion.
    """
    if not path.is_file():
        raise RawInputError(f"{path}: pose file missing")
    rows = []
    linenos = []  # the file line of each row (comments and blank lines are skipped), for the messages below
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        parts = line.split()
        try:
            vals = [float(v) for v in parts]
        except ValueError as err:
            raise RawInputError(f"{path}:{lineno}: non-numeric value in {line!r}") from err
        if len(vals) != 8:
            raise RawInputError(f"{path}:{lineno}: expected 8 values 't tx ty tz qx qy qz qw', got {len(vals)}")
        bad = [name for name, v in zip(_TUM_FIELDS, vals, strict=True) if not np.isfinite(v)]
        if bad:
            raise RawInputError(f"{path}:{lineno}: value not finite ({', '.join(bad)}) in {line!r}")
        rows.append(vals)
        linenos.append(lineno)
    if not rows:
        raise RawInputError(f"{path}: no poses")
    arr = np.asarray(rows, dtype=np.float64)
    q = arr[:, 4:8]
    norm = np.linalg.norm(q, axis=1)
    if np.any(norm < 1e-8):
        raise RawInputError(f"{path}:{linenos[int(np.argmin(norm))]}: zero quaternion")
    q = q / norm[:, None]
    c2w = np.tile(np.eye(4), (arr.shape[0], 1, 1))
    c2w[:, :3, :3] = quat_xyzw_to_rotmat(q)
    c2w[:, :3, 3] = arr[:, 1:4]
    return arr[:, 0], c2w


def quat_xyzw_to_rotmat(q: Float[np.ndarray, "n 4"]) -> Float[np.ndarray, "n 3 3"]:
    """Unit quaternions (x, y, z, w) to rotation matrices."""
    x, y, z, w = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack(
        [
            np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
            np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
            np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1),
        ],
        axis=1,
    )
