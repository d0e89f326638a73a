"""The event term: the event loss behind one interface for its three supervisions (EvDeblurNeRF's event pairs, the
stream's event pixels, the frames' event windows), its contrast thresholds, its `noise` weighting with running means
kept as buffers, and EvDeblurNeRF's EDI prior, which reads the same stream and thresholds."""

from __future__ import annotations

import math
from typing import Any, Dict, List, Optional, Tuple

import torch
from jaxtyping import Float, Int
from nerfstudio.cameras.rays import RayBundle
from torch import Tensor, nn
from torch.nn import Parameter

from agrinerf_ns import colour
from agrinerf_ns.dataparsers import event_stream
from agrinerf_ns.dataparsers.event_stream import EventCamera, EventStream, sample_windows
from agrinerf_ns.model import edi_prior, losses
from agrinerf_ns.model.blur_term import render_at
from agrinerf_ns.model.event_crf import EventCRF, event_log_luma
from agrinerf_ns.model.event_gate import EventGate
from agrinerf_ns.model.event_pairs import EventPairs, pair_targets, polarity_features
from agrinerf_ns.model.event_settings import EventSettings
from agrinerf_ns.model.loss_routing import pred
from agrinerf_ns.model.model_part import ModelPart, TermInputs
from agrinerf_ns.model.plan import ModelPlan
from agrinerf_ns.model.rig import RenderRays, Rig
from agrinerf_ns.model.timed_rays import frame_rows, on_device


