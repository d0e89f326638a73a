"""Host syncs per training step and per rendered chunk of each preset, counted on the CPU, and where each comes from.

On a GPU every read of a tensor's data by the host waits for the device to finish what it was given: a scalar read
(``.item()``, ``float()``, ``int()``, ``bool()`` of a tensor, each one call of ``aten._local_scalar_dense``) or a copy
to the host (``.tolist()``, ``.numpy()``, ``.cpu()``). On the CPU nothing waits, but the same calls are made, so they
can be counted exactly: a ``TorchDispatchMode`` sees each ``aten._local_scalar_dense``, a ``TorchFunctionMode`` each
``tolist`` / ``numpy`` / ``__array__`` / ``cpu`` of a tensor. Each is named by the innermost frame of this project on
its stack (file:line; a frame of Nerfstudio or torch where no project frame is on it). Moves of host tensors to the
device (``.to(device)``, ``.cuda()``, ``torch.tensor(..., device=)``) are counted apart, as calls: on the CPU a move
to the device it is already on cannot be told from an upload.

    OMP_NUM_THREADS=1 python benchmarks/host_syncs.py count --data DS --out results/host-syncs/after.json
    python benchmarks/host_syncs.py report --records before.json after.json --out syncs.md

The renders take the path they take on a GPU (``--gpu-path``, the default): no pruning of samples by their data
(``device_sync.prune_on`` is False there; on the CPU it prunes, which reads the share of samples kept) and the VM
volumes' ``grid_sample`` lookups. Each preset trains ``--steps`` steps at its own settings (its start grids: no upsampling or box fit is due), counting
every step (forward, losses, backward, optimizer step, the training callbacks), then renders one chunk of an eval
camera's rays twice (``eval_num_rays_per_chunk`` rays through ``Model.forward``, in eval mode): the first chunk of a
render, and the next, which every further chunk costs. Step 0 carries the first checks of
parts on their own schedule (the event gate); the table gives step 0 and the largest count of the later steps.
"""

from __future__ import annotations

import contextlib
import json
import random
import sys
import traceback
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Dict, Iterator, List, Optional, Tuple, Union
from unittest import mock

import numpy as np
import torch
import tyro
from torch.overrides import TorchFunctionMode
from torch.utils._python_dispatch import TorchDispatchMode

ROOT = Path(__file__).resolve().parents[1]
PRESETS = ("agrinerf", "agrinerf-lite", "evdeblurnerf", "evdeblurnerf-lite", "evdeblurnerf-windowed",
           "evdeblurnerf-windowed-lite")  # fmt: skip
HOST_READS = {"tolist", "numpy", "__array__", "cpu"}
"""Tensor methods that copy a tensor's data to the host (on a GPU: after waiting for it)."""
SCALAR_READ = torch.ops.aten._local_scalar_dense.default
"""The one op behind every scalar read of a tensor (``item``, ``float``, ``int``, ``bool``)."""
_SKIP = (str(Path(__file__).resolve()), str(ROOT / "agrinerf_ns" / "lab" / "stepper.py"))


def call_site() -> str:
    """file:line of the innermost frame of this project on the stack (else the innermost outside torch), and after
    ">" the innermost outside torch where that is another file's (a call this project makes into Nerfstudio)."""
    frames = traceback.extract_stack()[:-3]
    outside = [f for f in frames if "/torch/" not in f.filename and f.filename not in _SKIP]
    ours = [f for f in outside if f.filename.startswith(str(ROOT)) and "/.venv/" not in f.filename]
    frame = (ours or outside or frames)[-1]
    site = _where(frame)
    if outside and outside[-1] is not frame:
        site += " > " + _where(outside[-1])
    return site


def _where(frame: traceback.FrameSummary) -> str:
    name = frame.filename
    for prefix in (str(ROOT) + "/", "site-packages/"):
        name = name.split(prefix, 1)[-1] if prefix in name else name
    return f"{name}:{frame.lineno}"


