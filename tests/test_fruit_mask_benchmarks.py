"""The fruit-mask benchmark (`benchmarks/fruit_mask_quality.py`) on a tiny synthetic capture: it scores the masks a
dataset has, sweeps the colour maker's floor, and writes oracle masks from the truth."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2

ROOT = Path(__file__).resolve().parent.parent


def test_mask_quality_rows_and_oracle(tmp_path: Path) -> None:
    raw, ds = tmp_path / "raw", tmp_path / "ds"
    subprocess.run(["agrinerf-synth", "--out", str(raw), "--scene", "orchard", "--lighting", "bright", "--seed", "0",
                    "--views", "6", "--width", "96", "--height", "72", "--rgb-hfov-deg", "30", "--no-preview"],
                   check=True, capture_output=True)  # fmt: skip
    subprocess.run(["agrinerf-process", "--raw", str(raw), "--out", str(ds), "--poses", "given",
                    "--fruit-mask-maker", "colour"], check=True, capture_output=True)  # fmt: skip
    script = str(ROOT / "benchmarks" / "fruit_mask_quality.py")
    done = subprocess.run([sys.executable, script, "--raw", str(raw), "--dataset", str(ds), "--colour-scores", "0", "2"],
                          check=True, capture_output=True, text=True)  # fmt: skip
    rows = [line.split("|") for line in done.stdout.splitlines() if line.startswith("| orchard")]
    assert len(rows) == 2
    recall = [float(r[5]) for r in rows]
    assert 0.0 < recall[0] <= 1.0 and recall[1] == 0.0  # a floor of 2 is above every colour score: nothing is fruit
    # the balance and the speck rule swept beside the floor: one row each, unknown specks counted apart
    swept = subprocess.run([sys.executable, script, "--raw", str(raw), "--dataset", str(ds), "--colour-scores", "0.3",
                            "--balance", "none", "grey-world", "--min-region-pixels", "0", "8"],
                           check=True, capture_output=True, text=True)  # fmt: skip
    rows = [line.split("|") for line in swept.stdout.splitlines() if line.startswith("| orchard")]
    settings = [[part.strip() for part in r[2].split(",")] for r in rows]
    assert [(s[2], s[4]) for s in settings] == [("balance none", "specks under 0 px unknown"),
                                                ("balance none", "specks under 8 px unknown"),
                                                ("balance grey-world", "specks under 0 px unknown"),
                                                ("balance grey-world", "specks under 8 px unknown")]  # fmt: skip
    regions = [int(r[8].split("/")[1].split()[0]) for r in rows]
    assert regions[1] <= regions[0] and regions[3] <= regions[2]  # specks left unknown are no longer regions
    assert all(0.0 <= float(r[10]) <= 1.0 for r in rows)
    oracle = tmp_path / "oracle"
    subprocess.run([sys.executable, script, "--raw", str(raw), "--write-oracle", str(oracle)], check=True)
    masks = sorted(oracle.glob("*.png"))
    assert len(masks) == 6 and max(int(cv2.imread(str(m), 0).max()) for m in masks) == 255
    assert "Command: `python benchmarks/fruit_mask_quality.py" in done.stdout
    # the thermal rules, scored in the thermal camera's view (the truth seen along its rays)
    thermal = subprocess.run([sys.executable, script, "--raw", str(raw), "--dataset", str(ds), "--blob-thresholds", "2",
                              "--thermal-contrast"], check=True, capture_output=True, text=True)  # fmt: skip
    rows = [line.split("|") for line in thermal.stdout.splitlines() if line.startswith("| orchard")]
    assert [r[2].strip().split(" (")[0].split(",")[0] for r in rows] == ["thermal blobs", "thermal contrast"]
    touched = [int(r[7].split("/")[0]) for r in rows]
    assert all(0.0 <= float(r[k]) <= 1.0 for r in rows for k in (4, 5, 6)) and max(touched) > 0
