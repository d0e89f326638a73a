"""The event term's data gate (config `event_gate`): the term's weight is given only while a held-out share of the
event stream, never trained on, is explained better than when the gate first looked, and better than by predicting
no change. The gate starts closed: the term opens (at RESTART, doubling every check) once the field the frames shape
explains the held-out events, which is a warm-up the data decides, and never where they contradict the frames.

Why: the event loss's targets can disagree with the frames (a sensor's refractory losses and noise, a threshold or
time offset, a scene whose texture the field cannot fit at the event camera's rays); its `noise` weighting balances
the two terms' loss values, not their agreement, and on the blurred dusk garden it cost 3.5 dB with nothing to say so
(issue 50, results/event-diagnose). The gate asks the data instead: held-out event samples whose residual does not
fall are events the field cannot reconcile with the frames, and the term is switched down.
"""

from __future__ import annotations

import math
from typing import Any, Callable, Dict, Optional, Tuple

import torch
from jaxtyping import Bool, Float, Int
from torch import Tensor, nn

from agrinerf_ns.dataparsers import event_stream
from agrinerf_ns.dataparsers.event_stream import EventStream, sample_windows
from agrinerf_ns.model import losses
from agrinerf_ns.model.event_settings import EventSettings
from agrinerf_ns.model.rig import Rig

GATE_SEED = 5050
"""The held-out samples' own generator seed: the same samples in every run of a dataset, whatever the training seed."""
FALLEN = 0.95
"""The residual must be below this share of the reference for the term to keep (or regain) its weight."""
RISEN = 1.15
"""A residual above this multiple of the lowest seen so far counts as rising (the term is halved)."""
FLOOR, RESTART = 1.0 / 64.0, 1.0 / 16.0
"""Below FLOOR the factor is 0; it reopens at RESTART."""

LogRenderer = Callable[[Float[Tensor, "m 2 3"], Float[Tensor, "m 2 3"], Int[Tensor, " m"]], Float[Tensor, "m 2 1"]]
"""Log luminance of event samples' rays (origins, directions, training frames) at both window ends, no gradient."""


