"""agrinerf-count's field path: fruit found in 3D in a field fitted to known fruit, a run without thermal frames
counted from RGB (and saying so), and what is not a trained run named."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest
from helpers.fruit_field import assert_finds_the_known_fruit, fruit_model

from agrinerf_ns.count.cli import CountArgs, main
from agrinerf_ns.count.components import ComponentConfig
from agrinerf_ns.count.field_count import FieldCountConfig, count_model
from agrinerf_ns.count.pipeline import CountConfig
from agrinerf_ns.count.render import WorldFrame
from agrinerf_ns.count.volume import DepthView, VolumeConfig, VoxelGrid, views_seeing
from agrinerf_ns.run_loading import NotATrainedRunError, trained_run_config

SMALL_GRID = VolumeConfig(max_voxels=200_000, max_views=4)
"""The tiny runs' grids: few voxels, few rendered views."""


def test_the_field_counter_finds_the_known_fruit() -> None:
    """Four warm fruit in front of a cool leaf wall above warm ground: four fruit, at their centres, of their size and
    temperature; the ground (warm too, but not fruit-sized) and the wall are not fruit."""
    model = fruit_model(steps=300)
    config = FieldCountConfig(
        source="temperature",
        volume=VolumeConfig(voxel_size=0.025, density_threshold=10.0),
        components=ComponentConfig(min_diameter=0.1, max_diameter=0.4, background_size=0.5, min_views=1),
    )
    box = np.array([[-1.0] * 3, [1.0] * 3])
    result, sampled, info = count_model(model, None, WorldFrame(np.eye(4)[:3], 1.0), config, box=box)
    assert info["source"] == "temperature" and info["too_large"] >= 1  # the ground
    assert_finds_the_known_fruit(result.fruit)
    cool = count_model(
        model, None, WorldFrame(np.eye(4)[:3], 1.0),
        FieldCountConfig(source="temperature", volume=config.volume,
                         components=ComponentConfig(**{**config.components.__dict__, "polarity": "cool"})),
        box=box,
    )[0]  # fmt: skip
    assert cool.fruit == []  # these fruit are warm
    assert "warning" not in info
    empty_volume = VolumeConfig(voxel_size=0.025, density_threshold=1e9)  # above every density of the field
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)  # no mean of nothing on the way
        empty, _, empty_info = count_model(model, None, WorldFrame(np.eye(4)[:3], 1.0),
                                           FieldCountConfig(source="temperature", volume=empty_volume,
                                                            components=config.components), box=box)  # fmt: skip
    assert empty.fruit == [] and empty_info["dense_voxels"] == 0
    assert "no surface to count fruit on" in empty_info["warning"]


def test_a_voxel_behind_the_rendered_surface_is_not_seen() -> None:
    """One camera at the origin looking down -z at a surface 2 units away: points in front of it and up to the
    margin behind it are seen, points farther behind or outside the image are not."""
    depth = np.full((10, 10), 2.0)
    view = DepthView(np.eye(4)[:3], 10.0, 10.0, 5.0, 5.0, depth, np.zeros((0, 3)))
    points = np.array([[0, 0, -1.0], [0, 0, -2.04], [0, 0, -2.5], [5.0, 0, -1.0]])
    assert views_seeing(points, [view], margin=0.05).tolist() == [1, 1, 0, 0]
    grid = VoxelGrid.over(np.array([[0.0] * 3, [1.0] * 3]), 0.01, 1000)
    assert int(np.prod(grid.shape)) <= 1000 and grid.step > 0.01


@pytest.fixture(scope="module")
def rgb_run(tmp_path_factory) -> Path:
    """config.yml of a tiny agrinerf-lite run trained on RGB frames alone (no thermal frames in its dataset)."""
    from helpers.model_scene import tiny_trainer_config, write_model_scene
    from helpers.tiny_run import train_saved_run

    root = tmp_path_factory.mktemp("rgb_run")
    data = write_model_scene(root / "scene", modalities=("rgb",))
    return train_saved_run(tiny_trainer_config(data, root / "outputs", max_num_iterations=10), seed=0)


