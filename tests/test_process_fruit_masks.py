"""agrinerf-process --fruit-masks: the user's masks (a plain folder, or a FruitNeRF dataset's semantics/) reach the
dataset and its batches; a missing mask or one of the wrong size is refused, naming the file, before any output."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from helpers.process_raw_fixture import make_raw_capture

from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
from agrinerf_ns.dataparsers.agrinerf_dataset import AgriNeRFDataset
from agrinerf_ns.process.capture_to_dataset import ProcessConfig, process_capture
from agrinerf_ns.process.errors import RawInputError


def _masks(raw: Path, folder: Path, value: int = 255) -> None:
    """A fruit square, an unknown top row and background, per RGB frame, named like the frame."""
    folder.mkdir(parents=True)
    for frame in sorted((raw / "rgb").glob("*.png")):
        mask = np.zeros((48, 64), np.uint8)
        mask[10:20, 20:36] = value
        mask[0] = 128
        cv2.imwrite(str(folder / f"{frame.stem}.png"), mask)


def _snapshot(folder: Path) -> dict:
    return {p: (p.stat().st_mtime_ns, p.read_bytes()) for p in folder.rglob("*") if p.is_file()}


@pytest.mark.parametrize("layout", ["folder", "fruitnerf"])
def test_user_masks_reach_the_batches(tmp_path: Path, layout: str) -> None:
    raw = make_raw_capture(tmp_path / "raw", n=4)
    given = tmp_path / "seg"
    _masks(raw, given / "semantics" if layout == "fruitnerf" else given, value=1 if layout == "fruitnerf" else 255)
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False, fruit_masks=given))
    outputs = AgriNeRFDataParserConfig(data=out).setup().get_dataparser_outputs("train")
    assert len(outputs.metadata["fruit_mask_filenames"]) == len(outputs.image_filenames)
    item = AgriNeRFDataset(outputs)[0]
    assert float(item["fruit"][10:20, 20:36].min()) == 1.0 and float(item["fruit"].sum()) == 10 * 16
    assert float(item["fruit_known"][0].max()) == 0.0 and float(item["fruit_known"][1:].min()) == 1.0


def test_a_missing_or_wrongly_sized_mask_is_refused_before_any_output(tmp_path: Path) -> None:
    raw = make_raw_capture(tmp_path / "raw", n=4)
    given = tmp_path / "seg"
    _masks(raw, given)
    before = _snapshot(raw)
    frames = sorted((raw / "rgb").glob("*.png"))
    (given / f"{frames[2].stem}.png").unlink()
    with pytest.raises(RawInputError, match=f"no mask named like RGB frame {frames[2].name}"):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False, fruit_masks=given))
    cv2.imwrite(str(given / f"{frames[2].stem}.png"), np.zeros((24, 32), np.uint8))
    with pytest.raises(RawInputError, match=f"{frames[2].stem}.png: fruit mask is 32x24 but the RGB frames are 64x48"):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False, fruit_masks=given))
    assert not (tmp_path / "ds").exists() and not list(tmp_path.glob(".ds*"))
    assert _snapshot(raw) == before


def test_the_colour_maker_finds_a_red_fruit_not_a_tan_stake() -> None:
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, colour_mask

    rgb = np.zeros((60, 80, 3), np.uint8)
    rgb[:] = (60, 140, 50)  # leaves
    rgb[:, 60:64] = (170, 155, 130)  # a tan stake: a fruit's hue, dull
    cv2.circle(rgb, (25, 30), 5, (200, 30, 25), -1)  # a red fruit
    mask = colour_mask(rgb, MaskMakerConfig())
    disc = np.zeros((60, 80), np.uint8)
    cv2.circle(disc, (25, 30), 5, 1, -1)
    assert (mask[disc > 0] == 255).mean() > 0.9 and (mask[disc == 0] == 255).sum() == 0


def test_the_colour_maker_leaves_specks_unknown_and_keeps_the_fruit() -> None:
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, colour_mask

    rgb = np.zeros((60, 80, 3), np.uint8)
    rgb[:] = (60, 140, 50)  # leaves
    cv2.circle(rgb, (25, 30), 5, (200, 30, 25), -1)  # a red fruit
    rgb[10, 70] = rgb[50, 8] = (200, 30, 25)  # two pixels of chroma noise in the fruit hues
    plain = colour_mask(rgb, MaskMakerConfig(min_region_pixels=0))
    assert plain[10, 70] == 255 and plain[50, 8] == 255  # without the rule, noise is taught as fruit
    mask = colour_mask(rgb, MaskMakerConfig())  # the default leaves specks under 8 px unknown
    assert mask[10, 70] == 128 and mask[50, 8] == 128  # unknown: neither fruit nor background
    assert mask[30, 25] == 255 and (mask == 255).sum() == (plain == 255).sum() - 2
    assert set(np.unique(mask)) == {0, 128, 255}


def test_the_colour_maker_balances_a_warm_dusk_light_out_of_a_wooden_stake() -> None:
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, colour_mask

    rgb = np.zeros((60, 80, 3), np.float32)
    rgb[:] = (60, 140, 50)  # leaves
    rgb[:, 60:64] = (170, 155, 130)  # a tan stake
    cv2.circle(rgb, (25, 30), 5, (200, 30, 25), -1)  # a red fruit
    dusk = np.clip(rgb * np.array([0.30, 0.15, 0.06]) / 0.30, 0, 255).astype(np.uint8)  # the low sun's colour
    stake = np.zeros((60, 80), bool)
    stake[:, 60:64] = True
    tinted = colour_mask(dusk, MaskMakerConfig(colour_balance="none"))
    assert (tinted[stake] == 255).mean() > 0.5  # the warm light makes the stake a fruit's colour
    balanced = colour_mask(dusk, MaskMakerConfig())
    assert (balanced[stake] == 255).sum() == 0 and balanced[30, 25] == 255


def test_the_thermal_maker_finds_a_warm_fruit_and_leaves_the_unseen_unknown() -> None:
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, thermal_mask

    rng = np.random.default_rng(0)
    thermal = np.clip(100 + rng.normal(0, 2, (60, 80)), 0, 255).astype(np.uint8)
    cv2.circle(thermal, (40, 30), 4, 160, -1)
    seen = np.ones((60, 80), bool)
    seen[:, :10] = False  # outside the thermal camera's view
    mask = thermal_mask(thermal, seen, MaskMakerConfig(polarity="warm"))
    assert (mask[:, :10] == 128).all()
    assert mask[30, 40] == 255 and (mask[seen] == 255).sum() < 80
    assert (thermal_mask(thermal, np.zeros_like(seen), MaskMakerConfig()) == 128).all()


def test_processing_makes_masks_from_the_frames_and_records_how(tmp_path: Path) -> None:
    raw = make_raw_capture(tmp_path / "raw", n=4)
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False,
                                                               fruit_mask_maker="auto"))  # fmt: skip
    import json

    record = json.loads((out / "transforms.json").read_text())["agrinerf"]["fruit_masks"]
    assert record["source"] == "maker:auto" and sum(record["frames"].values()) == 4
    outputs = AgriNeRFDataParserConfig(data=out).setup().get_dataparser_outputs("train")
    assert len(outputs.metadata["fruit_mask_filenames"]) == len(outputs.image_filenames)
    # whose view each mask holds: the thermal maker's are the thermal camera's (supervised along its rays)
    frames = json.loads((out / "transforms.json").read_text())["frames"]
    thermal = [frame.get("fruit_mask_camera", "rgb") == "thermal" for frame in frames]
    assert sum(thermal) == record["frames"]["thermal"]
    thermal_only = process_capture(raw, tmp_path / "ds_thermal", ProcessConfig(poses="given", show_progress=False,
                                                                               fruit_mask_maker="thermal"))  # fmt: skip
    parsed = AgriNeRFDataParserConfig(data=thermal_only).setup().get_dataparser_outputs("train")
    assert parsed.metadata["fruit_mask_thermal"] == [True] * len(parsed.image_filenames)
    with pytest.raises(ValueError, match="either --fruit-masks DIR or --fruit-mask-maker"):
        process_capture(raw, tmp_path / "ds2", ProcessConfig(poses="given", show_progress=False,
                                                             fruit_mask_maker="colour", fruit_masks=tmp_path))  # fmt: skip


def test_the_thermal_blob_rule_fills_a_fruit_and_ignores_edges_and_leaves() -> None:
    """A warm fruit on a canopy is found whole; the straight edge of a cold sky, which a local contrast marks, is not
    fruit; with the scene's polarity set, the other side's blobs (a cold gap in the canopy) go."""
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, thermal_mask

    rng = np.random.default_rng(0)
    celsius = 15.0 + rng.normal(0, 0.2, (120, 160)).astype(np.float32)
    celsius[:25] = 2.0  # a cold sky above the canopy: a straight edge
    rows, cols = np.mgrid[0:120, 0:160]
    fruit = (rows - 70) ** 2 + (cols - 50) ** 2 <= 10**2  # 20 px across: wider than the contrast rule's 6 px scale
    celsius[fruit] = 19.0
    hole = (rows - 80) ** 2 + (cols - 120) ** 2 <= 6**2  # a cold gap in the canopy
    celsius[hole] = 5.0
    seen = np.ones(celsius.shape, bool)
    mask = thermal_mask(celsius, seen, MaskMakerConfig())
    assert (mask[fruit] == 255).mean() > 0.9, "the whole fruit, not its rim"
    assert (mask[20:30] == 255).mean() < 0.02, "the sky's edge is no fruit"
    assert (mask[~fruit & ~hole] == 255).mean() < 0.02
    band = thermal_mask(celsius, seen, MaskMakerConfig(thermal_rule="contrast"))
    assert (band[20:30] == 255).mean() > 0.2, "the earlier rule marks a band along the sky's edge"
    assert (mask[hole] == 255).mean() > 0.5  # "both": a cold blob in the canopy is taken for a cool fruit
    warm = thermal_mask(celsius, seen, MaskMakerConfig(polarity="warm"))
    assert (warm[hole] == 255).sum() == 0 and (warm[fruit] == 255).mean() > 0.9


def test_yolo_boxes_become_ellipses_with_unknown_corners_and_unsure_boxes() -> None:
    """A confident box is fruit in its inscribed ellipse and unknown in its corners; an unsure box is unknown; a box
    under the unsure score is background; a confident fruit wins where another box's corner overlaps it."""
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, box_mask

    boxes = np.array([[10, 10, 30, 30], [40, 5, 50, 15], [2, 35, 12, 45], [28, 10, 38, 30]], float)
    mask = box_mask(48, 64, boxes, np.array([0.9, 0.1, 0.01, 0.2]), MaskMakerConfig())
    assert mask[20, 20] == 255 and mask[10, 10] == 128 and mask[29, 11] == 128  # centre; corners
    yy, xx = np.mgrid[0:48, 0:64] + 0.5
    disc = (xx - 20) ** 2 + (yy - 20) ** 2 <= 100
    assert np.array_equal(mask == 255, disc)  # the ellipse of a square box is its inscribed disc, nothing else
    assert (mask[5:15, 40:50] == 128).all()  # unsure: neither fruit nor background
    assert (mask[35:45, 2:12] == 0).all()  # below the unsure score: background
    assert mask[20, 29] == 255 and mask[11, 37] == 128  # the fruit inside an unsure box's corner stays fruit
    assert (mask[:, 55:] == 0).all()


