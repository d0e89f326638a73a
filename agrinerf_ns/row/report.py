"""The row folder: the segments' counts joined (:mod:`agrinerf_ns.row.join`) into one fruit map, its yield per metre,
its map and its report, scored against a synthetic capture's truth where there is one.

``OUT/row/`` (written by the driver only, atomically): ``fruits.csv`` (world position, diameter, temperature, views,
the segment it came from, and with a truth its place in the capture's frame and the true fruit it matches),
``fruits.ply`` (the count's writer), ``row_yield.csv`` and ``row_map.png`` (:mod:`agrinerf_ns.row.yield_map`),
``row.md`` and ``row.json``. The truth scores are the count's own (:func:`agrinerf_ns.count.pipeline.score_result`:
one alignment of the whole dataset to the capture, the truth visible from the segments' training frames, within
``--count.max-range`` of the row's cameras) for the joined row and for the segments' counts put together unjoined.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence

import numpy as np
from jaxtyping import Bool, Float

from agrinerf_ns.atomic import atomic_output_dir
from agrinerf_ns.count.cluster import Fruit
from agrinerf_ns.count.fruit_score import CountScore, Similarity, align_to_capture, match_fruit, score_fruit
from agrinerf_ns.count.pipeline import CountConfig, CountResult, raw_training_frames, score_result
from agrinerf_ns.count.write import read_csv, write_ply
from agrinerf_ns.row.join import JoinResult, join_fruit
from agrinerf_ns.row.segment_steps import segment_folders
from agrinerf_ns.row.segments import Segment, camera_centres, read_transforms, trajectory_order
from agrinerf_ns.row.yield_map import along_row, correlation, draw_row_map, path_length, write_yield_csv, yield_bins
from agrinerf_ns.survey.intervals import mean_interval
from agrinerf_ns.survey.stages import STAGES, read_record

ROW_DIR = "row"
ROW_COLUMNS = ("id", "x", "y", "z", "diameter", "views", "detections", "temperature_c", "score", "segment", "copies",
               "along_m")  # fmt: skip
"""x, y, z, diameter: the capture's world frame (the dataset's, as in the segments' fruits.csv); along_m: the place
along the driven path; copies: how many segments counted the fruit."""
CAPTURE_COLUMNS = ("x_capture", "y_capture", "z_capture", "truth_id")


@dataclass(frozen=True)
class RowSettings:
    """How the segments' counts are joined and binned."""

    join_distance: float
    bin_m: float
    count: CountConfig


def double_counts(
    predicted: Float[np.ndarray, "m 3"],
    truth: Float[np.ndarray, "n 3"],
    visible: Bool[np.ndarray, " n"],
    distance: float,
) -> int:
    """Counted fruit that are a second copy of a visible true fruit: not matched one-to-one (the count's matching,
    :func:`~agrinerf_ns.count.fruit_score.match_fruit`) but within ``distance`` of a visible true fruit another counted
    fruit matched."""
    predicted = np.asarray(predicted, np.float64).reshape(-1, 3)
    rows, cols = match_fruit(predicted, truth, distance)
    matched = np.zeros(len(truth), bool)
    matched[cols] = True
    spare = np.setdiff1d(np.arange(len(predicted)), rows)
    if len(spare) == 0 or len(truth) == 0:
        return 0
    d = np.linalg.norm(predicted[spare, None, :] - np.asarray(truth)[None, :, :], axis=-1)
    near = (d <= distance) & matched[None, :] & np.asarray(visible, bool)[None, :]
    return int(near.any(axis=1).sum())


def _score(fruit: Sequence[Fruit], dataset: Path, train: Sequence[str], raw: Path, config: CountConfig,
           cameras: np.ndarray) -> CountResult:  # fmt: skip
    result = CountResult(list(fruit), [], [], 0.0)
    score_result(result, dataset, train, raw, config, cameras)
    return result


