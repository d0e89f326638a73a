"""Where the event loss costs the blurred dusk garden its RGB (issue 50): the paired runs with and without the events,
their held-out event loss, where their RGB error lies, and the rows that test a cause.

    OMP_NUM_THREADS=1 python benchmarks/event_diagnose.py --out outputs/event-diagnose [--scene garden-dusk] \
        [--rows blur blur-events-noise blur-events-warmup blur-events-gate blur-fine blur-events-fine]

Every row is one ``ns-train agrinerf-lite`` run of the ``deblur`` profile's scene (seed 0, one tuning seed: no
interval across seeds), a checkpoint every 200 steps. Printed as markdown (and written to ``OUT/diagnose.md``):

- (a) the event loss of a fixed held-out set of event samples (the stream supervision's sampler with its own seed:
  random sub-windows of ``--windows`` training frames' event windows, every ``--pixel-stride``-th event pixel), for
  each run at its checkpoints and for the scene's truth (the synthetic renderer's log luminance, no field);
  correlation, best gain and the loss of 'no change'; split into samples with and without events;
- (b) the held-out views' RGB error (exposure-aligned, against the clean truth) split by the truth's brightness
  tercile and by the event rate (ON + OFF events per pixel and frame window, warped into the RGB view) tercile;
- (c) the warm-up (event term from step 400), the data gate (`event_gate`) and finer grids as extra rows;
- (d) the simulated camera against the loss's model: clipped frame pixels, the log offsets, the threshold's spread,
  the events lost to the refractory period (``benchmarks/event_sim_fidelity.py`` measures the rest).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Dict, List, Tuple

import numpy as np
import torch
import tyro

from agrinerf_ns import image_metrics
from agrinerf_ns.lab.layout import experiment_folder, train_record
from agrinerf_ns.lab.profiles import PROFILES
from agrinerf_ns.lab.scenes import prepare_scene
from agrinerf_ns.machine import device_name
from agrinerf_ns.ns_commands import TrainRun, ns_train

sys.path.insert(0, str(Path(__file__).parent))
from bench_event_deblur import ROWS as DEBLUR_ROWS  # noqa: E402

MODEL = "--pipeline.model."
ROWS: Dict[str, Tuple[str, Tuple[str, ...], int]] = {
    "blur": ("blur model alone (K = 3)", DEBLUR_ROWS["blur"][1], 128),
    "blur-events-noise": ("blur + noise-balanced events (Ours, RGB module)", DEBLUR_ROWS["blur-events-noise"][1], 128),
    "blur-events-warmup": (
        "the same, event term from step 400",
        (*DEBLUR_ROWS["blur-events-noise"][1], f"{MODEL}event-start-step", "400"),
        128,
    ),
    "blur-events-gate": (
        "the same, data gate on (`event_gate`)",
        (*DEBLUR_ROWS["blur-events-noise"][1], f"{MODEL}event-gate", "True"),
        128,
    ),
    "blur-fine": ("blur model alone, grids to 192", DEBLUR_ROWS["blur"][1], 192),
    "blur-events-fine": ("blur + noise-balanced events, grids to 192", DEBLUR_ROWS["blur-events-noise"][1], 192),
}
"""Row -> (label, ``ns-train agrinerf-lite`` options, final grid resolution)."""


@dataclass
class Args:
    out: Path = Path("outputs/event-diagnose")
    scene: str = "garden-dusk"
    rows: Tuple[str, ...] = tuple(ROWS)
    profile: str = "deblur"
    seed: int = 0
    """The scene's seed (one tuning seed; the runs keep Nerfstudio's machine seed, as bench_event_deblur's rows)."""
    save_every: int = 200
    curve_rows: Tuple[str, ...] = ("blur", "blur-events-noise")
    """Rows whose every checkpoint is scored (the others: the last)."""
    windows: int = 4
    """Held-out event windows (training frames), all scored at every `pixel_stride`-th event pixel."""
    pixel_stride: int = 3
    threshold: float = 0.2
    min_fraction: float = 0.25


def train(args: Args, key: str, data: Path) -> TrainRun:
    """Train (or load) one row; checkpoints every `save_every` steps."""
    profile = PROFILES[args.profile]
    label, options, resolution = ROWS[key]
    record = train_record(args.out / "runs", args.scene, key)
    if record.exists():
        run = TrainRun.load(record)
        if run is not None and run.checkpoints():
            return run
    experiment = experiment_folder(args.out / "runs", args.scene, key)
    extra = list(profile.extra_args["agrinerf-lite"])
    extra[extra.index(f"{MODEL}final-resolution") + 1] = str(resolution)
    print(f"training {key}: {label}", flush=True)
    run = ns_train("agrinerf-lite", data / "transforms.json", experiment.parent, experiment.name,
                   max_steps=profile.steps["agrinerf-lite"], rays_per_batch=profile.rays_per_batch,
                   extra_args=(*options, *extra),
                   steps_per_save=args.save_every)  # fmt: skip
    run.save(record)
    return run


