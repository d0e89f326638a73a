"""agrinerf-detect end to end on a tiny synthetic scene: a real nerfacto run rendered, YOLOv8 trained from scratch,
detections scored; plus the bad-input errors of the CLI."""

from __future__ import annotations

import csv
import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import pytest

from agrinerf_ns.detect.boxes import MissingTruthError, SceneTruth, list_images
from agrinerf_ns.detect.detector import DetectorConfig
from agrinerf_ns.detect.eval_plan import MethodSpec, SceneSpec, check_scene
from agrinerf_ns.detect.render_views import MissingOutputError, render_pipeline_views
from agrinerf_ns.detect.settings import EvalSettings
from agrinerf_ns.lab.paper_cli import entrypoint
from agrinerf_ns.lab.paper_eval import evaluate_plan
from agrinerf_ns.run_loading import load_run


@pytest.fixture(scope="module")
def scene(tmp_path_factory: pytest.TempPathFactory):
    """Tiny dark orchard (12 frames, so the processed dataset has held-out test frames) and its processed dataset."""
    from agrinerf_ns.process.capture_to_dataset import ProcessConfig, process_capture
    from agrinerf_ns.synth import generate_capture
    from agrinerf_ns.synth.config import SynthConfig

    root = tmp_path_factory.mktemp("detect_scene")
    raw = generate_capture(SynthConfig.tiny(seed=3, lighting="dark", views=12), root / "raw")
    dataset = process_capture(raw, root / "dataset", ProcessConfig(poses="given", show_progress=False))
    return raw, dataset