def _in_segment_frames(
    row: CountResult, joined: JoinResult, folders: Sequence[Any], raw: Path, config: CountConfig
) -> Dict[str, Any]:
    """The joined row scored with each fruit carried into the capture's frame by the alignment of the segment it was
    kept from (that segment's cameras fitted to the true ones), not by one fit of the whole row: a long row's
    odometry drifts, so one fit misplaces fruit that each segment placed well (results/row/README.md)."""
    assert row.truth is not None and row.visible is not None
    fits = [align_to_capture(f.data, raw) if config.align == "poses" else Similarity.identity() for f in folders]
    capture = np.array([fits[r.segment].apply(np.asarray(r.fruit.centre, np.float64)[None])[0]
                        for r in joined.fruit]).reshape(-1, 3)  # fmt: skip
    score = score_fruit(capture, row.truth, row.visible, config.match_distance, None, row.tiers.get("well_seen"),
                        row.tiers.get("countable"))  # fmt: skip
    return _score_fields(score)


def _score_fields(s: CountScore) -> Dict[str, Any]:
    """The row table's fields of a count's score."""
    return {"fruit": s.counted, "visible": s.visible, "precision": s.precision, "recall": s.recall, "f1": s.f1,
            "count_error": s.count_error, "f1_countable": s.f1_countable, "recall_countable": s.recall_countable,
            "count_error_countable": s.count_error_countable}  # fmt: skip


def _scored(result: CountResult, config: CountConfig) -> Dict[str, Any]:
    assert result.score is not None and result.truth is not None and result.to_capture is not None
    capture = result.to_capture.apply(np.array([f.centre for f in result.fruit]).reshape(-1, 3))
    assert result.visible is not None
    doubles = double_counts(capture, result.truth.centres, result.visible, config.match_distance)
    counted = result.score.counted
    return _score_fields(result.score) | {"double_counts": doubles,
                                          "double_count_rate": doubles / counted if counted else math.nan}  # fmt: skip