class _Reads(TorchFunctionMode):
    def __init__(self, counter: "HostSyncCounter") -> None:
        super().__init__()
        self.counter = counter

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        name = getattr(func, "__name__", "")
        if name in HOST_READS and args and isinstance(args[0], torch.Tensor):
            self.counter.add("sync", f"{name}()")
        elif name in ("to", "cuda") and args and isinstance(args[0], torch.Tensor) and _names_device(args, kwargs):
            self.counter.add("move", name)
        elif name in ("tensor", "as_tensor") and kwargs.get("device") is not None:
            self.counter.add("move", name)
        return func(*args, **kwargs)


def _names_device(args: Tuple[Any, ...], kwargs: Dict[str, Any]) -> bool:
    if kwargs.get("device") is not None:
        return True
    return any(
        isinstance(a, (torch.device, str)) or (isinstance(a, torch.Tensor) and a is not args[0]) for a in args[1:]
    )


class _Scalars(TorchDispatchMode):
    def __init__(self, counter: "HostSyncCounter") -> None:
        super().__init__()
        self.counter = counter

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):
        if func is SCALAR_READ:
            self.counter.add("sync", "scalar")
        return func(*args, **(kwargs or {}))


@dataclass
class HostSyncCounter:
    """Counts host syncs (scalar reads and copies to the host) and device moves while entered, by call site."""

    syncs: Counter = field(default_factory=Counter)
    moves: Counter = field(default_factory=Counter)
    _modes: List[Any] = field(default_factory=list)

    def add(self, kind: str, what: str) -> None:
        (self.syncs if kind == "sync" else self.moves)[f"{call_site()} {what}"] += 1

    def __enter__(self) -> "HostSyncCounter":
        self._modes = [_Reads(self), _Scalars(self)]
        for mode in self._modes:
            mode.__enter__()
        return self

    def __exit__(self, *exc: Any) -> None:
        for mode in reversed(self._modes):
            mode.__exit__(*exc)

    @property
    def total(self) -> int:
        return sum(self.syncs.values())


@dataclass
class Args:
    data: Path
    """A processed dataset (agrinerf-process) with events and their stream, exposures and thermal frames."""
    out: Path
    """JSON file: per preset, per counted step and for one rendered chunk, the syncs by call site."""
    presets: Tuple[str, ...] = PRESETS
    steps: int = 3
    rays_per_batch: Optional[int] = None
    """Training rays per batch (default: the preset's)."""
    overrides: Dict[str, Any] = field(default_factory=dict)
    """Model config fields set on every preset (e.g. ``blur_start_step`` 0 to count the blur model's renders)."""
    gpu_path: bool = True
    """Render as on a GPU: no data-dependent pruning, ``grid_sample`` lookups (see above)."""


@contextlib.contextmanager
def gpu_render_path(on: bool) -> Iterator[None]:
    """The renders' GPU branches on the CPU: `prune_on` False where it is imported, `VMVolume.uses_rows` False."""
    if not on:
        yield
        return
    from agrinerf_ns.model import field as field_module
    from agrinerf_ns.model import model as model_module
    from agrinerf_ns.model.vm_encoding import VMVolume

    with (
        mock.patch.object(model_module, "prune_on", lambda like: False),
        mock.patch.object(field_module, "prune_on", lambda like: False),
        mock.patch.object(VMVolume, "uses_rows", lambda self: False),
    ):
        yield


def stepper_for(preset: str, data: Path, rays: Optional[int], overrides: Dict[str, Any]):
    """A `MethodStepper` of an ``ns-train`` preset, seeded as ``ns-train`` seeds (callbacks on)."""
    from nerfstudio.configs.method_configs import all_methods

    from agrinerf_ns.lab.methods import METHODS, BenchMethod
    from agrinerf_ns.lab.stepper import MethodStepper

    if preset not in METHODS:
        METHODS[preset] = BenchMethod(preset, preset, "transforms.json", "rgb")
    for seeded in (random.seed, np.random.seed, torch.manual_seed):
        seeded(0)
    batch = rays or all_methods[preset].pipeline.datamanager.train_num_rays_per_batch
    return MethodStepper(preset, data, batch, model_overrides=overrides, callbacks=True)