# ---------------------------------------------------------------------------------------------- held-out samples
def held_out_samples(args: Args, raw: Path, data: Path) -> Dict[str, torch.Tensor]:
    """The fixed held-out event samples with their targets and the truth's log change (cached in OUT)."""
    cache = args.out / f"{args.scene}-held-out.pt"
    if cache.exists():
        return torch.load(cache)
    from agrinerf_ns.dataparsers.agrinerf_dataparser import AgriNeRFDataParserConfig
    from agrinerf_ns.dataparsers.event_stream import sample_windows
    from agrinerf_ns.synth import SynthConfig
    from agrinerf_ns.synth.capture import event_log_luminance, make_scene
    from agrinerf_ns.synth.scene import LIGHTING_PRESETS

    meta = AgriNeRFDataParserConfig(data=data).setup().get_dataparser_outputs("train").metadata
    stream, windows = meta["event_stream"].stream(), meta["event_windows"]
    generator = torch.Generator().manual_seed(50)
    frames = torch.randperm(windows.shape[0], generator=generator)[: args.windows]
    t0, t1 = sample_windows(windows, frames, args.min_fraction, generator)
    written = json.loads((raw / "truth" / "scene.json").read_text())["config"]
    import dataclasses

    names = {f.name for f in dataclasses.fields(SynthConfig)}
    config = SynthConfig(**{k: (tuple(v) if isinstance(v, list) else v) for k, v in written.items() if k in names})
    scene, rig = make_scene(config)
    light = LIGHTING_PRESETS[config.lighting]
    pixel = torch.arange(0, stream.width * stream.height, args.pixel_stride)
    out: Dict[str, List[torch.Tensor]] = {k: [] for k in ("pixel", "t0", "t1", "frame", "on", "off", "truth", "lum")}
    for f, a, b in zip(frames.tolist(), t0.tolist(), t1.tolist(), strict=True):
        la = torch.from_numpy(event_log_luminance(config, scene, rig, light, a * 1e-6))[pixel]
        lb = torch.from_numpy(event_log_luminance(config, scene, rig, light, b * 1e-6))[pixel]
        on, off = stream.counts(pixel, torch.full_like(pixel, a), torch.full_like(pixel, b))
        out["pixel"].append(pixel)
        out["t0"].append(torch.full_like(pixel, a))
        out["t1"].append(torch.full_like(pixel, b))
        out["frame"].append(torch.full_like(pixel, f))
        out["on"].append(on[:, 0])
        out["off"].append(off[:, 0])
        out["truth"].append(lb - la)
        out["lum"].append(la)
    samples = {k: torch.cat(v) for k, v in out.items()}
    torch.save(samples, cache)
    return samples


def event_stats(pred: torch.Tensor, samples: Dict[str, torch.Tensor], c: float) -> Dict[str, float]:
    """Loss, correlation, best gain, 'no change' loss; the loss on samples with and without events; and by the
    truth's brightness tercile."""
    target = c * (samples["on"] - samples["off"]).double()
    p = pred.double()
    err = (p - target) ** 2
    fired = (samples["on"] + samples["off"]) > 0
    lum = samples["lum"]
    cuts = torch.quantile(lum.double(), torch.tensor([1 / 3, 2 / 3], dtype=torch.float64))
    tercile = torch.bucketize(lum.double(), cuts)
    row = {
        "loss": float(err.mean()),
        "no_change": float((target**2).mean()),
        "corr": float(torch.corrcoef(torch.stack([p, target]))[0, 1]),
        "gain": float((p * target).sum() / (p * p).sum().clamp(min=1e-12)),
        "loss_fired": float(err[fired].mean()),
        "loss_quiet": float(err[~fired].mean()),
        "pred_rms_quiet": float(p[~fired].pow(2).mean().sqrt()),
    }
    for k in range(3):
        row[f"loss_t{k}"] = float(err[tercile == k].mean())
    return row


