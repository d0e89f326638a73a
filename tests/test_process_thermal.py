"""Thermal rescaling on real Fieldscale frames: local contrast, flicker, flat frames.

Measures (agrinerf_ns.process.thermal_rescale):
- local contrast: mean 9x9 local standard deviation of the 8-bit output (grey levels);
- static-pixel flicker: mean |out_t - out_t+1| over pixels whose raw count changed by <= 0.5 % of the sequence
  range; "relative flicker" divides it by the local contrast (temporal change per unit of spatial detail).
"""

import numpy as np
import pytest
from helpers.process_raw_fixture import DATA

from agrinerf_ns.process.readers import read_thermal
from agrinerf_ns.process.thermal_rescale import (
    ThermalRescaleConfig,
    ThermalRescaler,
    local_contrast,
    rescale_sequence,
    static_pixel_flicker,
)


@pytest.fixture(scope="module")
def real_frames():
    return [read_thermal(p) for p in sorted(DATA.glob("*.tiff"))]


def _measures(raws, method, **kw):
    outs = rescale_sequence(raws, ThermalRescaleConfig(method=method, **kw))
    contrast = float(np.mean([local_contrast(o) for o in outs]))
    flicker = static_pixel_flicker(raws, outs)
    return contrast, flicker, outs


def test_fieldscale_keeps_more_local_contrast_than_global(real_frames):
    c_fs, _, outs = _measures(real_frames, "fieldscale")
    c_gl, _, _ = _measures(real_frames, "global")
    assert all(o.dtype == np.uint8 and o.shape == (512, 640) for o in outs)
    assert c_fs > 2.0 * c_gl, (c_fs, c_gl)


def test_fieldscale_flickers_less_than_per_frame_minmax(real_frames):
    c_fs, f_fs, _ = _measures(real_frames, "fieldscale")
    c_pf, f_pf, _ = _measures(real_frames, "per-frame")
    # on the plain real sequence: less flicker per unit of local contrast
    assert f_fs / c_fs < f_pf / c_pf, (f_fs / c_fs, f_pf / c_pf)
    # a hot object (16x16 px, far above the scene) in every other frame: per-frame min/max re-maps the whole
    # frame, Fieldscale's extrema suppression and shared statistics keep the rest of the frame steady
    hot = [r.copy() for r in real_frames]
    for r in hot[1::2]:
        r[100:116, 300:316] = 12000
    _, f_fs_hot, _ = _measures(hot, "fieldscale")
    _, f_pf_hot, _ = _measures(hot, "per-frame")
    assert f_fs_hot < 0.2 * f_pf_hot, (f_fs_hot, f_pf_hot)


def test_shared_sequence_statistics_reduce_flicker(real_frames):
    _, f_shared, _ = _measures(real_frames, "fieldscale", temporal_sigma=3.0)
    _, f_single, _ = _measures(real_frames, "fieldscale", temporal_sigma=0.0)
    assert f_shared < f_single, (f_shared, f_single)


@pytest.mark.parametrize("method", ["fieldscale", "global", "per-frame"])
def test_flat_frames_give_valid_images(method):
    flat = [np.full((32, 40), 3000, np.uint16) for _ in range(3)]
    r = ThermalRescaler(ThermalRescaleConfig(method=method, clahe=True)).fit(flat)
    for i, f in enumerate(flat):
        out = r.apply(f, i)
        assert out.dtype == np.uint8 and out.shape == (32, 40)
        assert len(np.unique(out)) == 1  # constant in, constant out, no NaN/garbage


def test_params_recorded():
    r = ThermalRescaler(ThermalRescaleConfig(temporal_sigma=float("inf"))).fit(
        [np.arange(1200, dtype=np.uint16).reshape(30, 40)]
    )
    p = r.params()
    assert p["method"] == "fieldscale" and p["grid"] == [8, 8] and p["temporal_sigma"] == "inf"
    assert p["global_hi"] > p["global_lo"]
