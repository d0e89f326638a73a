"""What the commands' consoles show: no third-party deprecation warning on the first screen of `ns-train agrinerf-lite`,
`agrinerf-count` and `agrinerf-demo` (while in-process code, this test suite included, still sees every warning), and
progress at least every tenth of the work of `agrinerf-synth` and `agrinerf-count`, in a log and on a terminal."""

from __future__ import annotations

import io
import os
import pty
import re
import select
import subprocess
import sys
import time
import warnings
from importlib import metadata
from pathlib import Path
from typing import Dict, List

import pytest
from rich.console import Console

from agrinerf_ns.progress import work_progress
from agrinerf_ns.quiet_warnings import (
    THIRD_PARTY_MESSAGES,
    is_console_command,
    quiet_console_command,
    quiet_third_party,
)

BIN = Path(sys.executable).parent
THIRD_PARTY_WARNING = re.compile(r"(DeprecationWarning|FutureWarning|PendingDeprecationWarning|UserWarning):")
PROGRESS_LINE = re.compile(r"^(?P<label>.+): (?P<share>\d+)% \((?P<done>\d+)/(?P<total>\d+)\) in \d+ s", re.MULTILINE)
HOOK = "agrinerf-ns-quiet-warnings = agrinerf_ns.quiet_warnings:torch_import_hook"


def _tenths(output: str, label: str = "") -> bool:
    """Whether the progress lines of ``output`` (labelled ``label...``) run to the end, no tenth of the work apart."""
    found = [m for m in PROGRESS_LINE.finditer(output) if m["label"].startswith(label)]
    shares = [int(m["done"]) / int(m["total"]) for m in found]
    return (
        bool(shares)
        and shares[-1] == 1.0
        and all(0 < b - a <= 0.1 + 1e-9 for a, b in zip([0.0, *shares], shares, strict=False))
    )


def _warned(category: type, module: str, message: str = "x is deprecated") -> bool:
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        quiet_third_party()
        warnings.warn_explicit(message, category, "f.py", 1, module=module)
    return bool(caught)


def test_filters_hide_third_party_deprecations_only() -> None:
    assert not _warned(FutureWarning, "torch.jit._script")
    assert not _warned(DeprecationWarning, "nerfstudio.field_components.activations")
    assert not _warned(UserWarning, "torch.utils.data.dataloader", "This DataLoader will create 4 worker processes ...")
    assert _warned(FutureWarning, "agrinerf_ns.model.model"), "the project's own warnings show"
    assert _warned(UserWarning, "nerfstudio.data.datamanagers", "no images"), "other third-party UserWarnings show"
    assert _warned(RuntimeWarning, "torchmetrics.image.lpip")
    assert all(re.compile(m) for m, _ in THIRD_PARTY_MESSAGES)


def test_only_console_commands_are_quieted() -> None:
    assert is_console_command(["/venv/bin/ns-train"]) and is_console_command(["agrinerf-count"])
    assert not is_console_command(["/venv/bin/pytest"]) and not is_console_command(["-c"])
    before = list(warnings.filters)
    assert not quiet_console_command(["/venv/bin/pytest"])
    assert not quiet_console_command(["/venv/bin/ns-train"]), "never inside the test suite"
    assert warnings.filters == before


def test_progress_in_a_log_every_tenth_and_a_bar_on_a_terminal() -> None:
    log = io.StringIO()
    with work_progress("work", 37, Console(file=log, force_terminal=False, width=200)) as progress:
        for _ in range(37):
            progress.advance()
    assert _tenths(log.getvalue()), log.getvalue()

    terminal = io.StringIO()
    with work_progress("work", 5, Console(file=terminal, force_terminal=True, width=120)) as progress:
        for _ in range(5):
            progress.advance()
            time.sleep(0.05)
    assert (
        "work" in terminal.getvalue() and "━" in terminal.getvalue() and not PROGRESS_LINE.search(terminal.getvalue())
    )


def _hook_env(tmp: Path) -> Dict[str, str]:
    """The environment of the commands: where the installed distribution lacks its `torch.backends` entry point (an
    install older than pyproject.toml), a distribution that declares just that entry point is put on the path."""
    env = {**os.environ, "COLUMNS": "200"}
    for name in ("PYTHONWARNINGS", "AGRINERF_SHOW_WARNINGS"):
        env.pop(name, None)
    installed = [
        ep for ep in metadata.entry_points(group="torch.backends") if ep.module == "agrinerf_ns.quiet_warnings"
    ]
    if not installed:
        info = tmp / "hook" / "agrinerf_ns_quiet_hook-0.dist-info"
        info.mkdir(parents=True)
        (info / "METADATA").write_text("Metadata-Version: 2.1\nName: agrinerf-ns-quiet-hook\nVersion: 0\n")
        (info / "entry_points.txt").write_text(f"[torch.backends]\n{HOOK}\n")
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(info.parent), env.get("PYTHONPATH", "")) if p)
    return env


