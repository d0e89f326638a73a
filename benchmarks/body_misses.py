"""Why the thermal bodies miss the row's countable fruit: each fruit's stage of loss, against the truth (#60).

``python benchmarks/body_misses.py --counts LABEL=COUNT_DIR... --out FILE.md`` reads each ``agrinerf-count --path
bodies`` folder written with ``--truth`` and ``--max-range`` (its ``count.json`` names the dataset, the capture and
the row's range), detects the thermal blobs of the dataset's frames again with the data stage's settings, labels each
blob with the true fruit the thermal camera sees at its centre (``fruit_mask_quality.thermal_view_fruit``: the truth's
depth and fruit ids projected into the thermal camera), decides the bodies again, and gives each countable fruit of
the row the first stage that lost it:

- *counted*: a counted fruit lies within the match distance (``fruits.csv``'s ``truth_id``);
- *no blob*: no frame's blob lies on it;
- *not placed*: blobs on it, none seen at one place in ``min_views`` frames;
- *not compact*: placed, none compact (``region_ratio`` above the bodies' bound: it is part of a larger warm or cool
  region, such as a warmer stake or ground behind the fruit);
- *other test*: placed and compact, dropped by the canopy offset or the polarity;
- *kept, not counted*: sightings kept as fruit, no counted fruit within the match distance (placed too far, merged
  with a neighbour, or too few sightings for the clustering).
"""

from __future__ import annotations

import csv
import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Dict, List

import numpy as np
import tyro

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fruit_mask_quality as quality  # noqa: E402

from agrinerf_ns.count.fruit_score import align_to_capture, read_truth_fruit  # noqa: E402
from agrinerf_ns.count.pipeline import CountConfig, raw_training_frames, truth_tiers  # noqa: E402
from agrinerf_ns.count.row_range import in_range  # noqa: E402
from agrinerf_ns.fruit.thermal_bodies import decide_bodies  # noqa: E402
from agrinerf_ns.process import align  # noqa: E402
from agrinerf_ns.process.fruit_mask_makers import MaskMakerConfig, frame_blobs, thermal_frame  # noqa: E402
from agrinerf_ns.process.readers import read_calibration  # noqa: E402

STAGES = ("counted", "no blob", "not placed", "not compact", "other test", "kept, not counted")


@dataclass
class MissArgs:
    counts: List[str] = field(default_factory=list)
    """LABEL=FOLDER: agrinerf-count --path bodies folders written with --truth and --max-range."""
    out: Path = Path("body_misses.md")
    """The table to write."""


def blob_truth(raw: Path, dataset: Path, config: MaskMakerConfig):
    """The dataset's thermal blobs (as the data stage finds them) and the true fruit id under each (-1: none)."""
    meta = json.loads((dataset / "transforms.json").read_text())
    calib = read_calibration(raw / "calib.yaml")
    maps = align.undistort_maps(calib.rgb)
    warp = align.warp_maps(calib.rgb, calib.thermal, float(meta["agrinerf"]["alignment"]["plane_depth"]))
    blobs, ids = [], []
    for k, frame in enumerate(meta["frames"]):
        thermal, seen = thermal_frame(dataset, frame, config)
        found = frame_blobs(thermal, seen, config, k)
        under = quality.thermal_view_fruit(raw, frame, quality.truth_fruit(raw, Path(frame["raw_rgb"]).name, maps),
                                           maps, calib, warp)  # fmt: skip
        for b in found:
            r, c = int(round(b.row)), int(round(b.col))
            values = under[max(0, r - 1) : r + 2, max(0, c - 1) : c + 2].ravel()
            ids.append(int(np.bincount(values).argmax()) - 1)  # fruit_ids hold k + 1 for fruit k
        blobs += found
    return blobs, np.array(ids, np.int64), quality.dataset_views(raw, dataset)


def fruit_stages(folder: Path) -> Dict[str, object]:
    """Each countable fruit of the row's stage (see the module), with the region ratios of the missed fruit's blobs."""
    report = json.loads((folder / "count.json").read_text())
    raw, dataset, reach = Path(report["truth"]), Path(report["source"]).parent, report["max_range"]
    if not dataset.is_absolute() and not dataset.is_dir():  # counted from the count folder's parent
        dataset = folder.parent / dataset
    config = MaskMakerConfig()
    blobs, ids, views = blob_truth(raw, dataset, config)
    decision = decide_bodies(blobs, views, config.bodies, radiometric=True)
    truth = read_truth_fruit(raw)
    meta = json.loads((dataset / "transforms.json").read_text())
    train = raw_training_frames(dataset, [f["file_path"] for f in meta["frames"]])
    cameras = np.array([np.asarray(f["transform_matrix"], np.float64)[:3, 3] for f in meta["frames"]])
    to_capture = align_to_capture(dataset, raw)
    near = in_range(truth.centres, to_capture.apply(cameras), None if reach is None else reach * to_capture.scale)
    countable = truth_tiers(raw, train, truth, CountConfig(), near)["countable"]
    with open(folder / "fruits.csv", newline="") as handle:
        counted = {int(row["truth_id"]) for row in csv.DictReader(handle)}
    compact = np.array([0.0 < b.region_ratio <= config.bodies.max_region_ratio for b in blobs], bool)
    stages: Dict[str, int] = dict.fromkeys(STAGES, 0)
    ratios: List[float] = []
    for fid in truth.ids[countable]:
        on = ids == fid
        if int(fid) in counted:
            stage = "counted"
        elif not on.any():
            stage = "no blob"
        elif not (on & decision.placed).any():
            stage = "not placed"
        elif not (on & decision.placed & compact).any():
            stage = "not compact"
            ratios += [blobs[k].region_ratio for k in np.flatnonzero(on & decision.placed)]
        elif not (on & decision.fruit).any():
            stage = "other test"
        else:
            stage = "kept, not counted"
        stages[stage] += 1
    kept_on_fruit = int((decision.fruit & (ids >= 0)).sum())
    return {"countable": int(countable.sum()), "stages": stages, "kept": int(decision.fruit.sum()),
            "kept_on_fruit": kept_on_fruit, "ratios": ratios}  # fmt: skip


def main(args: MissArgs) -> None:
    lines = [
        "| count | countable | "
        + " | ".join(STAGES)
        + " | kept sightings on a fruit | region ratio of the not-compact "
        "fruit's blobs (median) |",
        "|---|---|" + "---|" * len(STAGES) + "---|---|",
    ]
    for item in args.counts:
        label, folder = item.split("=", 1)
        found = fruit_stages(Path(folder))
        stages = found["stages"]
        assert isinstance(stages, dict)
        ratios = found["ratios"]
        assert isinstance(ratios, list)
        median = f"{np.median(ratios):.1f}" if ratios else "-"
        lines.append(f"| {label} | {found['countable']} | " + " | ".join(str(stages[s]) for s in STAGES)
                     + f" | {found['kept_on_fruit']} of {found['kept']} | {median} |")  # fmt: skip
        print(lines[-1], flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main(tyro.cli(MissArgs))
