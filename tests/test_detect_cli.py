"""``agrinerf-detect evaluate`` takes its settings from one dataclass (EvalSettings): flags, defaults and help."""

from __future__ import annotations

import ast
import inspect
import re
import typing
from dataclasses import fields
from pathlib import Path
from typing import Dict

import pytest
import tyro

from agrinerf_ns.detect.detector import DetectorConfig
from agrinerf_ns.detect.settings import EvalSettings
from agrinerf_ns.lab.paper_cli import EvaluateCommand, entrypoint


def _help_texts(cls: type) -> Dict[str, str]:
    """Each field's help as tyro shows it: its ``tyro.conf.arg(help=...)``, else the docstring under it."""
    texts: Dict[str, str] = {}
    body = ast.parse(inspect.getsource(cls)).body[0].body  # type: ignore[attr-defined]
    for node, after in zip(body, body[1:] + [None], strict=True):
        if isinstance(node, ast.AnnAssign) and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant):
            texts[node.target.id] = inspect.cleandoc(after.value.value)  # type: ignore[attr-defined]
    for name, hint in typing.get_type_hints(cls, include_extras=True).items():
        for meta in getattr(hint, "__metadata__", ()):
            if getattr(meta, "help", None):
                texts[name] = meta.help
    return texts


def _squash(text: str) -> str:
    return " ".join(re.sub(r"[│╭╮╰╯─]", " ", text).split())


def test_evaluate_declares_no_setting_of_its_own() -> None:
    settings = {f.name for f in fields(EvalSettings)}
    own = {f.name for f in fields(EvaluateCommand)}
    assert not settings & own, f"re-declared in the CLI: {sorted(settings & own)}"
    assert EvaluateCommand(out=Path("x")).settings == EvalSettings()
    assert tyro.cli(EvaluateCommand, args=["--out", "x"]).settings == EvalSettings()


def test_every_setting_has_its_flag() -> None:
    given = {
        "detector": (["--detector.epochs", "3"], DetectorConfig(epochs=3)),
        "conf_threshold": (["--conf-threshold", "0.5"], 0.5),
        "cross_spectral_fraction": (["--cross-spectral-fraction", "0.4"], 0.4),
        "max_render_views": (["--max-render-views", "3"], 3),
        "rays_per_chunk": (["--rays-per-chunk", "2048"], 2048),
        "reuse": (["--no-reuse"], False),
        "rgb_source": (["--rgb-source", "captured"], "captured"),
        "thermal_init": (["--thermal-init", "scratch"], "scratch"),
        "thermal_init_lr0": (["--thermal-init-lr0", "0.01"], 0.01),
        "min_box_pixels": (["--min-box-pixels", "7"], 7),
        "detectors_from": (["--detectors-from", "earlier"], Path("earlier")),
    }
    assert set(given) == {f.name for f in fields(EvalSettings)}, "a setting without a case here"
    args = ["--out", "x"] + [arg for flags, _ in given.values() for arg in flags]
    parsed = tyro.cli(EvaluateCommand, args=args).settings
    assert parsed == EvalSettings(**{name: value for name, (_, value) in given.items()})


def test_evaluate_help_is_the_settings_help(capsys, monkeypatch) -> None:
    monkeypatch.setenv("COLUMNS", "200")
    with pytest.raises(SystemExit):
        entrypoint(["evaluate", "--help"])
    shown = _squash(capsys.readouterr().out)
    texts = _help_texts(EvalSettings)
    assert set(texts) == {f.name for f in fields(EvalSettings)}, "every setting has a help text"
    for name, text in texts.items():
        assert _squash(text) in shown, name