def _run(command: List[str], env: Dict[str, str], cwd: Path) -> str:
    done = subprocess.run(command, check=False, cwd=cwd, env=env, capture_output=True, text=True, timeout=600,
                          stdin=subprocess.DEVNULL)  # fmt: skip
    output = done.stdout + done.stderr
    assert done.returncode == 0, output[-3000:]
    return output


def _until(command: List[str], env: Dict[str, str], cwd: Path, marker: str) -> str:
    """The output of ``command`` up to the line holding ``marker``; then it is stopped."""
    proc = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            stdin=subprocess.DEVNULL)  # fmt: skip
    lines: List[str] = []
    try:
        for line in proc.stdout:  # type: ignore[union-attr]
            lines.append(line)
            if marker in line:
                break
    finally:
        proc.kill()
        proc.wait(timeout=60)
    assert any(marker in line for line in lines), "".join(lines)[-3000:]
    return "".join(lines)


def _no_third_party_warning(output: str, command: str) -> None:
    found = [line for line in output.splitlines() if THIRD_PARTY_WARNING.search(line)]
    assert not found, f"{command} printed: {found}"


@pytest.mark.slow
def test_first_screens_hold_no_third_party_warning_and_count_reports_progress(tmp_path: Path) -> None:
    from helpers.model_scene import write_model_scene

    env = _hook_env(tmp_path)
    data = write_model_scene(tmp_path / "scene")
    train = _run([str(BIN / "ns-train"), "agrinerf-lite", "--data", str(data), "--output-dir", str(tmp_path / "out"),
                  "--max-num-iterations", "3", "--vis", "tensorboard", "--viewer.quit-on-train-completion", "True"],
                 env, tmp_path)  # fmt: skip
    _no_third_party_warning(train, "ns-train agrinerf-lite")
    config = next((tmp_path / "out").rglob("config.yml"))

    count = _run([str(BIN / "agrinerf-count"), "--config", str(config), "--out", str(tmp_path / "count"),
                  "--path", "views"], env, tmp_path)  # fmt: skip
    _no_third_party_warning(count, "agrinerf-count")
    assert _tenths(count, "rendering"), count
    screen = _on_terminal([str(BIN / "agrinerf-count"), "--config", str(config), "--out", str(tmp_path / "count_tty"),
                           "--path", "views"], tmp_path)  # fmt: skip
    assert "rendering" in screen and "━" in screen, screen[-2000:]
    assert not PROGRESS_LINE.search(screen), "a bar, not log lines, on a terminal"

    demo = [str(BIN / "agrinerf-demo"), "--out", str(tmp_path / "demo"), "--views", "8", "--width", "64"]
    _no_third_party_warning(_until(demo, env, tmp_path, "agrinerf-process"), "agrinerf-demo")
    assert "DeprecationWarning" in subprocess.run(
        [sys.executable, "-c", "import warnings, agrinerf_ns; warnings.warn('x', DeprecationWarning)"],
        env={**env, "PYTHONWARNINGS": "default"}, capture_output=True, text=True, check=True,
    ).stderr, "a Python program that imports the plugin keeps its warnings"  # fmt: skip


def _on_terminal(command: List[str], cwd: Path) -> str:
    """Run ``command`` with a pseudo-terminal as its stdout and stderr; its output."""
    leader, follower = pty.openpty()
    proc = subprocess.Popen(command, cwd=cwd, stdout=follower, stderr=follower, stdin=subprocess.DEVNULL,
                            env={**os.environ, "COLUMNS": "120", "TERM": "xterm"})  # fmt: skip
    os.close(follower)
    chunks = []
    while True:
        ready, _, _ = select.select([leader], [], [], 1.0)
        if ready:
            try:
                data = os.read(leader, 65536)
            except OSError:
                break
            if not data:
                break
            chunks.append(data)
        elif proc.poll() is not None:
            break
    proc.wait(timeout=120)
    os.close(leader)
    assert proc.returncode == 0
    return b"".join(chunks).decode(errors="replace")


@pytest.mark.slow
def test_synth_reports_progress_in_a_log_and_on_a_terminal(tmp_path: Path) -> None:
    tiny = ["--views", "8", "--width", "64", "--height", "48", "--heldout", "2", "--event-substeps", "4"]
    log = _run([str(BIN / "agrinerf-synth"), "--out", str(tmp_path / "log"), *tiny], dict(os.environ), tmp_path)
    assert _tenths(log, "synth"), log

    screen = _on_terminal([str(BIN / "agrinerf-synth"), "--out", str(tmp_path / "tty"), *tiny], tmp_path)
    assert "synth orchard/bright" in screen and "━" in screen, screen[-2000:]
    assert not PROGRESS_LINE.search(screen), "a bar, not log lines, on a terminal"
