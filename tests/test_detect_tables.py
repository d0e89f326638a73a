"""Table III / IV writers and the detection picture."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from agrinerf_ns.detect.box_metrics import ImageBoxes, score_detections
from agrinerf_ns.detect.figure import PanelBoxes, detection_figure
from agrinerf_ns.lab.paper_merge import merge_evaluations
from agrinerf_ns.lab.paper_tables import ResultRow, table_iv_markdown, write_tables


def _metrics(shift: float):
    true = np.array([[10, 10, 20, 20], [30, 30, 40, 40]], float)
    return score_detections([ImageBoxes(true + shift, np.array([0.9, 0.6]), true)])


def test_table_iii_groups_scenes_and_bolds_best(tmp_path: Path) -> None:
    rows = [
        ResultRow("garden", "dark", "Nerfacto (RGB)", _metrics(4.0)),
        ResultRow("garden", "dark", "Ours (Cross-Spectral)", _metrics(0.0)),
        ResultRow("orchard", "shadowed", "Nerfacto (RGB)", _metrics(0.0)),
    ]
    md, csv_path = write_tables(rows, tmp_path, "III", "table_iii", footer="Command: `x`")
    text = md.read_text()
    lines = text.splitlines()
    assert lines[0].startswith("| Scene | Method | mAP50 | mAP50-95 | Precision | Recall | F1-Score | Lighting |")
    assert "| garden | Nerfacto (RGB) |" in text and "|  | Ours (Cross-Spectral) | **100.0** | **100.0** |" in text
    # a scene with one method has no "best": nothing bold
    assert "| orchard | Nerfacto (RGB) | 100.0 |" in text and text.rstrip().endswith("Command: `x`")
    # shift 4 px on 10 px boxes: IoU 36/164 < 0.5, so no match at all
    assert "| garden | Nerfacto (RGB) | 0.0 | 0.0 | 0.000 | 0.000 | 0.000 | dark |" in text
    table = list(csv.DictReader(csv_path.open()))
    assert [(r["scene"], r["method"]) for r in table] == [
        ("garden", "Nerfacto (RGB)"),
        ("garden", "Ours (Cross-Spectral)"),
        ("orchard", "Nerfacto (RGB)"),
    ]
    assert float(table[1]["map50"]) == 1.0 and float(table[0]["map50"]) == 0.0


def test_table_iv_paper_order_and_single_scene() -> None:
    labels = ["Ours (All)", "Ours (Thermal)", "Ours (RGB)", "Ours (RGB+Events)"]
    rows = [ResultRow("garden", "dusk", label, _metrics(1.0 * i)) for i, label in enumerate(labels)]
    text = table_iv_markdown(rows)
    order = [line.split("|")[1].strip() for line in text.splitlines() if line.startswith("| Ours")]
    assert order == ["Ours (RGB)", "Ours (RGB+Events)", "Ours (Thermal)", "Ours (All)"]
    with pytest.raises(ValueError, match="one scene"):
        table_iv_markdown(rows + [ResultRow("orchard", "dark", "Ours (RGB)", _metrics(0.0))])


def test_detection_figure(tmp_path: Path) -> None:
    image = tmp_path / "000000.png"
    Image.fromarray(np.full((48, 64, 3), 90, np.uint8)).save(image)
    true = np.array([[10, 10, 20, 20]], float)
    panel = PanelBoxes(image, true, true + 1, np.array([0.8]))
    out = detection_figure({"RGB": {"000000": panel}, "Cross": {"000000": panel}}, tmp_path / "fig.png")
    assert Image.open(out).size[0] > 300
    with pytest.raises(ValueError, match="share no rendered view"):
        detection_figure({"RGB": {"000000": panel}, "Cross": {"000001": panel}}, tmp_path / "fig2.png")


def _evaluation(path: Path, lighting: str, shift: float, epochs: int = 60) -> Path:
    """A metrics.json as agrinerf-detect evaluate writes it."""
    settings = {"detector": {"epochs": epochs}, "min_box_pixels": 30, "reuse": True, "detectors_from": None}
    results = [
        {"scene": "garden", "lighting": lighting, "method": m, "step": 99, **_metrics(s).as_dict()}
        for m, s in (("Nerfacto (RGB)", 4.0), ("Ours (Cross-Spectral)", shift))
    ]
    path.mkdir(parents=True, exist_ok=True)
    (path / "metrics.json").write_text(json.dumps({"command": f"evaluate {lighting}", "settings": settings,
                                                   "results": results}))  # fmt: skip
    return path / "metrics.json"


def test_evaluations_merge_into_one_table(tmp_path: Path) -> None:
    dark = _evaluation(tmp_path / "dark", "dark", 0.0)
    dusk = _evaluation(tmp_path / "dusk", "dusk", 2.0)
    md, csv_path = merge_evaluations([dark, dusk], tmp_path / "merged", "III", "agrinerf-detect table")
    rows = list(csv.DictReader(csv_path.open()))
    assert [(r["lighting"], r["method"]) for r in rows] == [
        ("dark", "Nerfacto (RGB)"), ("dark", "Ours (Cross-Spectral)"),
        ("dusk", "Nerfacto (RGB)"), ("dusk", "Ours (Cross-Spectral)"),
    ]  # fmt: skip
    assert float(rows[1]["map50"]) == _metrics(0.0).map50 and float(rows[3]["map50"]) == _metrics(2.0).map50
    text = md.read_text()
    assert "| dark |" in text and "| dusk |" in text and "`evaluate dark`; `evaluate dusk`" in text
    with pytest.raises(ValueError, match=r"more than once: \[\('garden', 'dark', 'Nerfacto \(RGB\)'\)"):
        merge_evaluations([dark, dark], tmp_path / "twice", "III", "x")
    other = _evaluation(tmp_path / "other", "shadowed", 0.0, epochs=10)
    with pytest.raises(ValueError, match=r"other settings .*\(detector\)"):
        merge_evaluations([dark, other], tmp_path / "mixed", "III", "x")
