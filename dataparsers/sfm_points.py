"""SfM points of a dataset (``ply_file_path`` in ``transforms.json``, e.g. ns-process-data's ``sparse_pc.ply``), read
with NumPy.

Nerfstudio reads them through open3d, whose import needs the system library libusb (absent on many servers), and the
other PLY reader it brings, plyfile, is GPL-3.0: so this module reads the vertex element of an ASCII or binary PLY
itself. It reads what a point cloud needs (``x y z`` and, when present, ``red green blue``) and says which file and
what is wrong otherwise.
"""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import torch
from jaxtyping import Float, UInt8
from torch import Tensor

PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2", "ushort": "u2",
    "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4", "float": "f4", "float32": "f4",
    "double": "f8", "float64": "f8",
}  # fmt: skip
"""PLY scalar type names -> NumPy type codes (without byte order)."""

GREY = 128
"""The colour given to points of a file without colours."""


class PlyError(ValueError):
    """A PLY file this reader cannot read: the message names the file."""


def _header(path: Path, data: bytes) -> Tuple[str, List[Tuple[str, int, List[Tuple[str, str]]]], int]:
    """(format, [(element, count, [(property, type code)])], byte offset of the body)."""
    end = data.find(b"end_header")
    if not data.startswith(b"ply") or end < 0:
        raise PlyError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header')")
    body = data.index(b"\n", end) + 1
    fmt = ""
    elements: List[Tuple[str, int, List[Tuple[str, str]]]] = []
    for raw in data[:end].decode("ascii", errors="replace").splitlines()[1:]:
        words = raw.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                elements[-1][2].append((words[-1], "list"))
            elif words[1] in PLY_TYPES:
                elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
            else:
                raise PlyError(f"{path}: unknown PLY property type {words[1]!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise PlyError(f"{path}: unknown PLY format {fmt!r}")
    return fmt, elements, body


def read_ply_points(path: Path) -> Tuple[Float[np.ndarray, "n 3"], UInt8[np.ndarray, "n 3"]]:
    """The vertices of a PLY file: positions (float64) and colours (uint8; grey where the file has none)."""
    path = Path(path)
    data = path.read_bytes()
    fmt, elements, offset = _header(path, data)
    names = [e[0] for e in elements]
    if "vertex" not in names:
        raise PlyError(f"{path}: no 'vertex' element")
    before = elements[: names.index("vertex")]
    _, count, props = elements[names.index("vertex")]
    if any(kind == "list" for _, kind in props) or any(kind == "list" for e in before for _, kind in e[2]):
        raise PlyError(f"{path}: list properties before or in the vertex element are not supported")
    prop_names = [p for p, _ in props]
    if not {"x", "y", "z"} <= set(prop_names):
        raise PlyError(f"{path}: the vertex element has no x, y, z properties ({prop_names})")
    if fmt == "ascii":
        lines = data[offset:].decode("ascii", errors="replace").splitlines()
        skip = sum(e[1] for e in before)
        rows = [line.split() for line in lines[skip : skip + count]]
        if len(rows) < count or any(len(r) < len(props) for r in rows):
            raise PlyError(f"{path}: {count} vertices announced, fewer (or short rows) found")
        table = np.asarray([r[: len(props)] for r in rows], dtype=np.float64).reshape(count, len(props))
        column: Dict[str, np.ndarray] = {p: table[:, i] for i, p in enumerate(prop_names)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        offset += sum(e[1] * np.dtype([(p, order + k) for p, k in e[2]]).itemsize for e in before)
        dtype = np.dtype([(p, order + k) for p, k in props])
        if len(data) - offset < count * dtype.itemsize:
            raise PlyError(f"{path}: {count} vertices announced, the file ends before them")
        records = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        column = {p: records[p] for p in prop_names}
    xyz = np.stack([column[a].astype(np.float64) for a in ("x", "y", "z")], axis=-1)
    if {"red", "green", "blue"} <= set(prop_names):
        rgb = np.stack([column[c] for c in ("red", "green", "blue")], axis=-1)
        if rgb.dtype.kind == "f" and float(np.nanmax(rgb, initial=0.0)) <= 1.0:
            rgb = rgb * 255.0  # float colours in [0, 1]
        colours = np.clip(np.round(rgb.astype(np.float64)), 0, 255).astype(np.uint8)
    else:
        colours = np.full((count, 3), GREY, dtype=np.uint8)
    return xyz, colours


LEGACY_COLMAP_APPLIED = [[0.0, 1.0, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0], [0.0, 0.0, -1.0, 0.0]]
"""The ``applied_transform`` Nerfstudio's parser assumes for a dataset with ``colmap/sparse/0`` but no
``applied_transform`` (made by ns-process-data before it wrote the field)."""


def saved_to_output(
    meta: Dict[str, object], data_dir: Path, dataparser_transform: Float[Tensor, "3 4"]
) -> Float[Tensor, "3 4"]:
    """The transform from a dataset's saved coordinates (its poses and its PLY, which ns-process-data writes after
    its ``applied_transform``) to the dataparser's: ``dataparser_transform`` (from the original coordinates) with the
    applied transform undone, as Nerfstudio's parser moves its points."""
    applied = meta.get("applied_transform")
    if applied is None and (data_dir / "colmap" / "sparse" / "0").exists():
        applied = LEGACY_COLMAP_APPLIED
    if applied is None:
        return dataparser_transform
    bottom = torch.tensor([[0.0, 0.0, 0.0, 1.0]], dtype=torch.float64)
    full = torch.cat([dataparser_transform.double().cpu(), bottom])
    applied4 = torch.cat([torch.as_tensor(applied, dtype=torch.float64), bottom])
    return (full @ torch.linalg.inv(applied4))[:3].to(dataparser_transform.dtype)


def load_points3d(path: Path, transform: Float[Tensor, "3 4"], scale: float) -> Dict[str, Tensor]:
    """A PLY's points moved into the dataparser's world (``scale * (R p + t)``, `transform` from the saved
    coordinates: :func:`saved_to_output`) as
    Nerfstudio's ``points3D_xyz`` (float32 [n, 3]) and ``points3D_rgb`` (uint8 [n, 3]) metadata."""
    xyz, rgb = read_ply_points(path)
    transform64 = transform.double().cpu()
    moved = (torch.from_numpy(xyz) @ transform64[:3, :3].T + transform64[:3, 3]) * float(scale)
    return {"points3D_xyz": moved.float(), "points3D_rgb": torch.from_numpy(rgb)}
