"""Table III / IV writers and the detection picture."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from agrinerf_ns.detect.figure import PanelBoxes, detection_figure
from agrinerf_ns.detect.scoring import ImageBoxes, score_detections
from agrinerf_ns.detect.tables import ResultRow, table_iv_markdown, write_tables


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
