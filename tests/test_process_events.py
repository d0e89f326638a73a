"""Event windows at the RGB timestamps: streamed accumulation equals a direct count; representation."""

import numpy as np
import pytest

from agrinerf_ns.images import to_uint8
from agrinerf_ns.process.event_frames import (
    EventFrameConfig,
    accumulate_windows,
    event_windows,
    to_unit_frame,
)
from agrinerf_ns.process.readers import EventChunk


def _stream(n=20000, w=12, h=9, seed=0):
    rng = np.random.default_rng(seed)
    t = np.sort(rng.integers(0, 1_000_000, n)).astype(np.int64)
    return (
        rng.integers(0, w, n).astype(np.uint16),
        rng.integers(0, h, n).astype(np.uint16),
        t,
        rng.integers(0, 2, n).astype(np.uint8),
    )


def _chunks(x, y, t, p, size):
    for s in range(0, len(t), size):
        yield EventChunk(x[s : s + size], y[s : s + size], t[s : s + size], p[s : s + size])


@pytest.mark.parametrize("anchor,window", [("end", None), ("center", 0.25), ("end", 0.02)])
@pytest.mark.parametrize("chunk", [997, 50000])
def test_streamed_windows_equal_direct_count(anchor, window, chunk):
    x, y, t, p = _stream()
    frame_times = np.linspace(0.05, 1.1, 12)  # last windows run past the stream's end
    start, end, wlen = event_windows(frame_times, EventFrameConfig(window_s=window, anchor=anchor))
    got = list(accumulate_windows(_chunks(x, y, t, p, chunk), start, end, 12, 9))
    assert [k for k, _, _ in got] == list(range(12))
    for k, pos, neg in got:
        s_us, e_us = round(start[k] * 1e6), round(end[k] * 1e6)
        sel = (t >= s_us) & (t < e_us)
        ref_pos = np.zeros((9, 12), int)
        ref_neg = np.zeros((9, 12), int)
        np.add.at(ref_pos, (y[sel & (p == 1)], x[sel & (p == 1)]), 1)
        np.add.at(ref_neg, (y[sel & (p == 0)], x[sel & (p == 0)]), 1)
        np.testing.assert_array_equal(pos, ref_pos)
        np.testing.assert_array_equal(neg, ref_neg)
    if window is None:
        assert wlen == pytest.approx(np.median(np.diff(frame_times)))


def test_signed_representation_and_png_encoding():
    value = np.array([[-10.0, -2.0, 0.0, 2.0, 10.0]])
    unit = to_unit_frame(value, 4.0, "signed")
    np.testing.assert_allclose(unit, [[0.0, 0.25, 0.5, 0.75, 1.0]])
    np.testing.assert_array_equal(to_uint8(unit), [[0, 64, 128, 191, 255]])
    count = to_unit_frame(np.array([[0.0, 2.0, 9.0]]), 4.0, "count")
    np.testing.assert_allclose(count, [[0.0, 0.5, 1.0]])


def test_empty_and_flooded_windows_stay_in_range():
    flood = np.full((4, 4), 1e9)
    for rep in ("signed", "count"):
        for v in (np.zeros((4, 4)), flood, -flood):
            u = to_unit_frame(v, 0.0, rep)  # zero scale must not divide by zero
            assert np.all(np.isfinite(u)) and u.min() >= 0 and u.max() <= 1
