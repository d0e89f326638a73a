"""One benchmark scene, synthesised and processed once and cached: what ``agrinerf-bench`` and its grid jobs
(:mod:`agrinerf_ns.lab.bench_grid`) train on."""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path
from typing import TYPE_CHECKING, Optional, Tuple

from agrinerf_ns.dataset_format import BLOCK, TRANSFORMS
from agrinerf_ns.lab.layout import scene_folders
from agrinerf_ns.lab.profiles import BenchProfile

if TYPE_CHECKING:
    from agrinerf_ns.synth import SynthConfig


def prepare_scene(name: str, profile: BenchProfile, seed: int, root: Path) -> Tuple[Path, Path]:
    """Synthesise and process one scene (cached under ``root``); returns (raw capture, dataset)."""
    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.process.capture_to_dataset import recorded_plane_depth
    from agrinerf_ns.synth import SynthConfig, generate_capture

    scene, _, lighting = name.partition("-")
    raw, data = scene_folders(root, name)
    config = SynthConfig(scene=scene, lighting=lighting, seed=seed, views=profile.views, width=profile.width,
                         height=profile.height, **profile.synth)  # fmt: skip
    if not _same_capture(raw, config):
        if raw.exists():
            shutil.rmtree(raw)
        generate_capture(config, raw)
        if data.exists():
            shutil.rmtree(data)
    if (
        not (data / TRANSFORMS).exists()
        or recorded_plane_depth(data) != profile.plane_depth
        or not _same_split(data, profile.eval_every)
        or _mask_source(data) != _mask_source_wanted(profile)
    ):
        # Poses from the capture's odometry: the benchmark compares reconstructions, not SfM.
        process = ProcessConfig(poses="given", overwrite=True, show_progress=False, plane_depth=profile.plane_depth,
                                eval_every=profile.eval_every, **profile.process)  # fmt: skip
        process_capture(raw, data, process)
    return raw, data


def _mask_source(data: Path) -> Optional[str]:
    """The maker of a dataset's fruit masks as it records it (``maker:auto``; None: no masks made)."""
    meta = json.loads((data / TRANSFORMS).read_text()).get(BLOCK, {})
    return meta.get("fruit_masks", {}).get("source")


def _mask_source_wanted(profile: BenchProfile) -> Optional[str]:
    maker = profile.process.get("fruit_mask_maker", "none")
    return None if maker == "none" else f"maker:{maker}"


def _same_split(data: Path, eval_every: int) -> bool:
    """Whether the dataset's held-out list is the one ``eval_every`` gives."""
    from agrinerf_ns.process.dataset_writer import split_names

    meta = json.loads((data / TRANSFORMS).read_text())
    names = [frame["file_path"] for frame in meta["frames"]]
    return meta.get("test_filenames") == split_names(names, eval_every)["test_filenames"]


def _same_capture(raw: Path, config: "SynthConfig") -> bool:
    """Whether ``raw`` is a finished capture written with ``config`` (its ``truth/scene.json``). A capture that lacks a
    setting (written before the synthesiser had it) is not: the setting may change what is written."""
    scene_json = raw / "truth" / "scene.json"
    if not (raw / "calib.yaml").exists() or not scene_json.exists():
        return False
    written = json.loads(scene_json.read_text()).get("config", {})
    wanted = json.loads(json.dumps(asdict(config)))  # tuples as the JSON lists they are written as
    return all(key in written and written[key] == value for key, value in wanted.items())
