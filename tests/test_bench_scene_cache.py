"""agrinerf-bench's scene cache: a capture is reused only when it was written with the profile's settings, and a
dataset only when it was processed at the profile's thermal warp plane."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

from agrinerf_ns.lab.profiles import PROFILES
from agrinerf_ns.lab.scenes import prepare_scene


def _plane(data: Path) -> object:
    return json.loads((data / "transforms.json").read_text())["agrinerf"]["alignment"]["plane_depth"]


def test_scene_cache_follows_the_profile(tmp_path: Path) -> None:
    tiny = replace(PROFILES["tiny"], views=6)
    raw, data = prepare_scene("orchard-dark", tiny, 0, tmp_path)
    assert _plane(data) == "inf"
    stamp = (raw / "calib.yaml").stat().st_mtime_ns, (data / "transforms.json").stat().st_mtime_ns

    assert prepare_scene("orchard-dark", tiny, 0, tmp_path) == (raw, data)
    assert ((raw / "calib.yaml").stat().st_mtime_ns, (data / "transforms.json").stat().st_mtime_ns) == stamp

    # another warp plane: the same capture, re-processed
    prepare_scene("orchard-dark", replace(tiny, plane_depth=1.5), 0, tmp_path)
    assert (raw / "calib.yaml").stat().st_mtime_ns == stamp[0] and _plane(data) == 1.5

    # more views: a new capture (and dataset)
    prepare_scene("orchard-dark", replace(tiny, views=7, plane_depth=1.5), 0, tmp_path)
    assert json.loads((raw / "truth" / "scene.json").read_text())["config"]["views"] == 7
    assert len(json.loads((data / "transforms.json").read_text())["frames"]) == 7 and _plane(data) == 1.5


def test_a_capture_written_before_a_setting_existed_is_not_reused(tmp_path: Path) -> None:
    """A cached capture whose scene.json lacks one of today's settings (an older synthesiser wrote it) is made anew:
    the missing setting may change what is written (as event_supersample changed the events, not the RGB)."""
    tiny = replace(PROFILES["tiny"], views=6)
    raw, _ = prepare_scene("orchard-dark", tiny, 0, tmp_path)
    scene_json = raw / "truth" / "scene.json"
    written = json.loads(scene_json.read_text())
    del written["config"]["event_supersample"]
    scene_json.write_text(json.dumps(written))
    prepare_scene("orchard-dark", tiny, 0, tmp_path)
    assert "event_supersample" in json.loads(scene_json.read_text())["config"]