def test_the_yolo_maker_is_refused_before_any_output(tmp_path: Path) -> None:
    raw = make_raw_capture(tmp_path / "raw", n=4)
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig

    with pytest.raises(ValueError, match="needs --mask-maker.yolo-weights"):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False,
                                                             fruit_mask_maker="yolo"))  # fmt: skip
    missing = tmp_path / "best.pt"
    with pytest.raises(ValueError, match=f"{missing}: --mask-maker.yolo-weights: no such weights file"):
        process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False, fruit_mask_maker="yolo",
                                                             mask_maker=MaskMakerConfig(yolo_weights=missing)))  # fmt: skip
    assert not (tmp_path / "ds").exists() and not list(tmp_path.glob(".ds*"))


@pytest.mark.slow
def test_the_yolo_maker_writes_box_masks_from_a_real_detector(tmp_path: Path) -> None:
    """The real Ultralytics model (untrained, built from its YAML, nothing downloaded) runs on each processed RGB frame;
    every frame's mask is the boxes' mask of that frame's own detections, and the dataset records the rule."""
    pytest.importorskip("ultralytics", reason="optional [detect] extra: scripts/install_detect.sh")
    import json

    from agrinerf_ns.fruit.yolo import box_predictor, configure_offline
    from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, box_mask

    configure_offline()
    from ultralytics import YOLO

    weights = tmp_path / "untrained.pt"
    YOLO("yolov8n.yaml").save(str(weights))
    raw = make_raw_capture(tmp_path / "raw", n=4)
    settings = MaskMakerConfig(yolo_weights=weights, box_confidence=1e-4, unsure_confidence=0.0)  # untrained: low
    out = process_capture(raw, tmp_path / "ds", ProcessConfig(poses="given", show_progress=False,
                                                               fruit_mask_maker="yolo", mask_maker=settings))  # fmt: skip
    meta = json.loads((out / "transforms.json").read_text())
    record = meta["agrinerf"]["fruit_masks"]
    assert record["source"] == "maker:yolo" and record["settings"]["yolo_weights"] == str(weights)
    assert record["frames"]["yolo"] + record["frames"]["thermal"] == 4
    predict = box_predictor(weights, 0.0)
    fruit_pixels = 0
    for frame in meta["frames"]:
        if frame.get("fruit_mask_camera", "rgb") != "rgb":
            continue
        bgr = cv2.imread(str(out / frame["file_path"]))
        written = cv2.imread(str(out / frame["fruit_mask_file_path"]), cv2.IMREAD_GRAYSCALE)
        boxes, scores = predict(bgr)
        assert np.array_equal(written, box_mask(bgr.shape[0], bgr.shape[1], boxes, scores, settings))
        assert set(np.unique(written)) <= {0, 128, 255}
        fruit_pixels += int((written == 255).sum())
    assert fruit_pixels > 0  # the detector's boxes reached the masks