class EventTerm(nn.Module, ModelPart):
    """The event loss (`plan.event_supervision`) and the EDI prior (`plan.edi_prior`) of one model: the part of
    the terms `event_loss` and `edi_prior_loss`.

    Its learnt state is its own: the learnt thresholds (`log_threshold`, config `event_threshold_learnt`), the learnt
    event response (`crf`, built by the model with its other optional weights) and the `noise` weighting's running
    means of the RGB and event losses (buffers, so a resumed run goes on with them).
    """

    loss_means: Tensor
    weight: Tensor

    def __init__(self, config: EventSettings, plan: ModelPlan, rig: Rig, crf: Optional[EventCRF] = None) -> None:
        super().__init__()
        self.config, self.rig, self.mode = config, rig, plan.event_supervision
        native = rig.event_stream
        self.stream: Optional[EventStream] = None
        if self.mode == "stream" and native is not None:
            self.stream = native.stream()
        self.pairs: Optional[EventPairs] = None
        if self.mode == "pairs" and native is not None:
            self.pairs = EventPairs.from_h5(native.path, native.width, native.height)
        self.edi_stream: Optional[EventStream] = None  # the EDI prior's counts at the event pixels
        if plan.edi_prior and native is not None:
            self.edi_stream = self.stream or native.stream()
        self.log_threshold: Optional[Parameter] = None  # ON, OFF
        if self.mode != "off" and config.event_threshold_learnt:
            self.log_threshold = Parameter(torch.full((2,), math.log(config.event_threshold)))
        self.crf = crf
        self.gate: Optional[EventGate] = None  # `plan.event_gate`: held-out event samples that set the weight
        if plan.event_gate:
            assert native is not None, "the plan gates only the stream's supervisions"
            self.gate = EventGate(config, rig, self.stream or native.stream())
            if self.pairs is not None:  # the gate's held-out pixels are never trained on, under either supervision
                self.pairs = self.pairs.at_pixels(self.gate.train_mask)
        self._device_parts: Optional[Tuple[torch.device, Optional[EventStream], EventCamera]] = None  # `_on_device`
        self._pairs_on: Optional[EventPairs] = None  # the pairs on the device they are drawn on
        self.register_buffer("loss_means", torch.full((2,), math.nan, dtype=torch.float64))  # RGB, event
        self.register_buffer("weight", torch.zeros((), dtype=torch.float64))  # the `noise` weighting's last factor

    # ------------------------------------------------------------------ renders
    def outputs(self, render: RenderRays, bundle: RayBundle, frame: Dict[str, Tensor], step: int) -> Dict[str, Tensor]:
        """The EDI prior's factors and the event samples' renders at both ends of their windows, with their targets
        (training, in the side stream)."""
        outputs: Dict[str, Tensor] = {}
        if self.edi_stream is not None:
            outputs.update(self.edi_outputs(bundle))
        if step < self.config.event_start_step:  # the event term's warm-up: no sample, no loss
            return outputs
        if self.mode == "pairs":
            outputs.update(self.pair_logs(render, bundle, step))
        elif self.mode == "stream":
            outputs.update(self.stream_logs(render, bundle))
        elif self.mode == "frames":
            outputs["event_log_start"], outputs["event_log_end"] = self.window_logs(render, bundle)
        if self.gate is not None and self.gate.due(step):
            self.gate.check(step, lambda o, d, f: self._held_out_logs(render, bundle, o, d, f), self.fixed_thresholds())
        return outputs

    def _held_out_logs(self, render: RenderRays, like: RayBundle, origins: Tensor, directions: Tensor,
                       frames: Tensor) -> Tensor:  # fmt: skip
        """The gate's held-out samples rendered as the stream supervision renders its samples (no gradient)."""
        with torch.no_grad():
            rgb = self._render_event_rays(render, like, origins, directions, frames)
        return losses.log_luminance(rgb, self.config.event_log_eps)

    def fixed_thresholds(self) -> Tuple[float, float]:
        c_on, c_off = self.thresholds()
        return float(c_on), float(c_off)

    def edi_outputs(self, bundle: RayBundle) -> Dict[str, Tensor]:
        """The EDI prior's per-ray factor (the blurred value over it is the sharp mid-exposure value) and where the
        event camera sees the pixel (`model/edi_prior.py`)."""
        rig = self.rig
        assert self.edi_stream is not None and rig.event_stream is not None
        assert rig.trajectory is not None and rig.frame_times is not None and rig.exposure is not None
        device = bundle.origins.device
        stream, camera = self._on_device(device)  # all on the rays' device: nothing goes to the host and back
        assert stream is not None
        pose = rig.trajectory.poses_at_tensor(frame_rows(rig.frame_times, bundle).double(), dtype=torch.float64)
        local = (pose[:, :3, :3].transpose(-1, -2) @ bundle.directions.double()[..., None])[..., 0]
        depth = float(rig.event_camera.get("plane_depth", math.inf))
        pixel, inside = edi_prior.event_pixels(camera, local, depth)
        c_on, c_off = (c.detach() if isinstance(c, Tensor) else c for c in self.thresholds())
        factor = edi_prior.edi_factors(stream, pixel, frame_rows(rig.exposure, bundle), c_on, c_off)
        return {"edi_factor": factor, "edi_valid": inside.float()[:, None]}

    def _render_event_rays(
        self,
        render: RenderRays,
        like: RayBundle,
        origins: Float[Tensor, "m 2 3"],
        directions: Float[Tensor, "m 2 3"],
        frames: Int[Tensor, " m"],
    ) -> Float[Tensor, "m 2 3"]:
        """RGB of `m` event samples' rays at both their times (the device, dtype and pixel area of `like`; camera
        index: the training frame `frames` [m] of each), with the event loss's density gradient scale."""
        m = int(origins.shape[0])
        device, dtype = like.origins.device, like.origins.dtype
        bundle = RayBundle(
            origins=origins.reshape(2 * m, 3).to(device=device, dtype=dtype),
            directions=directions.reshape(2 * m, 3).to(device=device, dtype=dtype),
            pixel_area=like.pixel_area[:1].expand(2 * m, 1).contiguous(),
            camera_indices=frames.repeat_interleave(2)[:, None].to(device),
        )
        return render(bundle, ("rgb",), "event_loss")["rgb"].reshape(m, 2, 3)

    def pair_logs(self, render: RenderRays, like: RayBundle, step: int) -> Dict[str, Tensor]:
        """`event_rays_per_batch` EvDeblurNeRF event samples (`model/event_pairs.py`) rendered along the event
        camera's rays at both events' times: their log luma (after the learnt response, from its start step) and
        targets."""
        rig = self.rig
        assert self.pairs is not None and rig.trajectory is not None and rig.frame_times is not None
        assert rig.event_stream is not None
        device = like.origins.device
        if self._pairs_on is None or self._pairs_on.pixel.device != device:  # drawn where they are rendered
            self._pairs_on = self.pairs.to(device)
        _, camera = self._on_device(device)
        pixel, t0, t1, polarity = self._pairs_on.sample(self.config.event_rays_per_batch)
        m = int(pixel.shape[0])
        if m == 0:  # a stream without two events at any pixel: no sample, no loss
            return {}
        times = torch.stack([t0, t1], -1).double() * 1e-6
        origins, directions = event_stream.event_rays(rig.trajectory, camera, pixel, times)
        frame_times = on_device(rig.frame_times, device).double()
        frames = (times[:, :1] - frame_times[None, :]).abs().argmin(dim=-1)  # the nearest frame's camera
        rgb = self._render_event_rays(render, like, origins, directions, frames)
        crf = self.crf if step >= self.config.event_crf_start_step else None
        features = polarity_features(polarity)
        logs = event_log_luma(colour.srgb_to_linear(rgb), self.config.event_log_eps, crf, features)
        return {"event_log_start": logs[:, 0], "event_log_end": logs[:, 1],
                "event_target": pair_targets(polarity, *self.thresholds())}  # fmt: skip

    def stream_logs(self, render: RenderRays, like: RayBundle) -> Dict[str, Tensor]:
        """`event_rays_per_batch` random event pixels in random sub-windows of random training frames' windows,
        rendered along the event camera's rays at both ends: their log luminance and their ON / OFF counts."""
        rig = self.rig
        assert rig.trajectory is not None
        device = like.origins.device
        assert rig.event_windows is not None
        stream, camera = self._on_device(device)
        assert stream is not None
        windows = on_device(rig.event_windows, device)
        m = self.config.event_rays_per_batch
        # drawn, counted and cast where the rays are rendered: nothing goes to the host and back per step
        frames = torch.randint(0, windows.shape[0], (m,), device=device)
        t0, t1 = sample_windows(windows, frames, self.config.event_window_min_fraction, None)
        if self.gate is None:
            pixel = torch.randint(0, stream.width * stream.height, (m,), device=device)
        else:  # the gate's held-out pixels are never trained on
            pixel = self.gate.training_pixels(m, device)
        on, off = stream.counts(pixel, t0, t1)
        origins, directions = event_stream.event_rays(
            rig.trajectory, camera, pixel, torch.stack([t0, t1], -1).double() * 1e-6
        )
        rgb = self._render_event_rays(render, like, origins, directions, frames)
        logs = losses.log_luminance(rgb, self.config.event_log_eps)
        return {"event_log_start": logs[:, 0], "event_log_end": logs[:, 1], "event_on": on, "event_off": off}

    def _on_device(self, device: torch.device) -> Tuple[Optional[EventStream], EventCamera]:
        """The event stream (the stream supervision's and the EDI prior's) and the event camera on `device`, moved
        there once (the stream's sorted keys: 8 bytes an event)."""
        if self._device_parts is None or self._device_parts[0] != device:
            stream = self.stream or self.edi_stream
            assert self.rig.event_stream is not None
            moved = stream.to(device) if stream is not None else None
            self._device_parts = (device, moved, self.rig.event_stream.to(device))
        return self._device_parts[1], self._device_parts[2]

    def window_logs(self, render: RenderRays, bundle: RayBundle) -> Tuple[Float[Tensor, "m 1"], Float[Tensor, "m 1"]]:
        """Log luminance of the first `event_rays_per_batch` pixels at the start and end of their event windows,
        seen from the event camera (its centre and the alignment plane from the dataset's calibration, where
        recorded)."""
        rig = self.rig
        assert rig.event_windows is not None
        m = min(self.config.event_rays_per_batch, bundle.origins.shape[0])
        head = bundle[:m]
        windows = frame_rows(rig.event_windows, head).double()
        renders = render_at(render, rig, head, windows, "event_loss", **rig.event_camera)
        logs = losses.log_luminance(renders, self.config.event_log_eps)  # [m, 2, 1]
        return logs[:, 0], logs[:, 1]

    # ------------------------------------------------------------------ loss
    def thresholds(self) -> Tuple[Any, Any]:
        """C_on, C_off: learnt (config `event_threshold_learnt`) or the configured one."""
        if self.log_threshold is None:
            return self.config.event_threshold, self.config.event_threshold
        c = self.log_threshold.exp()
        return c[0], c[1]

    def loss(self, term: str, inputs: TermInputs) -> Optional[Tensor]:
        """The raw event loss of a training step under its supervision, or the EDI prior's (None where the step has
        no sample of it)."""
        return self.edi_prior_loss(inputs) if term == "edi_prior_loss" else self.event_loss(inputs)

    @staticmethod
    def edi_prior_loss(inputs: TermInputs) -> Optional[Tensor]:
        """EvDeblurNeRF's EDI prior: the frame ray's render against the event-deblurred frame."""
        outputs, image = inputs.outputs, inputs.batch.get("image")
        if "edi_factor" not in outputs or image is None:  # no side renders (evaluation)
            return None
        image = image[..., :3].to(inputs.device)
        sharp = colour.linear_to_srgb(colour.srgb_to_linear(image) / outputs["edi_factor"])
        return losses.masked_mse(pred(inputs, "edi_prior_loss"), sharp, outputs["edi_valid"])

    def event_loss(self, inputs: TermInputs) -> Optional[Tensor]:
        """The raw event loss under the plan's supervision (None where the step has no event sample)."""
        outputs, batch, device = inputs.outputs, inputs.batch, inputs.device
        if self.mode == "pairs" and "event_target" in outputs:  # EvDeblurNeRF's event-to-event samples
            loss = losses.event_pair_loss(outputs["event_log_start"], outputs["event_log_end"], outputs["event_target"])
        elif self.mode == "stream" and "event_on" in outputs:  # the stream's event pixels carry their own counts
            loss = losses.event_loss(
                outputs["event_log_start"],
                outputs["event_log_end"],
                outputs["event_on"],
                outputs["event_off"],
                *self.thresholds(),
                lower_bound=self.config.event_loss_bound,
            )
        elif self.mode == "frames" and "event_log_start" in outputs and "event_on" in batch:
            m = outputs["event_log_start"].shape[0]
            mask = batch.get("event_mask")
            loss = losses.event_loss(
                outputs["event_log_start"],
                outputs["event_log_end"],
                batch["event_on"][:m].to(device),
                batch["event_off"][:m].to(device),
                *self.thresholds(),
                None if mask is None else mask.to(device)[:m],
                lower_bound=self.config.event_loss_bound,
            )
        else:
            return None
        return loss

    def weigh(self, term: str, weighted: Tensor, inputs: TermInputs) -> Tensor:
        """The EDI prior's cosine-decayed weight (EvDeblurNeRF's); the event loss's `noise` weighting and gate."""
        if term == "edi_prior_loss":
            return weighted * edi_prior.cosine_weight(inputs.step)
        return self.weighted_loss(weighted, inputs.raw, inputs.outputs)

    def param_groups(self) -> Dict[str, List[Parameter]]:
        """The learnt thresholds with the "fields"; the learnt event response's own group "event_crf"."""
        groups: Dict[str, List[Parameter]] = {}
        if self.log_threshold is not None:
            groups["fields"] = [self.log_threshold]
        if self.crf is not None:
            groups["event_crf"] = list(self.crf.parameters())
        return groups

    def noise_weight(self, raw: Dict[str, Tensor], outputs: Dict[str, Tensor]) -> Float[Tensor, ""]:
        """The `noise` weighting's factor (config `event_loss_weighting`): the event samples' share of the batch
        times the ratio of the running RGB and event losses, never above an RGB ray's (means updated in training).
        Kept on the losses' device in float64 (the arithmetic of Python numbers): nothing is read back per step."""
        means = self.loss_means
        if self.training:
            new = torch.stack([raw["rgb_loss"].detach(), raw["event_loss"].detach()]).double()
            old = torch.where(means[0].isnan(), new, means)
            updated = 0.99 * old + 0.01 * new  # 0.99 a step
            means.copy_(torch.where(new.isfinite().all(), updated, means))  # a non-finite loss leaves them
        samples = outputs["event_log_start"].shape[0] / outputs["rgb"].shape[0]
        weight = samples * (means[0] / means[1].clamp(min=1e-12)).clamp(max=1.0)
        self.weight.copy_(torch.where(means[0].isnan(), 0.0, weight))
        return self.weight

    def weighted_loss(self, loss: Float[Tensor, ""], raw: Dict[str, Tensor], outputs: Dict[str, Tensor]) -> Tensor:
        """The weighted event loss: times the `noise` weighting's factor (where configured) and the gate's, both
        float64 on the device, multiplied as the one factor in the loss's dtype."""
        factor: Optional[Tensor] = None
        if self.config.event_loss_weighting == "noise" and "rgb_loss" in raw:
            factor = self.noise_weight(raw, outputs)
        if self.gate is not None:
            factor = self.gate.factor if factor is None else factor * self.gate.factor
        return loss if factor is None else loss * factor.to(loss.dtype)

    def metrics(self, training: bool) -> Dict[str, Any]:
        """`event_loss_weight` (training, with the `noise` weighting: 0 until it has means), the gate's factor and
        residual (training) and the learnt thresholds: tensors, read by the host only when logged."""
        metrics: Dict[str, Any] = {}
        if training and self.config.event_loss_weighting == "noise":
            metrics["event_loss_weight"] = self.weight.detach().clone()
        if self.gate is not None and training:
            metrics["event_gate"] = self.gate.factor.detach().clone()
            metrics["event_gate_residual"] = self.gate.residual.detach().clone()
        if self.log_threshold is not None:
            metrics["event_threshold_on"], metrics["event_threshold_off"] = self.log_threshold.detach().exp()
        return metrics
