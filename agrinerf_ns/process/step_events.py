"""The event step of ``agrinerf-process``: the events in a window at each RGB frame time (in the frames' clock, or
through the trigger sync), counted per pixel, warped into the RGB camera and written as sums, frames and masks, and the
events inside the windows copied as the dataset's event stream."""

from __future__ import annotations

from pathlib import Path
from typing import Dict, List

import numpy as np
from rich.progress import Progress

from agrinerf_ns.dataset_format import EVENT_MASK, EVENT_STREAM, EVENT_SUMS, EVENTS
from agrinerf_ns.images import to_uint8, write_png
from agrinerf_ns.process import align, event_frames, readers
from agrinerf_ns.process.config import ProcessConfig
from agrinerf_ns.process.errors import RawInputError
from agrinerf_ns.process.event_h5 import EventH5Writer
from agrinerf_ns.process.raw_capture import Capture


def write_event_frames(
    raw: Path, tmp: Path, cap: Capture, config: ProcessConfig, names: List[str], frames: List[Dict], progress: Progress
) -> Dict:
    """Write the event sums, frames and masks of every RGB frame and the dataset's event stream under ``tmp``;
    returns the dataset's event metadata."""
    assert cap.event_file is not None and cap.calib.event is not None
    ev_cam, rgb_cam = cap.calib.event, cap.calib.rgb
    ecfg = config.events
    # windows in the frames' clock (what the dataset and the trajectory use), read in the event camera's
    t_start, t_end, window = event_frames.event_windows(cap.rgb.times, ecfg)
    to_event_clock = cap.sync.apply if cap.sync is not None else (lambda t: np.asarray(t, np.float64))
    maps = align.warp_maps(rgb_cam, ev_cam, config.plane_depth)
    mask8 = (maps[2] * 255).astype(np.uint8)
    stream = EventH5Writer(tmp / Path(EVENT_STREAM).parent, ecfg.chunk_size, Path(EVENT_STREAM).name)
    chunks = _stream_copy(
        readers.iter_event_chunks(cap.event_file, ecfg.chunk_size, sensor_wh=(ev_cam.width, ev_cam.height)),
        stream,
        cap.sync,
        float(to_event_clock(t_start[:1])[0]),
        float(to_event_clock(t_end[-1:])[0]),
    )
    task = progress.add_task("event windows", total=len(names))
    percentiles = []
    total_in_windows = 0
    windows = event_frames.accumulate_windows(
        chunks, to_event_clock(t_start), to_event_clock(t_end), ev_cam.width, ev_cam.height
    )
    for k, pos, neg in windows:
        total_in_windows += int(pos.sum() + neg.sum())
        pos_al = align.warp_image(pos.astype(np.float32), maps, nearest=True)
        neg_al = align.warp_image(neg.astype(np.float32), maps, nearest=True)
        percentiles.append(
            event_frames.window_percentile(event_frames.frame_value(pos_al, neg_al, ecfg.representation))
        )
        rel = EVENT_SUMS.path(names[k])
        (tmp / EVENT_SUMS.folder).mkdir(exist_ok=True)
        np.savez_compressed(
            tmp / rel,
            pos=np.clip(pos_al, 0, 65535).astype(np.uint16),
            neg=np.clip(neg_al, 0, 65535).astype(np.uint16),
            mask=maps[2],
            t_start=np.float64(t_start[k]),
            t_end=np.float64(t_end[k]),
        )
        frames[k][EVENT_SUMS.key] = rel
        progress.advance(task)
    stream.close(0, {"clock": "frame", "width": ev_cam.width, "height": ev_cam.height})
    if total_in_windows == 0:
        raise RawInputError(
            f"{cap.event_file}: none of its {cap.num_events} events falls in a window of the RGB frames "
            f"({t_start[0]:.3f}..{t_end[-1]:.3f} s): event and RGB timestamps do not overlap"
        )
    scale = float(ecfg.clip_count) if ecfg.clip_count else event_frames.robust_scale(percentiles)
    task = progress.add_task("event frames", total=len(names))
    for k in range(len(names)):
        with np.load(tmp / frames[k][EVENT_SUMS.key]) as z:
            value = event_frames.frame_value(
                z["pos"].astype(np.float32), z["neg"].astype(np.float32), ecfg.representation
            )
        png = to_uint8(event_frames.to_unit_frame(value, scale, ecfg.representation))
        frames[k][EVENTS.key] = EVENTS.path(names[k])
        frames[k][EVENT_MASK.key] = EVENT_MASK.path(names[k])
        write_png(tmp / frames[k][EVENTS.key], png)
        write_png(tmp / frames[k][EVENT_MASK.key], mask8)
        progress.advance(task)
    return {
        **ecfg.as_dict(),
        "window_s": window,
        "scale": scale,
        "num_events": cap.num_events,
        "events_in_windows": total_in_windows,
        "file": str(cap.event_file.relative_to(raw)),
        "sync": {"method": "trigger", **cap.sync.as_dict(), "edge": config.trigger_edge}
        if cap.sync is not None
        else {"method": "recorded"},
        "png_encoding": "value = png / 255; signed: 0.5 (png 128) = no change",
        "sums": "event_sums_path: npz with pos, neg (uint16 ON/OFF counts in RGB pixels, nearest warp), mask, "
        "t_start, t_end (s, frame clock)",
        "stream": EVENT_STREAM,
    }


def _stream_copy(chunks, sink: EventH5Writer, sync, start_s: float, end_s: float):
    """Pass the chunks through, writing their events in ``[start_s, end_s)`` (event clock) to `sink` with times
    moved into the frames' clock."""
    lo, hi = round(start_s * 1e6), round(end_s * 1e6)
    for chunk in chunks:
        a, b = np.searchsorted(chunk.t, [lo, hi], side="left")
        if b > a:
            t = chunk.t[a:b].astype(np.float64) * 1e-6
            if sync is not None:
                t = (t - sync.offset_s) / sync.scale
            sink.add(chunk.x[a:b], chunk.y[a:b], np.round(t * 1e6).astype(np.int64), chunk.p[a:b])
        yield chunk