# ---------------------------------------------------------------------------------------------- one checkpoint
def score_checkpoint(args: Args, run: TrainRun, step: int, raw: Path, samples: Dict[str, torch.Tensor]) -> Dict:
    from nerfstudio.cameras.rays import RayBundle
    from nerfstudio.utils.eval_utils import eval_setup

    from agrinerf_ns.checkpoint_eval import TruthImages, _load_at_step
    from agrinerf_ns.dataparsers.event_stream import event_rays
    from agrinerf_ns.model import losses

    _, pipeline, _, _ = eval_setup(run.config, test_mode="test", update_config_callback=_load_at_step(step))
    model = pipeline.model
    meta = pipeline.datamanager.train_dataset.metadata
    eps = model.config.event_log_eps
    row: Dict = {"step": step + 1}
    with torch.no_grad():
        times = torch.stack([samples["t0"], samples["t1"]], -1).double() * 1e-6
        origins, directions = event_rays(meta["trajectory"], meta["event_stream"], samples["pixel"], times)
        n = origins.shape[0]
        logs = []
        for s in range(0, n, 2048):
            m = min(2048, n - s)
            bundle = RayBundle(origins=origins[s : s + m].reshape(-1, 3).float(),
                               directions=directions[s : s + m].reshape(-1, 3).float(),
                               pixel_area=torch.full((2 * m, 1), 1e-6),
                               camera_indices=samples["frame"][s : s + m].repeat_interleave(2)[:, None])  # fmt: skip
            rgb = model.render(model.collider(bundle), routed=False)["rgb"]
            logs.append(losses.log_luminance(rgb, eps).reshape(m, 2))
        logs_t = torch.cat(logs)
        row["event"] = event_stats(logs_t[:, 1] - logs_t[:, 0], samples, args.threshold)
        # (b) held-out RGB error by brightness and by event rate
        truth = TruthImages(raw)
        dataset = pipeline.datamanager.eval_dataset
        names = [Path(p).name for p in dataset._dataparser_outputs.image_filenames]
        errs, lums, rates, psnrs = [], [], [], []
        for camera, batch in pipeline.datamanager.fixed_indices_eval_dataloader:
            index = int(batch["image_idx"])
            outputs = model.get_outputs_for_camera(camera=camera)
            target = truth.get(names[index])
            aligned = image_metrics.exposure_align(outputs["rgb"].detach().cpu().float(), target)
            psnrs.append(image_metrics.psnr(aligned, target))
            errs.append(((aligned - target) ** 2).mean(-1).reshape(-1))
            lums.append(losses.luminance(target)[..., 0].reshape(-1))
            h, w = target.shape[:2]
            extra = dataset.get_metadata({"image_idx": index, "image": torch.zeros(h, w, 3)})
            rate = (extra["event_on"] + extra["event_off"]).float().reshape(-1) if "event_on" in extra else None
            rates.append(rate if rate is not None else torch.full((h * w,), math.nan))
    err, lum, rate = torch.cat(errs).double(), torch.cat(lums).double(), torch.cat(rates).double()
    row["psnr_clean"] = float(np.mean(psnrs))
    row["psnr_views"] = [float(v) for v in psnrs]
    row["mse"] = float(err.mean())
    for name, values in (("lum", lum), ("rate", rate)):
        if not bool(torch.isfinite(values).all()):
            continue
        cuts = torch.quantile(values, torch.tensor([1 / 3, 2 / 3], dtype=torch.float64))
        bins = torch.bucketize(values, cuts, right=name == "rate")  # ties (no events) in the lowest bin
        row[name] = [(float(err[bins == k].sum() / err.numel()), float((bins == k).double().mean())) for k in range(3)]
    if model.events is not None:
        row["noise_weight"] = float(model.events.weight)
        if model.events.gate is not None:
            row["gate"] = float(model.events.gate.factor)
    return row


def truth_row(samples: Dict[str, torch.Tensor], c: float) -> Dict:
    return {"step": 0, "event": event_stats(samples["truth"], samples, c)}


# ---------------------------------------------------------------------------------------------- the simulator
def simulator_figures(raw: Path, data: Path) -> List[str]:
    """(d): what the simulated camera does that the loss's model does not."""
    from PIL import Image

    from agrinerf_ns.synth.capture import EVENT_EPS

    written = json.loads((raw / "truth" / "scene.json").read_text())["config"]
    frames = sorted((data / "images").glob("*.png"))
    clipped, dark = [], []
    for path in frames:
        image = np.asarray(Image.open(path).convert("RGB"))
        clipped.append(float((image.max(-1) >= 254).mean()))
        dark.append(float((image.max(-1) <= 8).mean()))
    return [
        f"- frames: {np.mean(clipped) * 100:.2f}% of RGB pixels clipped (a channel >= 254), "
        f"{np.mean(dark) * 100:.2f}% at or below 8 DN; the event camera sees past the frames' clip",
        f"- log offset: simulator log(Y_radiance + {EVENT_EPS:g}), the loss log(Y_frame + "
        "event_log_eps) on the exposure-scaled frame radiance",
        f"- contrast threshold: simulator {written.get('event_threshold')} +- {written.get('event_threshold_sigma')} "
        f"per pixel, refractory {written.get('event_refractory_us')} us, noise {written.get('event_noise_hz')} Hz "
        "per pixel (times the lighting's scale); the loss: one C, no refractory period, no noise",
    ]


