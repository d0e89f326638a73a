"""Every preset's whole training step, ns-eval's image metrics and the count's render of a view on a pretend
accelerator (``helpers/fake_device.py``): any tensor left on the CPU that meets the model's device raises, as on a GPU.

The run mirrors Nerfstudio's ``Trainer`` per step (callbacks before, the pipeline's loss, backward, optimisers and
schedulers, callbacks after) over its real pipeline, datamanager and dataset, at tiny sizes: a synthetic dusk
garden with an event stream, thermal frames and fruit masks, the schedule moved so that the first steps hold the blur
and event terms, the event gate's check, the thermal camera's view, a box fit (step 0), an upsampling and an occupancy
update (step 1), and the fruit head.

What does not run on the pretend device, and where it is tested instead:

- the fused Adam kernel (torch has none for the pretend device type): the unfused update (the same rule) runs here;
  ``scripts/gpu_check.sh`` trains with the fused one on CUDA;
- the CUDA random state that ``rig.side_stream`` forks (``torch.cuda``'s calls need a GPU): the fork's device list is
  tested apart below;
- LPIPS's AlexNet (its weights would come from the network): a stand-in checks that its inputs are on the model's
  device; ns-eval on CUDA is in the GPU check;
- Nerfstudio's ``Trainer`` itself (autocast, its grad scaler, checkpoint writes): the GPU check runs ``ns-train``.
"""

from __future__ import annotations

import copy
import re
import sys
from pathlib import Path
from typing import Any, Callable, Dict, List, Set, Tuple

import numpy as np
import pytest
import torch
from helpers.fake_device import PRETEND, DeviceMismatch, DeviceTensor, FakeDevice, on_device
from helpers.small_model import SMALL_MODEL

from agrinerf_ns.method_configs import agrinerf_methods as methods

ROOT = Path(__file__).resolve().parent.parent
PRESETS = {
    "agrinerf": methods.agrinerf,
    "agrinerf-lite": methods.agrinerf_lite,
    "evdeblurnerf": methods.evdeblurnerf,
    "evdeblurnerf-lite": methods.evdeblurnerf_lite,
    "evdeblurnerf-windowed": methods.evdeblurnerf_windowed,
    "evdeblurnerf-windowed-lite": methods.evdeblurnerf_windowed_lite,
}
STEPS = 2
SCHEDULE: Dict[str, Any] = dict(
    SMALL_MODEL,
    upsampling_iters=(1,),
    box_fit_iters=(0,),
    box_fit_rays=128,
    occupancy_update_iters=(1,),
    blur_samples=2,
    blur_start_step=0,
    event_crf_start_step=0,
    event_rays_per_batch=32,
    thermal_rays_per_batch=32,
    event_gate_every=1,
    event_gate_samples=32,
    eval_num_rays_per_chunk=4096,
    density_shift=1.0,
)
"""Tiny grids and batches; every part that starts late starts at step 0, a box fit (step 0), an upsampling (step 1)
(a dense young field, so that the box fit finds surfaces and resamples the grids into its box)."""


