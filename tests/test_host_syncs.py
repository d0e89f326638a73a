"""Host syncs per training step of the `agrinerf` preset (issue 61, item 4; `benchmarks/host_syncs.py`): counted on
the CPU by a dispatch mode, taking the renders' GPU path, on a tiny bright capture with its event stream (the event
loss, its noise weighting and gate, the thermal camera's rays, the blur model from step 0). The counts may not rise
above the figures reached (results/host-syncs/README.md), and none may come from this project's own code."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from helpers.bench_script import load_bench_script

from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture

STEP_SYNCS = 9
"""Syncs per training step after step 0 (whose gate check reads its residual): Nerfstudio's pixel sampler and ray
generator, none of this project's (results/host-syncs/README.md)."""
CHUNK_SYNCS = 0
"""Syncs of a rendered eval chunk after the first (which computes the box's resolutions once)."""
SMALL = {"init_resolution": 16, "final_resolution": 24, "num_coarse_samples": 16, "num_fine_samples": 16,
         "blur_start_step": 0, "event_rays_per_batch": 64, "event_gate_samples": 64, "eval_num_rays_per_chunk": 256,
         "thermal_rays_per_batch": 64}  # fmt: skip


@pytest.fixture(scope="module")
def host_syncs():
    return load_bench_script("host_syncs")


@pytest.fixture(scope="module")
def capture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("host-syncs")
    raw = generate_capture(SynthConfig.tiny(seed=2, lighting="bright", views=8), root / "raw")
    return process_capture(raw, root / "data", ProcessConfig(poses="given", show_progress=False))


def test_the_counter_sees_every_kind_of_host_read(host_syncs) -> None:
    x = torch.arange(4.0)
    with host_syncs.HostSyncCounter() as counter:
        x[0].item(), float(x[1]), int(x[2]), bool(x[3] > 0), x.tolist(), x.cpu(), x.numpy()  # noqa: B018
        x.to("cpu")
        y = x * 2  # no read
    assert counter.total == 7 and sum(counter.moves.values()) == 1 and y.shape == (4,)
    here = Path(__file__).name
    assert all(site.startswith(f"tests/{here}:") for site in counter.syncs), counter.syncs


def _own(syncs: dict) -> dict:
    """The syncs this project's code makes itself (not in a call into Nerfstudio)."""
    return {site: n for site, n in syncs.items() if " > nerfstudio/" not in site and not site.startswith("nerfstudio/")}


@pytest.mark.slow
def test_agrinerf_steps_and_chunks_stay_within_their_host_syncs(host_syncs, capture: Path) -> None:
    args = host_syncs.Args(data=capture, out=Path("unused.json"), steps=2, rays_per_batch=64, overrides=SMALL)
    with host_syncs.gpu_render_path(True):
        result = host_syncs.count_preset("agrinerf", args)
    assert result["plan"] == {"event_supervision": "stream", "blur": "trajectory"}
    for step in result["steps"][1:]:
        assert step["total"] <= STEP_SYNCS and not _own(step["syncs"]), step["syncs"]
    assert result["chunks"][1]["total"] <= CHUNK_SYNCS, result["chunks"][1]["syncs"]


def test_the_python_copies_of_buffers_follow_a_checkpoint() -> None:
    """The numbers kept beside their buffers (so a render reads no buffer) are the loaded ones after a load."""
    from agrinerf_ns.model.grid_mapping import BoxContraction
    from agrinerf_ns.model.vm_encoding import VMVolume

    saved = BoxContraction(torch.tensor([[-1.0, -2.0, -1.0], [1.0, 2.0, 3.0]]), inner=0.7)
    fresh = BoxContraction(torch.tensor([[-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]]))
    assert fresh.axis_resolution(64) != saved.axis_resolution(64)
    fresh.load_state_dict(saved.state_dict())
    assert fresh.inner_value == float(saved.inner) == float(torch.tensor(0.7)) != 0.7
    assert fresh.axis_resolution(64) == saved.axis_resolution(64)
    volume = VMVolume(8, num_components=2)
    volume.resample((6, 9, 12))
    loaded = VMVolume(8, num_components=2)
    loaded.load_state_dict(volume.state_dict())
    assert loaded.resolution == (6, 9, 12) == tuple(loaded.res.tolist())


@pytest.mark.parametrize(
    "distortion", [(0.0, 0.0, 0.0, 0.0), (-0.12, 0.03, 1e-3, -2e-3), (-0.12, 0.03, 1e-3, -2e-3, 0.01)]
)
def test_the_edi_priors_projection_is_opencvs_to_the_last_digit(distortion) -> None:
    """The EDI prior projects on the rays' device in torch, in OpenCV's order of operations: the same numbers."""
    import cv2
    import numpy as np

    from agrinerf_ns.model.edi_prior import project_points

    rng = np.random.default_rng(0)
    points = np.stack([rng.uniform(-1, 1, 20000), rng.uniform(-1, 1, 20000), rng.uniform(0.2, 3.0, 20000)], -1)
    intrinsics = (50.3, 49.7, 25.1, 14.6)
    K = np.array([[50.3, 0.0, 25.1], [0.0, 49.7, 14.6], [0.0, 0.0, 1.0]])
    expected, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), K, np.asarray(distortion, np.float64))
    got = project_points(torch.from_numpy(points), intrinsics, distortion).numpy()
    assert np.array_equal(got, expected[:, 0, :])
    assert not np.array_equal(got, project_points(torch.from_numpy(points), intrinsics, (0.1, 0.0, 0.0, 0.0)).numpy())
