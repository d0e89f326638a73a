"""The dataset format is one table (`agrinerf_ns/dataset_format.py`, issue 65): the processing writes its rows, the
dataparser reads them, and no other module of the package spells a per-frame file key or a metadata key of its own."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Dict, List

from test_static_checks import _modules

from agrinerf_ns import dataset_format
from agrinerf_ns.dataset_format import (
    ALIGNED_FRAMES,
    EVENT_STREAM,
    EXPOSURE_END,
    EXPOSURE_START,
    FRAME_FILES,
    FRUIT_MASK_CAMERA,
    IMAGE,
    THERMAL_TIMESTAMP,
    THERMAL_TRANSFORMS,
    TRAJECTORY,
    TRANSFORMS,
)


def _strings(tree: ast.AST) -> List[ast.Constant]:
    """The string constants of ``tree`` that are not docstrings (prose may name a key)."""
    docstrings = {id(node.body[0].value) for node in ast.walk(tree)
                  if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
                  and node.body and isinstance(node.body[0], ast.Expr)}  # fmt: skip
    docstrings |= {id(node.value) for node in ast.walk(tree) if isinstance(node, ast.Expr)}  # attribute docstrings
    return [node for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docstrings]  # fmt: skip


def _spelled(names: Dict[str, str]) -> List[str]:
    """``file:line: 'key' (row)`` for every module but the table that spells one of ``names`` (key -> its row)."""
    found = []
    table = (Path(__file__).resolve().parents[1] / "agrinerf_ns" / "dataset_format.py").resolve()  # the checkout's
    # own file: a non-editable install (CI's) puts the imported module in site-packages
    for path in sorted(_modules().values()):
        if path.resolve() == table:
            continue
        for node in _strings(ast.parse(path.read_text())):
            if node.value in names:
                found.append(f"{path}:{node.lineno}: {node.value!r} ({names[node.value]})")
    return found


def _table_names() -> Dict[str, str]:
    """Every per-frame key and metadata key of the table but Nerfstudio's own ``file_path`` (and ``timestamp``, a
    word of every raw reader too), and the dataset's file names."""
    names = {key: "frame key" for key in (FRUIT_MASK_CAMERA, THERMAL_TIMESTAMP, EXPOSURE_START, EXPOSURE_END)}
    names.update({name: "file name" for name in (TRANSFORMS, THERMAL_TRANSFORMS, TRAJECTORY, EVENT_STREAM)})
    for row in FRAME_FILES:
        if row is not IMAGE:
            names[row.key] = names[row.metadata] = f"{row.key} row"
    return names


def test_the_table_is_the_only_place_its_keys_are_spelled():
    assert not (spelled := _spelled(_table_names())), "\n".join(spelled)


def test_the_check_finds_a_spelled_key():
    """A module that spells a key (not in a docstring) is found; the table's own docstrings and prose are not."""
    code = '"""Reads ``thermal_file_path``."""\nKEY = "thermal_file_path"\n'
    strings = [node.value for node in _strings(ast.parse(code))]
    assert strings == ["thermal_file_path"]


def test_the_rows_are_distinct_and_written_where_the_table_says():
    keys = [row.key for row in FRAME_FILES]
    assert len(set(keys)) == len(keys)
    assert set(ALIGNED_FRAMES) <= set(FRAME_FILES)
    assert {row.modality for row in ALIGNED_FRAMES} == {"thermal", "events"}
    assert all(row.metadata for row in ALIGNED_FRAMES)
    assert dataset_format.THERMAL.path("000003") == "thermal/000003.png"
    assert dataset_format.EVENT_SUMS.path("000003") == "events/000003.npz"