@pytest.fixture(scope="module")
def dataset(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny dusk garden: RGB, thermal frames, an event stream (and event frames) and fruit masks made as the GPU
    check makes them (`--fruit-mask-maker auto`)."""
    from PIL import Image

    from agrinerf_ns.process import ProcessConfig, process_capture
    from agrinerf_ns.synth import SynthConfig, generate_capture

    root = tmp_path_factory.mktemp("fake-device")
    raw = generate_capture(SynthConfig.tiny(seed=4, scene="garden", lighting="dusk", views=8), root / "raw")
    config = ProcessConfig(poses="given", show_progress=False, fruit_mask_maker=GPU_CHECK_MASKS)
    data = process_capture(raw, root / "data", config)
    assert (data / "events" / "stream.h5").is_file()
    masks = [np.asarray(Image.open(path)) for path in sorted((data / "fruit_masks").iterdir())]
    assert len(masks) == 8 and sum(int((m == 255).sum()) for m in masks) > 0  # fruit for the fruit head to learn
    return data


GPU_CHECK_MASKS = "auto"


def test_the_gpu_check_makes_fruit_masks(tmp_path: Path) -> None:
    """`scripts/gpu_check.sh` processes its dusk garden with the fruit masks this test's dataset has (`dataset`), so
    every preset builds its fruit head on the lent GPU."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    try:
        import gpu_check
    finally:
        sys.path.pop(0)
    (step,) = [s for s in gpu_check.steps(gpu_check.Args(out=tmp_path)) if s.check == "dataset"]
    argv = step.argv
    assert argv[argv.index("--fruit-mask-maker") + 1] == GPU_CHECK_MASKS


def _config(preset: str, data: Path) -> Any:
    config = copy.deepcopy(PRESETS[preset].config)
    config.data = data
    datamanager = config.pipeline.datamanager
    datamanager.data = data
    datamanager.train_num_rays_per_batch = datamanager.eval_num_rays_per_batch = 64
    model = config.pipeline.model
    for key, value in SCHEDULE.items():
        setattr(model, key, value)
    for group in config.optimizers.values():
        if getattr(group["optimizer"], "fused", False):
            group["optimizer"].fused = False  # no fused kernel for the pretend device (see the module docstring)
    return config


class LpipsStandIn(torch.nn.Module):
    """LPIPS's place in the eval: checks its inputs lie on the model's device (the real one fetches weights)."""

    def forward(self, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
        assert isinstance(pred, DeviceTensor) and isinstance(target, DeviceTensor)
        return (pred - target).abs().mean()


def _project_files(seen: Set[str]) -> Set[str]:
    """The project modules among the code files a run called, as paths relative to the repository."""
    out = set()
    for name in seen:
        path = Path(name)
        if path.suffix == ".py" and ROOT in path.parents:
            out.add(path.relative_to(ROOT).as_posix())
    return out


def _run_preset(preset: str, data: Path, out: Path) -> Tuple[Any, Dict[str, Any], List[str], Set[str]]:
    """Set the pipeline up on the pretend device and run STEPS steps, ns-eval's metrics and the count's render of one
    view; returns the pipeline, what each part showed, the output names per step and the project files called."""
    from nerfstudio.engine.callbacks import TrainingCallbackAttributes, TrainingCallbackLocation
    from nerfstudio.engine.optimizers import Optimizers

    from agrinerf_ns.count.render import render_loaded_run
    from agrinerf_ns.detect.render_views import LoadedRun
    from agrinerf_ns.model.event_crf import _identity_fit

    config = _config(preset, data)
    if config.pipeline.model.event_crf:  # the event response's CPU fit at construction (cached), outside the mode
        _identity_fit(2, 16)
    seen: Set[str] = set()

    def trace(frame: Any, event: str, arg: Any) -> None:
        seen.add(frame.f_code.co_filename)  # each new frame's file; no line tracing (returns None)

    torch.manual_seed(0)
    shown: Dict[str, Any] = {}
    names: List[str] = []
    sys.settrace(trace)
    try:
        with FakeDevice() as mode:
            pipeline = config.pipeline.setup(device=PRETEND, test_mode="val", world_size=1, local_rank=0)
            model = pipeline.model
            assert on_device(model), "model.to(device) left a parameter or buffer on the CPU"
            optimizers = Optimizers(config.optimizers, pipeline.get_param_groups())
            attributes = TrainingCallbackAttributes(
                optimizers=optimizers, grad_scaler=None, pipeline=pipeline, trainer=None
            )
            callbacks = pipeline.get_training_callbacks(attributes)
            box = model.field.full_resolution_box().cpu()
            resolution = model.field.density_encoding.resolution
            for step in range(STEPS):
                for callback in callbacks:
                    callback.run_callback_at_location(step, TrainingCallbackLocation.BEFORE_TRAIN_ITERATION)
                optimizers.zero_grad_all()
                outputs, loss_dict, _ = pipeline.get_train_loss_dict(step)
                loss = torch.stack([v.reshape(()) for v in loss_dict.values()]).sum()
                assert isinstance(loss, DeviceTensor) and torch.isfinite(loss.cpu())
                loss.backward()
                optimizers.optimizer_step_all()
                optimizers.scheduler_step_all(step)
                for callback in callbacks:
                    callback.run_callback_at_location(step, TrainingCallbackLocation.AFTER_TRAIN_ITERATION)
                names += list(outputs)
            shown["box moved"] = not torch.equal(box, model.field.full_resolution_box().cpu())
            shown["upsampled"] = model.field.density_encoding.resolution != resolution
            shown["on device after the schedule"] = on_device(model)
            gate = getattr(model.events, "gate", None) if model.events is not None else None
            shown["gate checked"] = gate is not None and int(gate.last_check) >= 0
            model._lazy_metrics["lpips"] = LpipsStandIn()
            shown["eval"] = pipeline.get_average_eval_image_metrics()
            pipeline.datamanager.train_dataparser_outputs.save_dataparser_transform(out / "dataparser_transforms.json")
            shown["config"] = out / "config.yml"
            run = LoadedRun(config_path=shown["config"], method=preset, pipeline=pipeline, checkpoint=out, step=STEPS)
            shown["count render"] = render_loaded_run(run, splits=("eval",)).views
            shown["aten calls"] = mode.calls
    finally:
        sys.settrace(None)
    return pipeline, shown, names, _project_files(seen)


@pytest.fixture(scope="module")
def runs(dataset: Path, tmp_path_factory: pytest.TempPathFactory) -> Callable[[str], Tuple[Any, ...]]:
    """`_run_preset` of a preset, run once per module (the benchmarks' test reuses a run)."""
    done: Dict[str, Tuple[Any, ...]] = {}

    def run(preset: str) -> Tuple[Any, ...]:
        if preset not in done:
            done[preset] = (*_run_preset(preset, dataset, tmp_path_factory.mktemp(preset)), preset)
        return done[preset]

    return run


@pytest.mark.parametrize("preset", sorted(PRESETS))
def test_preset_step_eval_and_count_render_on_a_pretend_device(preset: str, runs: Callable) -> None:
    pipeline, shown, names, files, _ = runs(preset)
    plan = pipeline.model.plan
    expected = {"rgb", "depth", "accumulation", "fruit"}  # every preset: the masks build the fruit head
    if plan.use_blur:
        expected.add("rgb_blurred")
    if plan.use_event_loss:
        expected |= {"event_log_start", "event_log_end"}
    if plan.edi_prior:
        expected.add("edi_factor")
    assert expected <= set(names), sorted(set(names))
    assert plan.has_fruit_head
    if plan.thermal_view:
        assert any(n.startswith("thermal_view/") for n in names), sorted(set(names))
    assert shown["box moved"] and shown["upsampled"] and shown["on device after the schedule"], shown
    if preset == "agrinerf":  # the paper preset's parts: all on in its first steps here
        assert plan.use_blur and plan.use_event_loss and plan.thermal_view and shown["gate checked"], shown
    if preset.startswith("evdeblurnerf") and not preset.startswith("evdeblurnerf-windowed"):
        assert plan.event_supervision == "pairs" and plan.edi_prior
    assert np.isfinite(shown["eval"]["psnr"]) and "fruit_iou" in shown["eval"], shown["eval"]
    views = shown["count render"]
    assert len(views) == 1 and views[0].depth.shape == (48, 64) and views[0].fruit is not None

    # the static scan reads every project module that handles tensors and that this run called
    outside = {f for f in files - _scanned() if f.startswith(("agrinerf_ns/", "dataparsers/", "method_configs/"))}
    uses_torch = re.compile(r"^\s*(import torch|from torch\b)", re.M)  # a module that imports torch, not one naming it
    assert not {f for f in outside if uses_torch.search((ROOT / f).read_text())}, sorted(outside)


def _scanned() -> Set[str]:
    """The modules the static device scan reads, and the host-side ones it names."""
    sys.path.insert(0, str(ROOT / "scripts"))
    try:
        from device_factories import HOST_SIDE, scope_files
    finally:
        sys.path.pop(0)
    return {p.relative_to(ROOT).as_posix() for p in scope_files(ROOT)} | set(HOST_SIDE)


def test_the_benchmarks_sample_the_field_on_the_models_device(runs: Callable, dataset: Path, monkeypatch) -> None:
    """`count_field_contrast.py` and `box_truth_ceiling.py` on a run whose model is on the pretend device (each crashed
    on CUDA before: CPU points into the device's field and box)."""
    from helpers.bench_script import load_bench_script

    from agrinerf_ns import run_loading
    from agrinerf_ns.run_loading import LoadedRun

    pipeline, shown, _, _, preset = runs("agrinerf-lite")
    config = shown["config"]  # a run folder holding the run's dataparser_transforms.json
    run = LoadedRun(config_path=config, method=preset, pipeline=pipeline, checkpoint=config.parent, step=STEPS)
    contrast, ceiling = load_bench_script("count_field_contrast"), load_bench_script("box_truth_ceiling")
    monkeypatch.setattr(run_loading, "load_run", lambda *a, **k: run)  # the run in memory, not from disk
    monkeypatch.setattr(ceiling, "load_run", lambda *a, **k: run)
    monkeypatch.setattr(contrast, "trained_run_config", lambda path: path)
    raw = dataset.parent / "raw"
    with FakeDevice():
        table = contrast.main(contrast.Args(run=config, raw=raw))
        shares = ceiling.main(ceiling.Args(config=config, raw=raw, data=dataset))
    assert "visible true fruit" in table and shares["heldout_views"] == 1
    assert 0.0 < shares["share_of_pixels_with_any_true_surface"] <= 1.0


def test_a_cpu_tensor_planted_in_the_render_fails_the_step(dataset: Path, tmp_path: Path, monkeypatch) -> None:
    """The check is live in a whole step: a render background made on the CPU (the classic bug) raises."""
    from agrinerf_ns.model.model import AgriNeRFModel

    def cpu_background(self: Any, values: torch.Tensor) -> torch.Tensor:
        return torch.zeros(values.shape[0], values.shape[-1])  # the planted bug: no device

    monkeypatch.setattr(AgriNeRFModel, "_background", cpu_background)
    with pytest.raises(DeviceMismatch, match="mixes devices"):
        _run_preset("agrinerf-lite", dataset, tmp_path)


def test_the_pretend_device_refuses_what_a_gpu_refuses() -> None:
    """The harness: a CPU tensor meeting a device tensor, device indices into a CPU tensor, a CPU generator's draw on
    the device and numpy of a device tensor fail; CPU scalars, CPU indices and copies pass, as on a GPU."""
    with FakeDevice():
        x = torch.rand(4, 3, device=PRETEND)
        assert isinstance(x * torch.tensor(2.0) + 1.0, DeviceTensor)  # a CPU scalar tensor in a pointwise op
        assert isinstance(x[torch.tensor([0, 2])], DeviceTensor) and isinstance(x[[0, 2]], DeviceTensor)
        assert not isinstance(x.cpu(), DeviceTensor) and isinstance(torch.zeros(4, 3).to(x.device), DeviceTensor)
        assert isinstance(torch.tensor([1.0, 2.0, 3.0], device=x.device) + x, DeviceTensor)
        assert float(x.sum()) == pytest.approx(float(x.cpu().sum())) and len(x.tolist()) == 4
        for bug in (
            lambda: x + torch.ones(3),
            lambda: torch.cat([x, torch.zeros(1, 3)]),
            lambda: torch.where(x > 0.5, x, torch.zeros(4, 3)),
            lambda: x @ torch.eye(3),
            lambda: x.add_(torch.ones(3)),
            lambda: torch.zeros(5)[torch.tensor([1], device=PRETEND)],
            lambda: torch.rand(3, device=x.device, generator=torch.Generator()),
        ):
            with pytest.raises(DeviceMismatch):
                bug()
        with pytest.raises(TypeError, match="numpy"):
            x.numpy()


def test_the_side_stream_forks_the_cuda_random_state_on_cuda(monkeypatch) -> None:
    """The one CUDA-only call of a step, apart: on a CUDA device the side stream forks that device's random state."""
    import contextlib

    from agrinerf_ns.model import rig

    forked = []

    @contextlib.contextmanager
    def fork_rng(devices):
        forked.append(list(devices))
        yield

    monkeypatch.setattr(rig.torch.random, "fork_rng", fork_rng)
    monkeypatch.setattr(rig.torch, "manual_seed", lambda seed: None)
    for device in (torch.device("cuda", 0), torch.device("cpu")):
        with rig.side_stream(device, 3):
            pass
    assert forked == [[torch.device("cuda", 0)], []]
