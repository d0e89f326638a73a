"""A pretend accelerator on the CPU: tensors that say they live on another device, with real values, and a dispatch
mode that raises where one meets a CPU tensor as it would on a GPU.

``FakeTensorMode`` (shapes only) stops at the first read of a value (``float()``, ``x[mask]``, ``nonzero``), so it
cannot run a whole training step. Here every tensor on the pretend device is a ``DeviceTensor``: a wrapper whose
``.device`` is ``PRETEND`` around a real CPU tensor, so the model computes its real values while the mode
(``FakeDevice``) checks every aten call, forward, backward and optimiser alike:

- an op that mixes a ``DeviceTensor`` with a CPU tensor raises ``DeviceMismatch``, except where PyTorch allows that on
  a GPU: a 0-dim CPU tensor in a pointwise op or as the value of ``x[idx] = v`` (a CPU scalar), CPU indices of a
  tensor on the device (``x[idx]``, ``x[idx] = v``), and copies across devices (``copy_``, ``.to``);
- a factory told ``device=PRETEND`` (``torch.zeros(3, device=x.device)``), ``.to(PRETEND)`` and any op on a
  ``DeviceTensor`` give ``DeviceTensor``s; ``.cpu()`` / ``.to("cpu")`` give the plain CPU tensor; a draw on the
  pretend device from a CPU ``torch.Generator`` raises, as CUDA does;
- ``.numpy()`` of a ``DeviceTensor`` raises as it does for a CUDA tensor; ``.tolist()`` and ``.item()`` read it.

``PRETEND`` is PyTorch's ``lazy`` device type, not ``cuda``: a ``cuda`` device makes PyTorch initialise CUDA (which
fails without a GPU) before any mode sees the call. So code that branches on ``device.type == "cuda"`` (the CUDA random
state in ``rig.side_stream``) takes its other branch here; code that branches on ``device.type == "cpu"``
(``device_sync.prune_on``) takes the accelerator's.
"""

from __future__ import annotations

from typing import Any, Dict, List, Optional, Tuple

import torch
from torch import Tensor
from torch.utils._python_dispatch import TorchDispatchMode

PRETEND = torch.device("lazy", 0)
aten = torch.ops.aten

CROSS_DEVICE = frozenset({aten.copy_.default, aten._to_copy.default, aten._copy_from.default})
"""Ops that copy across devices by design."""
CPU_INDICES = frozenset(
    {aten.index.Tensor, aten.index_put.default, aten.index_put_.default, aten._index_put_impl_.default}
)
"""Ops whose indices (argument 1) may stay on the CPU for a tensor on the device, as PyTorch allows."""


class DeviceMismatch(RuntimeError):
    """A CPU tensor met a tensor on the (pretend) device: the step would fail on a GPU."""


class DeviceTensor(Tensor):
    """A real CPU tensor (`elem`) that says it lives on `PRETEND`."""

    elem: Tensor

    @staticmethod
    def __new__(cls, elem: Tensor) -> "DeviceTensor":
        out = Tensor._make_wrapper_subclass(  # type: ignore[attr-defined]
            cls,
            elem.size(),
            strides=elem.stride(),
            storage_offset=elem.storage_offset(),
            dtype=elem.dtype,
            layout=elem.layout,
            device=PRETEND,
            requires_grad=elem.requires_grad,
        )
        out.elem = elem
        return out

    __torch_function__ = torch._C._disabled_torch_function_impl  # type: ignore[assignment]

    @classmethod
    def __torch_dispatch__(cls, func, types, args=(), kwargs=None):  # type: ignore[override]
        raise RuntimeError(f"{func}: a DeviceTensor used outside its FakeDevice mode")

    def __repr__(self) -> str:  # type: ignore[override]
        return f"DeviceTensor({self.elem!r})"

    def tolist(self) -> Any:  # type: ignore[override]
        return self.elem.tolist()

    def numpy(self, *, force: bool = False) -> Any:  # type: ignore[override]
        raise TypeError(f"can't convert {PRETEND} device type tensor to numpy. Use Tensor.cpu() first.")

    def __array__(self, *args: Any, **kwargs: Any) -> Any:
        return self.numpy()


def _describe(value: Any) -> str:
    if isinstance(value, DeviceTensor):
        return f"{PRETEND.type} {tuple(value.shape)} {value.dtype}"
    if isinstance(value, Tensor):
        return f"cpu {tuple(value.shape)} {value.dtype}"
    return repr(value)


