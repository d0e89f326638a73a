"""The layout of an ``agrinerf-bench`` output folder, written by the benchmark and read by detection and counting.

::

    OUT/scenes/<scene>/raw/                      synthetic raw capture with truth/ (``agrinerf-synth``)
    OUT/scenes/<scene>/data/                     its processed dataset (``agrinerf-process``)
    OUT/runs/<scene>/<method key>/               one ``ns-train`` experiment per (scene, bench method key)
        train_run.json                           the run's :class:`~agrinerf_ns.ns_commands.TrainRun` record
        <ns method>/run/config.yml               the Nerfstudio run (timestamp fixed to "run")
        <ns method>/run/nerfstudio_models/step-NNNNNNNNN.ckpt   its checkpoints
    OUT/results.csv, results.md, tradeoff.png    the benchmark's report

``<scene>`` is ``<name>-<lighting>`` (e.g. ``garden-dark``). Nothing else in the package spells these paths.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Mapping, NamedTuple, Optional, Sequence, Tuple

from agrinerf_ns.ns_commands import RUN_TIMESTAMP, checkpoints

SCENES_DIR = "scenes"
RUNS_DIR = "runs"
TRAIN_RECORD = "train_run.json"


class SceneFolders(NamedTuple):
    """A benchmark scene's raw capture (with ``truth/``) and processed dataset."""

    raw: Path
    data: Path


def scene_folders(scenes_root: Path, scene: str) -> SceneFolders:
    """``scenes_root/<scene>/{raw,data}``."""
    return SceneFolders(Path(scenes_root) / scene / "raw", Path(scenes_root) / scene / "data")


def split_scene(scene: str) -> Tuple[str, str]:
    """``"garden-dark"`` -> ``("garden", "dark")``; ``"-"`` for a name without lighting."""
    name, _, lighting = scene.partition("-")
    return name, lighting or "-"


def experiment_folder(runs_root: Path, scene: str, method_key: str) -> Path:
    """``ns-train``'s ``--output-dir`` is ``runs_root/<scene>`` and its ``--experiment-name`` the method key."""
    return Path(runs_root) / scene / method_key


def train_record(runs_root: Path, scene: str, method_key: str) -> Path:
    """Where the benchmark keeps the run's ``TrainRun`` record (resumes without retraining)."""
    return experiment_folder(runs_root, scene, method_key) / TRAIN_RECORD


def run_config(runs_root: Path, scene: str, method_key: str, ns_method: str) -> Path:
    """The run's ``config.yml`` as ``ns-train`` writes it for this layout."""
    return experiment_folder(runs_root, scene, method_key) / ns_method / RUN_TIMESTAMP / "config.yml"


@dataclass(frozen=True)
class BenchLayout:
    """One ``agrinerf-bench`` output folder."""

    out: Path

    @property
    def scenes(self) -> Path:
        return Path(self.out) / SCENES_DIR

    @property
    def runs(self) -> Path:
        return Path(self.out) / RUNS_DIR

    @property
    def results_csv(self) -> Path:
        return Path(self.out) / "results.csv"

    @property
    def results_md(self) -> Path:
        return Path(self.out) / "results.md"

    @property
    def tradeoff_png(self) -> Path:
        return Path(self.out) / "tradeoff.png"

    def scene(self, scene: str) -> SceneFolders:
        return scene_folders(self.scenes, scene)

    def run_scenes(self) -> List[str]:
        """Scenes with a run folder, sorted; ``FileNotFoundError`` when ``OUT/runs`` does not exist."""
        if not self.runs.is_dir():
            raise FileNotFoundError(f"{self.out}: not an agrinerf-bench output folder ({self.runs} does not exist)")
        return sorted(p.name for p in self.runs.iterdir() if p.is_dir())

    def has_runs(self, scene: str, method_keys: Sequence[str]) -> bool:
        """Whether any of these method keys has an experiment folder in the scene (finished or not)."""
        return any(experiment_folder(self.runs, scene, key).is_dir() for key in method_keys)

    def finished_run(self, scene: str, method_key: str, ns_method: str) -> Optional[Path]:
        """The run's ``config.yml`` when it has saved a checkpoint, else None."""
        config = run_config(self.runs, scene, method_key, ns_method)
        return config if config.is_file() and checkpoints(config) else None

    def finished_runs(self, scene: str, ns_methods: Mapping[str, str]) -> Dict[str, Path]:
        """Method key -> ``config.yml`` of each finished run among ``ns_methods`` (method key -> ``ns-train`` method),
        in their order."""
        found = {key: self.finished_run(scene, key, ns_method) for key, ns_method in ns_methods.items()}
        return {key: config for key, config in found.items() if config is not None}