class EventGate(nn.Module):
    """Held-out event samples and the factor they allow the event term (buffers: a resumed run keeps them)."""

    factor: Tensor
    reference: Tensor
    best: Tensor
    residual: Tensor
    last_check: Tensor

    def __init__(self, config: EventSettings, rig: Rig, stream: EventStream) -> None:
        super().__init__()
        assert rig.event_windows is not None and rig.trajectory is not None and rig.event_stream is not None
        self.config = config
        # cpu: the held-out pixels, windows and counts live with the host event stream; a CPU generator draws the
        # same ones on every device (the renders take them to the model's device in `check`)
        generator = torch.Generator().manual_seed(GATE_SEED)  # cpu: see above
        total = stream.width * stream.height
        n = max(1, config.event_gate_samples)
        held = torch.randperm(total, generator=generator)[: max(1, min(n, total // 8))]  # cpu: see above
        keep = torch.ones(total, dtype=torch.bool)  # cpu: see above
        keep[held] = False
        self.train_mask: Bool[Tensor, " pixels"] = keep  # per event pixel: may training draw it
        self.train_pixels: Int[Tensor, " k"] = keep.nonzero()[:, 0]  # the pixels training may draw
        self._train_pixels_on: Optional[Tensor] = None  # their copy on the device training draws on
        frames = torch.randint(0, rig.event_windows.shape[0], (n,), generator=generator)  # cpu: see above
        t0, t1 = sample_windows(rig.event_windows, frames, config.event_window_min_fraction, generator)
        pixel = held[torch.randint(0, held.shape[0], (n,), generator=generator)]  # cpu: see above
        self.on, self.off = stream.counts(pixel, t0, t1)
        times = torch.stack([t0, t1], -1).double() * 1e-6
        self.origins, self.directions = event_stream.event_rays(rig.trajectory, rig.event_stream, pixel, times)
        self.frames = frames
        self.register_buffer("factor", torch.zeros((), dtype=torch.float64))  # closed until the frames explain
        self.register_buffer("reference", torch.full((), math.nan, dtype=torch.float64))
        self.register_buffer("best", torch.full((), math.nan, dtype=torch.float64))
        self.register_buffer("residual", torch.full((), math.nan, dtype=torch.float64))
        self.register_buffer("last_check", torch.full((), -1, dtype=torch.int64))
        # `last_check` as a Python number, kept with it: `due` is asked every step, and a read of the buffer on a GPU
        # waits for the device; it changes only at a check or when a checkpoint loads
        self.last_check_step = -1
        self._register_load_state_dict_pre_hook(self._load_last_check)

    def _load_last_check(self, state_dict: Dict[str, Any], prefix: str, *args: Any) -> None:
        saved = state_dict.get(prefix + "last_check")
        if saved is not None:
            self.last_check_step = int(saved)

    def training_pixels(self, m: int, device: Optional[torch.device] = None) -> Int[Tensor, " m"]:
        """`m` random event pixels outside the held-out share (the global random stream of `device`, default the
        CPU, as the plain sampler), on `device` (the training pixels are copied there once)."""
        device = torch.device("cpu") if device is None else torch.device(device)
        if self._train_pixels_on is None or self._train_pixels_on.device != device:
            self._train_pixels_on = self.train_pixels.to(device)
        return self._train_pixels_on[torch.randint(0, self.train_pixels.shape[0], (m,), device=device)]

    def due(self, step: int) -> bool:
        last = self.last_check_step
        return last < 0 or step >= last + max(1, self.config.event_gate_every)

    def no_change(self, thresholds: Tuple[float, float]) -> float:
        """The held-out loss of predicting no change: the mean squared target."""
        target = thresholds[0] * self.on - thresholds[1] * self.off
        return float((target.double() ** 2).mean())

    def score(self, logs: Float[Tensor, "m 2 1"], thresholds: Tuple[float, float]) -> float:
        """The held-out event loss of rendered log luminances (the training loss's form and bound)."""
        logs = logs.detach().float().cpu()
        return float(
            losses.event_loss(
                logs[:, 0], logs[:, 1], self.on, self.off, *thresholds, lower_bound=self.config.event_loss_bound
            )  # fmt: skip
        )

    @torch.no_grad()
    def check(self, step: int, render_logs: LogRenderer, thresholds: Tuple[float, float]) -> float:
        """Score the held-out samples and update the factor; returns it."""
        chunk = 2048
        logs = torch.cat([
            render_logs(self.origins[s : s + chunk], self.directions[s : s + chunk], self.frames[s : s + chunk])
            for s in range(0, self.origins.shape[0], chunk)
        ])  # fmt: skip
        residual = self.score(logs, thresholds)
        self.last_check.fill_(step)
        self.last_check_step = step
        self.residual.fill_(residual)
        if not math.isfinite(residual):
            return float(self.factor)
        if math.isnan(float(self.reference)):  # the first check: the bar the residual must pass from now on
            self.reference.fill_(min(residual, self.no_change(thresholds)))
            self.best.fill_(residual)
            return float(self.factor)
        best = float(self.best)
        self.best.fill_(residual if math.isnan(best) else min(best, residual))
        self.factor.fill_(next_factor(float(self.factor), residual, float(self.reference), float(self.best)))
        return float(self.factor)


def next_factor(factor: float, residual: float, reference: float, best: float) -> float:
    """The gate's rule: halve (0 below FLOOR) unless the residual is below FALLEN x reference and not above RISEN x
    the best so far; then double (from RESTART), at most 1."""
    if residual < FALLEN * reference and residual <= RISEN * best:
        return min(1.0, max(2.0 * factor, RESTART))
    halved = factor / 2.0
    return 0.0 if halved < FLOOR else halved