def _tensors(value: Any) -> List[Tensor]:
    """The tensors of an aten argument: a tensor, or a list / tuple of them (aten nests no deeper)."""
    if isinstance(value, Tensor):
        return [value]
    if isinstance(value, (list, tuple)):
        return [t for t in value if isinstance(t, Tensor)]
    return []


def _unwrap(value: Any) -> Any:
    if isinstance(value, DeviceTensor):
        return value.elem
    if isinstance(value, (list, tuple)) and any(isinstance(t, DeviceTensor) for t in value):
        return type(value)(t.elem if isinstance(t, DeviceTensor) else t for t in value)
    return value


def _check(func: Any, args: Tuple[Any, ...], kwargs: Dict[str, Any]) -> None:
    """Raise where a CPU tensor meets a device tensor in a way that fails on a GPU."""
    if func in CROSS_DEVICE:
        return
    checked = list(args)
    if func in CPU_INDICES and len(checked) > 1:
        if not isinstance(checked[0], DeviceTensor) and any(isinstance(t, DeviceTensor) for t in _tensors(checked[1])):
            raise DeviceMismatch(f"{func}: indices on {PRETEND} for a CPU tensor {_describe(checked[0])}")
        checked[1] = None  # CPU indices of a tensor on the device: allowed
    tensors = [t for value in (*checked, *kwargs.values()) for t in _tensors(value)]
    if not any(isinstance(t, DeviceTensor) for t in tensors):
        return
    pointwise = func in CPU_INDICES or torch.Tag.pointwise in func.tags
    bad = [t for t in tensors if not isinstance(t, DeviceTensor) and not (pointwise and t.dim() == 0)]
    if bad:
        raise DeviceMismatch(
            f"{func} mixes devices: " + ", ".join(_describe(t) for t in tensors) + " (expected all on one device)"
        )


class FakeDevice(TorchDispatchMode):
    """The mode of a fake-device run (see the module's docstring). `calls` counts the aten calls it checked."""

    def __init__(self) -> None:
        super().__init__()
        self.calls = 0
        self._lift_cpu = False

    def __enter__(self) -> "FakeDevice":
        # data turned into a tensor on the device (`torch.tensor(data, device=...)`, `x[[0, 2]]`) is made on the CPU
        # and moved through the mode, which then sees the move (as `FakeTensorMode` does)
        self._lift_cpu = torch._C._only_lift_cpu_tensors()
        torch._C._set_only_lift_cpu_tensors(True)
        return super().__enter__()  # type: ignore[return-value]

    def __exit__(self, *exc: Any) -> None:
        torch._C._set_only_lift_cpu_tensors(self._lift_cpu)
        super().__exit__(*exc)

    def __torch_dispatch__(self, func, types, args=(), kwargs=None):  # type: ignore[override]
        kwargs = dict(kwargs or {})
        self.calls += 1
        inputs = [t for value in (*args, *kwargs.values()) for t in _tensors(value) if isinstance(t, DeviceTensor)]
        target: Optional[torch.device] = None
        if kwargs.get("device") is not None:
            target = torch.device(kwargs["device"])
            kwargs["device"] = torch.device("cpu")
        elif func is aten._to_copy.default or func is aten.lift_fresh.default:
            target = PRETEND if inputs else None
        wanted = target is not None and target.type == PRETEND.type
        _check(func, args, kwargs)
        generator = kwargs.get("generator")
        if wanted and isinstance(generator, torch.Generator) and generator.device.type == "cpu":
            raise DeviceMismatch(f"{func}: a draw on {PRETEND} from a CPU generator (CUDA expects a CUDA generator)")
        wraps = {id(t.elem): t for t in inputs}
        out = func(*[_unwrap(a) for a in args], **{k: _unwrap(v) for k, v in kwargs.items()})
        on_device = wanted if target is not None else bool(inputs)

        def wrap(value: Any) -> Any:
            if not isinstance(value, Tensor):
                return value
            if id(value) in wraps:  # an in-place op or an out= argument: the caller's own tensor
                return wraps[id(value)]
            return DeviceTensor(value) if on_device else value

        if isinstance(out, (list, tuple)):
            return type(out)(wrap(v) for v in out)
        return wrap(out)


def on_device(module: torch.nn.Module) -> bool:
    """Whether every parameter and buffer of `module` lives on the pretend device."""
    return all(isinstance(t, DeviceTensor) for t in [*module.parameters(), *module.buffers()])