# ---------------------------------------------------------------------------------------------- report
def _f(value: float, digits: int = 3) -> str:
    return "-" if value is None or value != value else f"{value:.{digits}f}"


def paired(row: Dict, base: Dict) -> str:
    """Mean per-view PSNR difference to `base` and its 95% t-interval (the same held-out views)."""
    if "psnr_views" not in row or "psnr_views" not in base or row is base:
        return "-"
    from scipy import stats

    d = np.asarray(row["psnr_views"]) - np.asarray(base["psnr_views"])
    half = stats.t.ppf(0.975, len(d) - 1) * d.std(ddof=1) / math.sqrt(len(d))
    return f"{d.mean():+.2f} +- {half:.2f}" + ("*" if abs(d.mean()) > half else "")


def report(args: Args, scores: Dict[str, List[Dict]], truth: Dict, sim: List[str]) -> str:
    lines = [f"## Event diagnosis: {args.scene}, profile `{args.profile}`, seed {args.seed} (one tuning seed)", "",
             "(a) held-out event samples (stream sampler, own seed; every checkpoint scored for the curve rows)", "",
             "| row | step | PSNR clean | event loss | no change | corr | gain | loss, fired | loss, quiet | "
             "rms pred, quiet | loss dark / mid / bright | noise weight | gate |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for key, rows in [("truth", [truth])] + list(scores.items()):
        for row in rows:
            e = row["event"]
            terciles = " / ".join(_f(e[f"loss_t{k}"]) for k in range(3))
            lines.append(f"| {key} | {row['step']} | {_f(row.get('psnr_clean'), 2)} | {_f(e['loss'])} | "
                         f"{_f(e['no_change'])} | {_f(e['corr'], 2)} | {_f(e['gain'], 2)} | {_f(e['loss_fired'])} | "
                         f"{_f(e['loss_quiet'])} | {_f(e['pred_rms_quiet'])} | {terciles} | "
                         f"{_f(row.get('noise_weight'), 5)} | {_f(row.get('gate'), 3)} |")  # fmt: skip
    lines += ["", "(b) held-out RGB squared error (x 1e-3) by the truth's brightness and by the event rate, the last "
              "checkpoint: each tercile's share of the mean (pixels' share in brackets); paired: the mean per-view "
              "PSNR difference to the blur row of the same grids, 95% t-interval (* excludes 0)", "",
              "| row | PSNR clean | vs blur, paired | MSE | dark | mid | bright | fewest events | mid | most events |",
              "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
    for key, rows in scores.items():
        row = rows[-1]
        cells = []
        for name in ("lum", "rate"):
            parts = row.get(name) or [(math.nan, math.nan)] * 3
            cells += [f"{share * 1e3:.2f} ({frac:.2f})" for share, frac in parts]
        base = scores.get("blur-fine" if key.endswith("fine") else "blur", [row])[-1]  # the same grids, no events
        lines.append(f"| {key} | {_f(row['psnr_clean'], 2)} | {paired(row, base)} | {row['mse'] * 1e3:.2f} | "
                     + " | ".join(cells) + " |")  # fmt: skip
    lines += ["", "(d) the simulated camera against the loss's model", "", *sim]
    return "\n".join(lines) + "\n"


def main(args: Args) -> None:
    unknown = [r for r in args.rows if r not in ROWS]
    if unknown:
        raise SystemExit(f"unknown rows {unknown}: {list(ROWS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    profile = replace(PROFILES[args.profile])
    raw, data = prepare_scene(args.scene, profile, args.seed, args.out / "scenes")
    samples = held_out_samples(args, raw, data)
    cache_path = args.out / f"{args.scene}-scores.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    scores: Dict[str, List[Dict]] = {}
    for key in args.rows:
        run = train(args, key, data)
        checkpoints = run.checkpoints()
        if key not in args.curve_rows:
            checkpoints = checkpoints[-1:]
        scores[key] = []
        for step, _ in checkpoints:
            name = f"{key}@{step}"
            if name not in cache:
                print(f"scoring {name}", flush=True)
                cache[name] = score_checkpoint(args, run, step, raw, samples)
                cache_path.write_text(json.dumps(cache, indent=1))
            scores[key].append(cache[name])
    text = (f"Command: `python benchmarks/event_diagnose.py {' '.join(sys.argv[1:])}`\n\nMachine: {device_name()}\n\n"
            + report(args, scores, truth_row(samples, args.threshold), simulator_figures(raw, data)))  # fmt: skip
    (args.out / "diagnose.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main(tyro.cli(Args))