def test_a_run_without_thermal_frames_counts_from_rgb_and_says_so(rgb_run: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "count"
    main(CountArgs(out=out, config=rgb_run.parent, path="field", field=FieldCountConfig(volume=SMALL_GRID)))
    report = json.loads((out / "count.json").read_text())
    assert report["path"] == "field" and report["source"] == "rgb"
    assert "no thermal" in report["source_note"]
    assert "Counting from RGB" in capsys.readouterr().out
    assert {"fruits.csv", "fruits.ply", "fruit_map.png"} <= {p.name for p in out.iterdir()}
    with pytest.raises(SystemExit):  # the thermal output it does not have, asked for by name
        main(
            CountArgs(
                out=tmp_path / "t",
                config=rgb_run,
                path="field",
                field=FieldCountConfig(source="thermal", volume=SMALL_GRID),
            )
        )
    assert "no 'thermal' output" in capsys.readouterr().out
    # --max-range on the field path: a range past the scene keeps the count, one shorter than any fruit's leaves none
    counts = {}
    for name, max_range in (("far", 1e6), ("near", 1e-3)):
        main(CountArgs(out=tmp_path / name, config=rgb_run.parent, path="field", field=FieldCountConfig(volume=SMALL_GRID),
                       count=CountConfig(max_range=max_range)))  # fmt: skip
        counts[name] = json.loads((tmp_path / name / "count.json").read_text())
        assert counts[name]["max_range"] == max_range
    assert counts["far"]["fruit"] == report["fruit"] and counts["near"]["fruit"] == 0


def test_the_default_path_counts_a_lit_run_in_its_rgb_views_by_rays(rgb_run: Path, tmp_path: Path, capsys) -> None:
    out = tmp_path / "count"
    main(CountArgs(out=out, config=rgb_run.parent, splits=("eval",)))  # --path auto
    assert "Counting by the views path" in capsys.readouterr().out.replace("\n", " ")
    report = json.loads((out / "count.json").read_text())
    assert report["detector"]["source"] == "rgb" and report["cluster"]["triangulate"] is True


def test_the_default_path_counts_a_dark_run_in_its_field(tmp_path: Path, capsys) -> None:
    """RGB frames of 2% of full scale (below the model's low_light_level) beside thermal frames: the field's
    temperature or thermal output, not the views."""
    from helpers.model_scene import tiny_trainer_config, write_model_scene
    from helpers.tiny_run import train_saved_run

    data = write_model_scene(tmp_path / "scene", modalities=("rgb", "thermal"), constant={"rgb": 0.02})
    run = train_saved_run(tiny_trainer_config(data, tmp_path / "outputs", max_num_iterations=10), seed=0)
    out = tmp_path / "count"
    main(CountArgs(out=out, config=run, field=FieldCountConfig(volume=SMALL_GRID)))
    assert "Counting by the field path" in capsys.readouterr().out.replace("\n", " ")
    report = json.loads((out / "count.json").read_text())
    assert report["path"] == "field" and report["source"] != "rgb"


def test_the_tri_modal_run_counts_from_its_thermal_camera_channel(tiny_run_config: Path, tmp_path: Path) -> None:
    main(
        CountArgs(
            out=tmp_path / "count", config=tiny_run_config, path="field", field=FieldCountConfig(volume=SMALL_GRID)
        )
    )
    report = json.loads((tmp_path / "count" / "count.json").read_text())
    assert report["source"] == "thermal_camera" and report["views_rendered"] == 4
    assert np.prod(report["grid_shape"]) <= SMALL_GRID.max_voxels


def test_a_folder_that_is_not_a_trained_run_is_named(tmp_path: Path, rgb_run: Path, capsys) -> None:
    empty = tmp_path / "not-a-run"
    empty.mkdir()
    for path in ("field", "views"):
        with pytest.raises(SystemExit):
            main(CountArgs(out=tmp_path / "out", config=empty, path=path))
        message = capsys.readouterr().out.replace("\n", "")
        assert str(empty) in message and "not a trained Nerfstudio run" in message
    untrained = tmp_path / "untrained"
    untrained.mkdir()
    (untrained / "config.yml").write_text(rgb_run.read_text())
    with pytest.raises(NotATrainedRunError, match="no step-.*ckpt checkpoint"):
        trained_run_config(untrained)
    with pytest.raises(NotATrainedRunError, match="no such run folder"):
        trained_run_config(tmp_path / "missing")
    assert not (tmp_path / "out").exists()


def test_the_count_tables_pool_runs_with_bootstrap_intervals(tmp_path: Path) -> None:
    from agrinerf_ns.lab.count_tables import TablesArgs, append_rows, bootstrap_mean
    from agrinerf_ns.lab.count_tables import main as tables_main

    interval = bootstrap_mean([0.5, 0.7, 0.9, float("nan")])
    assert interval.value == pytest.approx(0.7) and 0.5 <= interval.low < 0.7 < interval.high <= 0.9
    assert bootstrap_mean([0.4]).low == bootstrap_mean([0.4]).high == 0.4
    for seed, f1 in ((0, 0.5), (1, 0.9)):
        row = {"scene": "garden-dark", "lighting": "dark", "seed": seed, "method": "agrinerf-lite", "step": 10,
               "path": "field", "source": "temperature", "counted": 10, "visible": 10, "count_error": 0.0,
               "precision": f1, "recall": f1, "f1": f1, "mean_match_error": 0.01, "mean_temperature_error": 0.5,
               "seconds": 3.0}  # fmt: skip
        (tmp_path / f"seed{seed}").mkdir()
        append_rows(tmp_path / f"seed{seed}" / "count.csv", [row])
    rows = tables_main(TablesArgs(csvs=(tmp_path / "seed0", tmp_path / "seed1" / "count.csv"), out=tmp_path / "all"))
    assert len(rows) == 2
    text = (tmp_path / "all" / "count.md").read_text()
    assert "| dark | agrinerf-lite | field | temperature | 2 | 0.70 [0.50, 0.90] |" in text
    assert "## Per scene" not in text  # one scene per lighting: the per-lighting table says it all
    orchard = {**row, "scene": "orchard-dark", "f1": 0.1}
    append_rows(tmp_path / "seed1" / "count.csv", [orchard])
    tables_main(TablesArgs(csvs=(tmp_path / "seed0", tmp_path / "seed1"), out=tmp_path / "all"))
    text = (tmp_path / "all" / "count.md").read_text()
    lighting, scene = text.split("## Per scene")
    assert "| dark | agrinerf-lite | field | temperature | 3 | 0.50 [" in lighting  # pooled over both scenes
    assert "| garden-dark | agrinerf-lite | field | temperature | 2 | 0.70 [0.50, 0.90] |" in scene
    assert "| orchard-dark | agrinerf-lite | field | temperature | 1 | 0.10 [0.10, 0.10] |" in scene
    with pytest.raises(FileNotFoundError, match="no count.csv"):
        tables_main(TablesArgs(csvs=(tmp_path / "nothing",), out=tmp_path / "x"))