def count_preset(preset: str, args: Args) -> Dict[str, Any]:
    """The syncs of each training step and of one rendered eval chunk, by call site."""
    stepper = stepper_for(preset, args.data, args.rays_per_batch, args.overrides)
    model = stepper.pipeline.model
    steps = []
    for step in range(args.steps):
        with HostSyncCounter() as counter:
            stepper.apply(stepper.loss_dict(step), step)
        steps.append({"total": counter.total, "syncs": dict(counter.syncs), "moves": dict(counter.moves)})
        print(preset, "step", step, "syncs", counter.total, "moves", sum(counter.moves.values()), flush=True)
    camera = stepper.pipeline.datamanager.eval_dataset.cameras[0:1].to(model.device)
    bundle = camera.generate_rays(camera_indices=0, keep_shape=False)
    chunk = bundle[: model.config.eval_num_rays_per_chunk]
    model.eval()
    chunks = []
    for _ in range(2):  # the first chunk of a render, and the next (what every further chunk costs)
        with torch.no_grad(), HostSyncCounter() as counter:
            model(chunk)  # Model.forward: the collider, then get_outputs
        chunks.append({"rays": int(chunk.shape[0]), "total": counter.total, "syncs": dict(counter.syncs),
                       "moves": dict(counter.moves)})  # fmt: skip
    model.train()
    print(preset, "chunk syncs", [c["total"] for c in chunks], flush=True)
    return {"plan": {"event_supervision": model.plan.event_supervision, "blur": model.plan.blur}, "steps": steps,
            "chunks": chunks}  # fmt: skip


def count(args: Args) -> None:
    with gpu_render_path(args.gpu_path):
        results = {preset: count_preset(preset, args) for preset in args.presets}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    record = {"args": {"steps": args.steps, "overrides": args.overrides, "gpu_path": args.gpu_path}, "presets": results}
    tmp.write_text(json.dumps(record, indent=1, sort_keys=True))
    tmp.replace(args.out)
    print(report_text({"counted": record}))


@dataclass
class Report:
    records: Tuple[Path, ...]
    """Records of ``count`` (e.g. before.json after.json), one column group each."""
    out: Optional[Path] = None
    """Markdown file of the table and each record's call sites (default: print only)."""


def report_text(records: Dict[str, Dict[str, Any]]) -> str:
    """Per preset: syncs of step 0, the most of the later steps, the first and the next rendered chunk, per record;
    then each record's call sites of its presets' later steps and chunks."""
    names = list(records)
    head = "| preset | " + " | ".join(
        f"{n}: step 0 | {n}: later steps | {n}: first chunk | {n}: next chunk" for n in names
    )
    lines = [head + " |", "|---" * (1 + 4 * len(names)) + "|"]
    presets = [p for p in records[names[0]]["presets"] if all(p in r["presets"] for r in records.values())]
    for preset in presets:
        cells = []
        for name in names:
            result = records[name]["presets"][preset]
            steps, chunks = [s["total"] for s in result["steps"]], [c["total"] for c in result["chunks"]]
            cells += [str(steps[0]), str(max(steps[1:], default=0)), str(chunks[0]), str(chunks[1])]
        lines.append(f"| {preset} | " + " | ".join(cells) + " |")
    for name in names:
        for preset in presets:
            result = records[name]["presets"][preset]
            for label, part in (("step 0", result["steps"][0]), ("a later step", result["steps"][-1]),
                                ("the first chunk", result["chunks"][0]), ("the next chunk", result["chunks"][1])):  # fmt: skip
                if part["syncs"]:
                    lines += ["", f"{name}, {preset}, {label}:", ""]
                    lines += [f"- {n} x `{site}`" for site, n in sorted(part["syncs"].items(), key=lambda kv: -kv[1])]
    return "\n".join(lines) + "\n"


def report(args: Report) -> None:
    text = report_text({path.stem: json.loads(path.read_text()) for path in args.records})
    if args.out is not None:
        tmp = args.out.with_suffix(".tmp")
        tmp.write_text(text)
        tmp.replace(args.out)
    print(text)


def entrypoint() -> None:
    args: Union[Args, Report] = tyro.extras.subcommand_cli_from_dict(
        {"count": Args, "report": Report}, prog="host_syncs.py"
    )
    count(args) if isinstance(args, Args) else report(args)


if __name__ == "__main__":
    entrypoint()
    sys.exit(0)
