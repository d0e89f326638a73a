"""How well can a good reconstruction explain the event loss's targets? The diagnosis behind the event supervision.

    python benchmarks/event_oracle.py --config RUN/config.yml --out results/event-oracle

Takes a trained run (an RGB-only one is the fair judge: the events never shaped it) on a dataset with events and
compares, for random event samples, the run's rendered log-luminance change with the event loss's target
C (ON - OFF), for each way the loss can read the events:

- ``frames, RGB rays``: the frame-window counts warped into the RGB pixels, rendered along the RGB pixels' rays;
- ``frames, event-camera rays``: the same counts, rendered from the event camera's centre (``event_camera``);
- ``stream``: the event stream at the event camera's own pixels, each rendered along its own ray, whole frame windows;
- ``stream, sub-windows``: the same in random sub-windows (``event_window_min_fraction``);
- with ``--truth-capture RAW`` (a synthetic capture): the stream against the scene's truth instead of the run, what
  the targets are worth when the reconstruction is perfect.

Per way: the correlation of prediction and target, the loss (MSE) of the prediction and of predicting no change,
and the gain g minimising |g prediction - target|^2 (1 for a consistent response). Writes ``OUT/event_oracle.md``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Optional, Tuple

import torch
import tyro

from agrinerf_ns.dataparsers.event_stream import EventStream, event_rays, sample_windows
from agrinerf_ns.machine import device_name
from agrinerf_ns.model import losses
from agrinerf_ns.model.blur_term import render_at
from agrinerf_ns.model.timed_rays import camera_rows


@dataclass
class Args:
    config: Path
    """A trained run's config.yml (its dataset must have events)."""
    out: Path = Path("results/event-oracle")
    samples: int = 8192
    """Event samples per way."""
    threshold: float = 0.2
    """Contrast threshold C."""
    min_fraction: float = 0.25
    """Shortest sub-window, as a fraction of the frame window."""
    seed: int = 0
    truth_capture: Optional[Path] = None
    """The run's raw synthetic capture (``agrinerf-synth`` output): also judge the events by the scene's truth, the
    synthetic renderer's log luminance at the event camera (whole event frames, every third training window)."""


def _stats(pred: torch.Tensor, target: torch.Tensor) -> Tuple[float, float, float, float]:
    p, t = pred.double().reshape(-1), target.double().reshape(-1)
    corr = float(torch.corrcoef(torch.stack([p, t]))[0, 1])
    gain = float((p * t).sum() / (p * p).sum().clamp(min=1e-12))
    return corr, float(((p - t) ** 2).mean()), float((t**2).mean()), gain


def _render_logs(model, bundle, eps: float) -> torch.Tensor:
    out = []
    for s in range(0, len(bundle), 4096):
        out.append(losses.log_luminance(model.render(model.collider(bundle[s : s + 4096]), routed=False)["rgb"], eps))
    return torch.cat(out)


def truth_rows(
    raw: Path, stream: EventStream, windows: torch.Tensor, threshold: float, min_fraction: float
) -> List[Tuple[str, Tuple[float, float, float, float]]]:
    """The stream's targets against the synthetic scene's truth log-luminance change at the event camera."""
    import dataclasses
    import json

    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.capture import event_log_luminance, make_scene
    from agrinerf_ns.synth.scene import LIGHTING_PRESETS

    written = json.loads((raw / "truth" / "scene.json").read_text())["config"]
    fields = {f.name for f in dataclasses.fields(SynthConfig)}
    config = SynthConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in written.items() if k in fields})
    scene, rig = make_scene(config)
    light, cam = LIGHTING_PRESETS[config.lighting], rig.cams["event"]

    def log_lum(t_us: int) -> torch.Tensor:
        return torch.from_numpy(event_log_luminance(config, scene, rig, light, t_us * 1e-6))

    pixel = torch.arange(cam.width * cam.height)
    rows = []
    for label, fraction in (("stream, synthetic truth", 1.0), ("stream, sub-windows, synthetic truth", min_fraction)):
        frames = torch.arange(0, windows.shape[0], 3)
        t0, t1 = sample_windows(windows, frames, fraction, torch.Generator().manual_seed(0))
        pred, target = [], []
        for a, b in zip(t0.tolist(), t1.tolist(), strict=True):
            on, off = stream.counts(pixel, torch.full_like(pixel, a), torch.full_like(pixel, b))
            pred.append(log_lum(b) - log_lum(a))
            target.append(threshold * (on - off)[:, 0])
        rows.append((label, _stats(torch.cat(pred), torch.cat(target))))
    return rows