def assemble_row(
    out: Path,
    dataset: Path,
    segments: Sequence[Segment],
    settings: RowSettings,
    truth: Optional[Path],
    header: str,
    wall: Dict[str, float],
) -> Dict[str, Any]:
    """Join the segments' counts (each ``OUT/segments/<segNN>/count/fruits.csv``) and write ``OUT/row``; returns the
    row's summary (``row.json``); ``wall``: the wall times so far (s), to which the join's own is added."""
    start = time.perf_counter()
    meta = read_transforms(dataset)
    order = trajectory_order(meta["frames"])
    cameras = camera_centres(meta["frames"], order)
    folders = [segment_folders(out, s) for s in segments]
    per_segment = [read_csv(f.count / "fruits.csv") for f in folders]
    joined = join_fruit(per_segment, segments, cameras, settings.join_distance)
    kept = [r.fruit for r in joined.fruit]
    centres = np.array([f.centre for f in kept]).reshape(-1, 3)
    length = float(path_length(cameras)[-1])
    along = along_row(centres, cameras)
    summary: Dict[str, Any] = {"fruit": len(kept), "segments_alone": sum(len(f) for f in per_segment),
                               "joined_pairs": {f"{a}-{b}": n for (a, b), n in joined.pairs.items()},
                               "path_m": length, "segments": []}  # fmt: skip
    truth_along, capture, truth_ids = None, None, None
    if truth is not None:
        train = sorted({stem for f in folders for stem in raw_training_frames(f.data, [])})
        row = _score(kept, dataset, train, truth, settings.count, cameras)
        alone = _score([f for fruit in per_segment for f in fruit], dataset, train, truth, settings.count, cameras)
        scored = {"row": _scored(row, settings.count), "alone": _scored(alone, settings.count),
                  "row_in_segment_frames": _in_segment_frames(row, joined, folders, truth, settings.count)}  # fmt: skip
        assert row.truth is not None and row.visible is not None and row.to_capture is not None
        truth_along = along_row(row.to_capture.inverse(row.truth.centres[row.visible]), cameras)
        capture = row.to_capture.apply(centres)
        rows, cols = match_fruit(capture, row.truth.centres, settings.count.match_distance)
        truth_ids = np.full(len(kept), -1, np.int64)
        truth_ids[rows] = row.truth.ids[cols]
        own = [(f.get("score") or {}) for f in (read_record(x, "count") or {} for x in folders)]
        f1, f1_half = mean_interval([o.get("f1", math.nan) for o in own])
        error, error_half = mean_interval([o.get("count_error", math.nan) for o in own])
        scored["segments_own"] = {"f1": f1, "f1_half": f1_half, "count_error": error,
                                  "count_error_half": error_half, "segments": len(own)}  # fmt: skip
        summary["truth"] = scored
    bins = yield_bins(along, length, settings.bin_m, truth_along)
    if bins.truth is not None:
        r, lo, hi = correlation(bins.counts, bins.truth)
        summary["per_metre_correlation"] = {"r": r, "low": lo, "high": hi, "bins": len(bins.counts)}
    for segment, f in zip(segments, folders, strict=True):
        records = {stage: read_record(f, stage) for stage in ("cut", *STAGES[1:])}
        count = records["count"] or {}
        summary["segments"].append({
            "segment": segment.name, "frames": [segment.start, segment.stop],
            "fruit": count.get("fruit"), "fruit_interval": count.get("fruit_interval"),
            "kept": sum(1 for r in joined.fruit if r.segment == segment.index),
            "score": count.get("score"),
            "wall_s": {stage: (rec or {}).get("wall_s") for stage, rec in records.items()},
        })  # fmt: skip
    driven = path_length(cameras)
    overlaps = [
        (float(driven[b.start]), float(driven[a.stop - 1])) for a, b in zip(segments, segments[1:], strict=False)
    ]
    with atomic_output_dir(Path(out) / ROW_DIR, overwrite=True) as tmp:
        summary["wall_s"] = dict(wall) | {"join and score": time.perf_counter() - start}
        write_row_csv(tmp / "fruits.csv", joined, along, capture, truth_ids)
        write_ply(tmp / "fruits.ply", kept)
        write_yield_csv(tmp / "row_yield.csv", bins)
        temps = np.array([np.nan if f.temperature is None else f.temperature for f in kept], np.float64)
        draw_row_map(tmp / "row_map.png", centres, temps, cameras, bins, overlaps,
                     f"{len(kept)} fruit along {length:.1f} m in {len(segments)} segments")  # fmt: skip
        (tmp / "row.md").write_text(row_markdown(summary, header, settings))
        (tmp / "row.json").write_text(json.dumps(summary, indent=1, default=_json) + "\n")
    return summary


def _json(value: Any) -> Any:
    return (
        float(value) if isinstance(value, np.floating) else int(value) if isinstance(value, np.integer) else str(value)
    )


def write_row_csv(
    path: Path,
    joined: JoinResult,
    along: np.ndarray,
    capture: Optional[np.ndarray] = None,
    truth_ids: Optional[np.ndarray] = None,
) -> None:
    """The row's ``fruits.csv``: one line per fruit kept (with ``capture`` its centre in the capture's frame and the
    true fruit it matches, -1: none)."""
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(ROW_COLUMNS + (CAPTURE_COLUMNS if capture is not None else ()))
        for i, (item, copies) in enumerate(zip(joined.fruit, joined.copies, strict=True)):
            f = item.fruit
            row: List[object] = [i, *(f"{float(v):.4f}" for v in f.centre), f"{f.diameter:.4f}", f.views,
                                 f.detections, "" if f.temperature is None else f"{f.temperature:.2f}",
                                 f"{f.score:.3f}", f"seg{item.segment:02d}", copies, f"{along[i]:.3f}"]  # fmt: skip
            if capture is not None and truth_ids is not None:
                row += [*(f"{float(v):.4f}" for v in capture[i]), int(truth_ids[i])]
            writer.writerow(row)


def _n(value: Any, digits: int = 2, signed: bool = False) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:+.{digits}f}" if signed else f"{value:.{digits}f}"