def _cli_error(args, capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        entrypoint(args)
    assert exit_info.value.code == 2
    return capsys.readouterr().err


@pytest.mark.slow
def test_benchmark_on_tiny_scene_with_nerfacto(scene, tmp_path: Path) -> None:
    pytest.importorskip("ultralytics", reason="optional [detect] extra: scripts/install_detect.sh")
    from agrinerf_ns.ns_commands import ns_train

    raw, dataset = scene
    config = ns_train(
        "nerfacto",
        dataset,
        tmp_path / "outputs",
        "tiny",
        max_steps=1,
        rays_per_batch=256,
        extra_args=["--pipeline.model.eval-num-rays-per-chunk", "4096"],
        dataparser_args=["nerfstudio-data"],
    ).config
    test_stems = [Path(name).stem for name in json.loads((dataset / "transforms.json").read_text())["test_filenames"]]
    assert test_stems, "the processed dataset should hold out test frames"
    # the thermal branch: the dataset's own (aligned) thermal frames at the held-out views, as a reference "method"
    captured_thermal = tmp_path / "captured_thermal"
    captured_thermal.mkdir()
    for stem in test_stems:
        shutil.copy(dataset / "thermal" / f"{stem}.png", captured_thermal / f"{stem}.png")

    scenes = [
        SceneSpec(
            "orchard",
            "dark",
            raw,
            dataset,
            [
                MethodSpec("Nerfacto (RGB)", "rgb", config=config),
                MethodSpec("Captured thermal", "thermal", renders=captured_thermal),
            ],
        )
    ]
    # a method without a thermal output asked for the cross-spectral rendering (checked before anything is written)
    runs = {config: load_run(config)}
    with pytest.raises(MissingOutputError, match="no 'thermal' output"):
        render_pipeline_views(runs[config], "thermal", tmp_path / "nope", max_views=1)
    assert not (tmp_path / "nope").exists()
    # a few training views, evenly spaced: the first and the last
    train_stems = [Path(n).stem for n in json.loads((dataset / "transforms.json").read_text())["train_filenames"]]
    two = render_pipeline_views(runs[config], "rgb", tmp_path / "two", "train", max_views=2)
    assert [p.stem for p in two] == [train_stems[0], train_stems[-1]]

    settings = EvalSettings(DetectorConfig(epochs=2, imgsz=64, batch=8), cross_spectral_fraction=0.25, min_box_pixels=4)
    out = tmp_path / "detect"
    written = evaluate_plan(scenes, out, settings, "III", "pytest", runs=runs)  # renders with the loaded run
    assert not runs, "loaded pipelines are released before the detectors train"

    renders = out / "work" / "orchard_dark" / "renders" / "nerfacto__rgb"
    assert sorted(p.stem for p in list_images(renders)) == sorted(test_stems)
    rows = list(csv.DictReader(written["csv"].open()))
    assert [r["method"] for r in rows] == ["Nerfacto (RGB)", "Captured thermal"]
    for row in rows:
        assert int(row["num_images"]) == len(test_stems) and int(row["num_true"]) > 0
        for key in ("map50", "map50_95", "precision", "recall", "f1"):
            value = float(row[key])
            assert math.isfinite(value) and 0.0 <= value <= 1.0, (key, value)
    markdown = written["markdown"].read_text()
    assert "| orchard | Nerfacto (RGB) |" in markdown and "Captured thermal" in markdown and "dark" in markdown
    assert written["figure"].stat().st_size > 1000
    # detectors never saw the held-out frames; the thermal one trained on thermal frames
    for modality in ("rgb", "thermal"):
        trained = [p.stem for p in list_images(out / "work" / "orchard_dark" / f"yolo_{modality}" / "images" / "train")]
        assert trained and all(name.startswith(f"{modality}_") for name in trained)
        assert not {name.split("_", 1)[1] for name in trained} & set(test_stems)
        assert (out / "work" / "orchard_dark" / f"detector_{modality}" / "weights").is_dir()
    # the thermal detector started from the RGB one (thermal_init "rgb", the default)
    record = json.loads((out / "work" / "orchard_dark" / "detector_thermal" / "agrinerf_detect.json").read_text())
    assert Path(record["init"]["path"]).parent == (out / "work" / "orchard_dark" / "detector_rgb" / "weights").resolve()
    # scored again with those detectors (--detectors-from): nothing trained, the same figures
    again = evaluate_plan(scenes, tmp_path / "again", replace(settings, detectors_from=out), "III", "pytest")
    assert not list((tmp_path / "again" / "work" / "orchard_dark").glob("detector_*"))
    assert list(csv.DictReader(again["csv"].open())) == rows


def test_scene_without_truth_boxes(scene, tmp_path: Path, capsys) -> None:
    raw, dataset = scene
    bare = tmp_path / "bare"
    shutil.copytree(raw, bare, ignore=shutil.ignore_patterns("truth"))
    with pytest.raises(MissingTruthError, match="no true fruit boxes"):
        check_scene(SceneSpec("bare", "dark", bare, dataset, [MethodSpec("x", renders=raw / "rgb")]))
    err = _cli_error(["train", "--raw", str(bare), "--out", str(tmp_path / "det")], capsys)
    assert "no true fruit boxes" in err and str(bare) in err


def test_empty_render_folder(scene, tmp_path: Path, capsys) -> None:
    raw, _ = scene
    empty = tmp_path / "renders"
    empty.mkdir()
    (empty / "renders.json").write_text("{}")
    err = _cli_error(["score", "--raw", str(raw), "--renders", str(empty), "--weights", str(tmp_path / "w.pt")], capsys)
    assert "empty render folder" in err and str(empty) in err
    plan = tmp_path / "plan.json"
    plan.write_text(
        json.dumps(
            {
                "scenes": [
                    {
                        "name": "s",
                        "lighting": "dark",
                        "raw": str(raw),
                        "methods": [{"label": "m", "renders": str(empty)}],
                    }
                ]
            }
        )
    )
    err = _cli_error(["evaluate", "--plan", str(plan), "--out", str(tmp_path / "out")], capsys)
    assert "empty render folder" in err


def test_rgb_renders_or_no_dataset_for_cross_spectral(scene, tmp_path: Path) -> None:
    raw, dataset = scene
    rgb_renders = tmp_path / "rgb_renders"
    shutil.copytree(raw / "truth" / "rgb_clean", rgb_renders)
    (rgb_renders / "renders.json").write_text(json.dumps({"output": "rgb", "method": "nerfacto"}))
    method = MethodSpec("Ours (Cross-Spectral)", "thermal", renders=rgb_renders)
    with pytest.raises(MissingOutputError, match="asks for 'thermal'"):
        check_scene(SceneSpec("s", "dark", raw, dataset, [method]))
    (rgb_renders / "renders.json").unlink()
    with pytest.raises(ValueError, match="thermal detector"):
        check_scene(SceneSpec("s", "dark", raw, None, [method]))


def test_render_frames_without_truth_are_named(scene, tmp_path: Path) -> None:
    from agrinerf_ns.detect.yolo_data import rendered_images

    raw, _ = scene
    renders = tmp_path / "renders"
    renders.mkdir()
    shutil.copy(raw / "truth" / "rgb_clean" / "000000.png", renders / "view_9.png")
    with pytest.raises(MissingTruthError, match="view_9.png: no true boxes for frame 'view_9'"):
        rendered_images(SceneTruth(raw), renders)


def test_small_fruit_are_ignored_and_thermal_labels_need_the_thermal_view(scene, tmp_path: Path) -> None:
    import cv2
    import numpy as np

    from agrinerf_ns.detect.yolo_data import dataset_images

    raw, dataset = scene
    coco = json.loads((raw / "truth" / "boxes_coco.json").read_text())
    areas = np.array([a["area"] for a in coco["annotations"]])
    threshold = int(np.unique(areas)[len(np.unique(areas)) // 2])  # some boxes on each side
    everything, split = SceneTruth(raw, 0), SceneTruth(raw, threshold)
    counted = ignored = 0
    for stem in everything.label_files:
        whole = everything.frame(stem, raw / "rgb" / f"{stem}.png")
        parts = split.frame(stem, raw / "rgb" / f"{stem}.png")
        assert len(whole.ignored) == 0 and len(parts.counted) + len(parts.ignored) == len(whole.counted)
        counted, ignored = counted + len(parts.counted), ignored + len(parts.ignored)
    assert counted == int((areas >= threshold).sum()) and ignored == int((areas < threshold).sum()) > 0

    # the two truth files disagree: named, not silently misaligned
    broken = tmp_path / "broken"
    shutil.copytree(raw, broken)
    stem = next(s for s in everything.label_files if len(everything.frame(s, Path(s)).counted))
    image_id = next(im["id"] for im in coco["images"] if Path(im["file_name"]).stem == stem)
    coco["annotations"] = [a for a in coco["annotations"] if a["image_id"] != image_id]
    (broken / "truth" / "boxes_coco.json").write_text(json.dumps(coco))
    with pytest.raises(MissingTruthError, match="the two truth files disagree"):
        SceneTruth(broken, 1).frame(stem, Path("view.png"))
    (broken / "truth" / "boxes_coco.json").unlink()
    with pytest.raises(MissingTruthError, match="min_box_pixels 0"):
        SceneTruth(broken, 1)
    assert SceneTruth(broken, 0).frame(stem, Path("view.png")).counted.shape[1] == 4

    # thermal frames keep only the boxes the thermal camera saw (its mask); RGB frames keep all counted boxes
    copy = tmp_path / "dataset"
    shutil.copytree(dataset, copy)
    frames = json.loads((copy / "transforms.json").read_text())["frames"]
    blind = next(f for f in frames if len(everything.frame(Path(f["file_path"]).stem, Path("x")).counted))
    mask = cv2.imread(str(copy / blind["thermal_mask_path"]), cv2.IMREAD_GRAYSCALE)
    cv2.imwrite(str(copy / blind["thermal_mask_path"]), np.zeros_like(mask))
    thermal = {item.name: item for item in dataset_images(everything, copy, "thermal")}
    rgb = {item.name: item for item in dataset_images(everything, copy, "rgb")}
    stem = Path(blind["file_path"]).stem
    assert len(thermal[f"thermal_{stem}"].boxes) == 0 < len(rgb[f"rgb_{stem}"].boxes)
    assert sum(len(item.boxes) for item in thermal.values()) > 0


@pytest.mark.slow
def test_detector_starts_from_given_weights(scene, tmp_path: Path) -> None:
    """``init`` weights are the starting point (Ultralytics drops them when told pretrained=False): with a zero
    learning rate the trained convolutions equal the start's; from scratch they do not."""
    pytest.importorskip("ultralytics", reason="optional [detect] extra: scripts/install_detect.sh")
    import torch

    from agrinerf_ns.detect.detector import train_detector
    from agrinerf_ns.detect.yolo_data import rgb_truth_images, write_yolo_dataset

    raw, _ = scene
    data_yaml = write_yolo_dataset(tmp_path / "yolo", rgb_truth_images(SceneTruth(raw))[:4])
    config = DetectorConfig(epochs=1, imgsz=64, batch=4)
    start = train_detector(data_yaml, tmp_path / "start", config)
    frozen = train_detector(data_yaml, tmp_path / "frozen", replace(config, lr0=0.0), init=start)
    fresh = train_detector(data_yaml, tmp_path / "fresh", replace(config, lr0=0.0, seed=1))

    def convs(weights: Path) -> list:
        model = torch.load(weights, map_location="cpu", weights_only=False)["model"]
        return [m.weight.detach().float() for m in model.modules() if isinstance(m, torch.nn.Conv2d)]

    assert all(torch.equal(a, b) for a, b in zip(convs(start), convs(frozen), strict=True))
    assert not all(torch.equal(a, b) for a, b in zip(convs(start), convs(fresh), strict=True))
    with pytest.raises(FileNotFoundError, match="do not exist"):
        train_detector(data_yaml, tmp_path / "none", config, init=tmp_path / "missing.pt")