def main(args: Args) -> None:
    from nerfstudio.cameras.rays import RayBundle
    from nerfstudio.utils.eval_utils import eval_setup

    torch.manual_seed(args.seed)
    _, pipeline, _, _ = eval_setup(args.config, test_mode="val")
    model, dataset = pipeline.model, pipeline.datamanager.train_dataset
    metadata = dataset.metadata
    eps = model.config.event_log_eps
    windows, trajectory = metadata["event_windows"], metadata["trajectory"]
    rows: List[Tuple[str, Tuple[float, float, float, float]]] = []
    with torch.no_grad():
        # frames: random RGB pixels of random training frames, the frame windows' warped counts
        frames = torch.randint(0, len(dataset), (args.samples,))
        h, w = int(dataset.cameras.height[0]), int(dataset.cameras.width[0])
        ys, xs = torch.randint(0, h, (args.samples,)), torch.randint(0, w, (args.samples,))
        coords = torch.stack([frames, ys, xs], -1)
        bundle = dataset.cameras.to("cpu").generate_rays(
            camera_indices=coords[:, :1], coords=coords[:, 1:].float() + 0.5
        )
        bundle = bundle.flatten() if bundle.shape != (args.samples,) else bundle
        counts: Dict[str, List[torch.Tensor]] = {"on": [], "off": [], "mask": []}
        cache: Dict[int, Dict[str, torch.Tensor]] = {}
        for f, y, x in coords.tolist():
            if f not in cache:
                cache[f] = dataset.get_metadata({"image_idx": f, "image": torch.zeros(h, w, 3)})
            counts["on"].append(cache[f]["event_on"][y, x])
            counts["off"].append(cache[f]["event_off"][y, x])
            counts["mask"].append(cache[f]["event_mask"][y, x] if "event_mask" in cache[f] else torch.ones(1))
        target = args.threshold * (torch.stack(counts["on"]).float() - torch.stack(counts["off"]).float())
        inside = torch.stack(counts["mask"]).reshape(-1) > 0.5
        win = windows[camera_rows(bundle)].double()
        for label, camera in (("frames, RGB rays", {}), ("frames, event-camera rays", metadata.get("event_camera"))):
            if camera is None:
                continue
            renders = render_at(model.render_rays, model.rig, bundle, win, "event_loss", **camera)
            logs = losses.log_luminance(renders, eps)
            rows.append((label, _stats((logs[:, 1] - logs[:, 0])[inside], target[inside])))
        # stream: random event pixels, whole frame windows and random sub-windows
        meta = metadata.get("event_stream")
        if meta is not None:
            stream = meta.stream()
            for label, fraction in (("stream", 1.0), ("stream, sub-windows", args.min_fraction)):
                frames = torch.randint(0, windows.shape[0], (args.samples,))
                t0, t1 = sample_windows(windows, frames, fraction, None)
                pixel = torch.randint(0, stream.width * stream.height, (args.samples,))
                on, off = stream.counts(pixel, t0, t1)
                origins, directions = event_rays(trajectory, meta, pixel, torch.stack([t0, t1], -1).double() * 1e-6)
                rays = RayBundle(
                    origins=origins.reshape(-1, 3).float(),
                    directions=directions.reshape(-1, 3).float(),
                    pixel_area=bundle.pixel_area[:1].expand(2 * args.samples, 1).contiguous(),
                    camera_indices=frames.repeat_interleave(2)[:, None],
                )
                logs = _render_logs(model, rays, eps).reshape(args.samples, 2)
                rows.append((label, _stats(logs[:, 1] - logs[:, 0], args.threshold * (on - off)[:, 0])))
        if meta is not None and args.truth_capture is not None:
            rows += truth_rows(args.truth_capture, stream, windows, args.threshold, args.min_fraction)
    args.out.mkdir(parents=True, exist_ok=True)
    lines = [
        "# How well a trained reconstruction explains the event loss's targets",
        "",
        f"Command: `python benchmarks/event_oracle.py {' '.join(sys.argv[1:])}`",
        "",
        f"Machine: {device_name()}. Run `{args.config}`; {args.samples} samples per row, C = {args.threshold}, "
        f"log offset {eps}. Prediction: the run's log-luminance change over the window; target: C (ON - OFF).",
        "",
        "| events read as | correlation | loss of the prediction | loss of 'no change' | best gain |",
        "|---|---|---|---|---|",
    ]
    lines += [f"| {label} | {c:+.3f} | {m:.4f} | {z:.4f} | {g:.2f} |" for label, (c, m, z, g) in rows]
    (args.out / "event_oracle.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main(tyro.cli(Args))