def row_markdown(summary: Dict[str, Any], header: str, settings: RowSettings) -> str:
    """``row.md``: the count, the segments, the truth scores where there is a truth, the wall time per stage."""
    lines = [header, "", f"**{summary['fruit']} fruit** along {summary['path_m']:.1f} m of driven path "
             f"({summary['segments_alone']} in the segments' counts before the join; "
             f"{sum(summary['joined_pairs'].values())} pairs joined at borders within {settings.join_distance:g} m). "
             f"Yield per {settings.bin_m:g} m: row_yield.csv, row_map.png.", "",
             "| segment | frames | fruit (95% jackknife) | kept in the row | F1 | count error "
             "| cut / train / count (s) |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for s in summary["segments"]:
        interval = s.get("fruit_interval") or [None, None]
        score = s.get("score") or {}
        times = " / ".join(_n(s["wall_s"].get(k), 0) for k in ("cut", "train", "count"))
        lines.append(f"| {s['segment']} | {s['frames'][0]}-{s['frames'][1] - 1} | {s['fruit']} "
                     f"({_n(interval[0], 1)} to {_n(interval[1], 1)}) | {s['kept']} | {_n(score.get('f1'))} | "
                     f"{_n(score.get('count_error'), 2, True)} | {times} |")  # fmt: skip
    truth = summary.get("truth")
    if truth:
        own = truth["segments_own"]
        lines += ["", "Against the truth (the visible true fruit of the segments' training frames"
                  + ("" if settings.count.max_range is None else f" within {settings.count.max_range:g} m of a camera")
                  + f"; matched within {settings.count.match_distance:g} m):", "",
                  "| count | fruit | visible truth | precision | recall | F1 | count error | double counts (share) |",
                  "|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for key, label in (("row", "the row, joined"), ("alone", "the segments' counts summed, unjoined")):
            t = truth[key]
            lines.append(f"| {label} | {t['fruit']} | {t['visible']} | {_n(t['precision'])} | {_n(t['recall'])} | "
                         f"{_n(t['f1'])} | {_n(t['count_error'], 2, True)} | {t['double_counts']} "
                         f"({_n(100 * t['double_count_rate'], 1)}%) |")  # fmt: skip
        t = truth.get("row_in_segment_frames")
        if t:
            lines.append(f"| the row, joined, each fruit aligned as its segment | {t['fruit']} | {t['visible']} | "
                         f"{_n(t['precision'])} | {_n(t['recall'])} | {_n(t['f1'])} | {_n(t['count_error'], 2, True)} "
                         "| |")  # fmt: skip
        lines.append(f"| the segments' own (mean ± 95% t interval over {own['segments']}) | | | | | "
                     f"{_n(own['f1'])} ± {_n(own['f1_half'])} | {_n(own['count_error'], 2, True)} ± "
                     f"{_n(own['count_error_half'])} | |")  # fmt: skip
        if math.isfinite(own["count_error"]) and own["count_error"] > -1:
            low, high = (own["count_error"] + own["count_error_half"], own["count_error"] - own["count_error_half"])
            estimate = [summary["fruit"] / (1 + e) if e > -1 else math.inf for e in (low, high)]
            lines.append(f"\nThe row's fruit corrected by the segments' count error (its 95% interval): "
                         f"{_n(summary['fruit'] / (1 + own['count_error']), 0)} ({_n(estimate[0], 0)} to "
                         f"{_n(estimate[1], 0)}) visible fruit.")  # fmt: skip
        corr = summary.get("per_metre_correlation")
        if corr:
            lines += ["", f"Fruit per bin against the truth's: r = {_n(corr['r'])} (95% interval {_n(corr['low'])} "
                      f"to {_n(corr['high'])}, {corr['bins']} bins)."]  # fmt: skip
    wall = summary.get("wall_s", {})
    lines += ["", "Wall time (s): " + ", ".join(f"{k} {_n(v, 1)}" for k, v in wall.items()) + "."]
    return "\n".join(lines) + "\n"
