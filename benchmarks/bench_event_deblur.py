"""What the event loss and the blur model do for the RGB reconstruction of motion-blurred scenes (Tables I/II's
EvDeblurNeRF against Ours (RGB), and the ablation of the RGB module's parts).

    python benchmarks/bench_event_deblur.py --out outputs/deblur --scenes orchard-dusk orchard-dark \
        [--rows rgb blur events evdeblurnerf] [--profile deblur]

Every row is one ``ns-train agrinerf-lite`` run on the profile's scene (the same RGB TensoRF; the rows switch its
parts on), evaluated on the held-out views against the sharp, exposure-aligned clean truth; each row is paired, view
by view, with ``rgb`` (the RGB TensoRF alone). Writes ``OUT/results.csv`` (resumable) and ``OUT/deblur.md`` with the
PSNR table and the paper's Tables I/II (step times: ``benchmarks/bench_event_speed.py``).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Dict, Optional, Tuple

import tyro

from agrinerf_ns.lab import results
from agrinerf_ns.lab.methods import METHODS, BenchMethod
from agrinerf_ns.lab.profiles import PROFILES, BenchProfile
from agrinerf_ns.lab.runs import run_method
from agrinerf_ns.lab.scenes import prepare_scene
from agrinerf_ns.machine import device_name
from agrinerf_ns.method_configs.agrinerf_methods import EVDEBLURNERF_LR, evdeblurnerf_lite

MODEL = "--pipeline.model."
RGB = (f"{MODEL}modalities", "rgb")
EVENTS = (f"{MODEL}modalities", "rgb", "events", f"{MODEL}cross-spectral-output", "False")
NOISE = (f"{MODEL}event-loss-weighting", "noise")
GATE = (f"{MODEL}event-gate", "True")
"""The `agrinerf` preset's event gate (a held-out share of the events sets the term's weight)."""


def _blur(k: int) -> Tuple[str, ...]:
    return (f"{MODEL}blur-samples", str(k))


def _events(pixels: int, weight: float = 0.1) -> Tuple[str, ...]:
    """The event loss on `pixels` event pixels per batch at `weight`, in any light (the rows measure it)."""
    return (
        f"{MODEL}event-supervision", "stream", f"{MODEL}event-rays-per-batch", str(pixels), f"{MODEL}loss-coefficients.event-loss", str(weight),
        f"{MODEL}low-light-event-loss", "True",
    )  # fmt: skip


OURS_EVENTS = (*_events(256, 1.0), *NOISE, *GATE)
"""The `agrinerf` preset's kind of event term on the lite field: noise-balanced (coefficient 1) and gated."""


def _window(fraction: float) -> Tuple[str, ...]:
    return (f"{MODEL}event-window-min-fraction", str(fraction))


LITE_MODEL_ON_EVDEBLURNERF = (
    f"{MODEL}edi-prior", "False", f"{MODEL}event-crf", "False", f"{MODEL}blur-kernel", "trajectory",
    f"{MODEL}blur-start-step", "0", f"{MODEL}num-fine-samples", "16", f"{MODEL}event-log-eps", "1e-4",
)  # fmt: skip
"""``evdeblurnerf-lite``'s model settings back to ``agrinerf-lite``'s (with a row's own options on top): only the
optimizers then differ."""

OURS_PLUS_PARTS: Dict[str, Tuple[str, Tuple[str, ...]]] = {
    "gate-plus-edi": ("EvDeblurNeRF's EDI prior", (f"{MODEL}edi-prior", "True")),
    "gate-plus-pairs": (
        "EvDeblurNeRF's event-to-event pairs in place of windows",
        (f"{MODEL}event-supervision", "pairs"),
    ),
    "gate-plus-pairs-crf": (
        "event-to-event pairs with EvDeblurNeRF's learnt event response from step 0",
        (f"{MODEL}event-supervision", "pairs", f"{MODEL}event-crf", "True", f"{MODEL}event-crf-start-step", "0"),
    ),
    "gate-plus-learnt-kernel": (
        "EvDeblurNeRF's learnt rigid kernel (3 rays) from step 0 in place of the trajectory",
        (f"{MODEL}blur-kernel", "learnt"),
    ),
    "gate-plus-evd-schedule": ("EvDeblurNeRF's learning-rate schedule", LITE_MODEL_ON_EVDEBLURNERF),
}
"""Ours' RGB module (``blur-events-gate``) with one of EvDeblurNeRF's parts added, as ``evdeblurnerf-lite`` has it
(issue #63, item 1b), each paired with ``blur-events-gate``: key -> (the part, its options). The learnt event response
works on event pairs only (``model/parts.py``), so it comes with them (paired with ``gate-plus-pairs`` as well). Its
response and kernel start at step 1200 in ``evdeblurnerf-lite``, past these rows' 800 steps: they start where Ours'
blur model does, at step 0. The kernel keeps Ours' 3 rays (EvDeblurNeRF: 10), the pairs Ours' 256 samples, noise
balance and gate (EvDeblurNeRF: 4096 at weight 0.1), so that only the part changes. The schedule row trains with
``evdeblurnerf-lite``'s optimizers (:data:`ROW_PRESETS`)."""

ROWS: Dict[str, Tuple[str, Tuple[str, ...]]] = {
    "rgb": ("RGB TensoRF", RGB),
    "blur": ("+ blur model (K=3)", (*RGB, *_blur(3))),
    "events-frames": ("+ event loss on warped frames", (*EVENTS, *_events(256), f"{MODEL}event-supervision", "frames")),
    "events-whole": ("+ event loss, whole frame windows", (*EVENTS, *_events(256), *_window(1.0))),
    "events": ("+ event loss", (*EVENTS, *_events(256))),
    "events-w0.01": ("+ event loss at weight 0.01", (*EVENTS, *_events(256, 0.01))),
    "events-w0.001": ("+ event loss at weight 0.001", (*EVENTS, *_events(256, 0.001))),
    "events-noise": ("+ event loss, noise-balanced weight", (*EVENTS, *_events(256, 1.0), *NOISE)),
    "evdeblurnerf": (
        "EvDeblurNeRF port (windowed events at 0.1, trajectory blur K=3)",
        (*EVENTS, *_blur(3), *_events(256)),
    ),
    "evdeblurnerf-w0.01": ("EvDeblurNeRF, event weight 0.01", (*EVENTS, *_blur(3), *_events(256, 0.01))),
    "blur-events-noise": (
        "Ours (RGB module): blur + noise-balanced events",
        (*EVENTS, *_blur(3), *_events(256, 1.0), *NOISE),
    ),
    "blur-events-learnt": (
        "blur + noise-balanced events, learnt thresholds",
        (*EVENTS, *_blur(3), *_events(256, 1.0), *NOISE, f"{MODEL}event-threshold-learnt", "True"),
    ),
    "events-learnt": (
        "+ noise-balanced event loss, learnt thresholds",
        (*EVENTS, *_events(256, 1.0), *NOISE, f"{MODEL}event-threshold-learnt", "True"),
    ),
    "events-eps1e-6": (
        "+ noise-balanced event loss, log offset 1e-6",
        (*EVENTS, *_events(256, 1.0), *NOISE, f"{MODEL}event-log-eps", "1e-6"),
    ),
    "events-bound": (
        "+ noise-balanced event loss, counts as lower bounds",
        (*EVENTS, *_events(256, 1.0), *NOISE, f"{MODEL}event-loss-bound", "True"),
    ),
    "blur-events-bound": (
        "blur + noise-balanced events, counts as lower bounds",
        (*EVENTS, *_blur(3), *_events(256, 1.0), *NOISE, f"{MODEL}event-loss-bound", "True"),
    ),
    "blur-pairs-noise": (
        "blur + noise-balanced event-to-event loss (EvDeblurNeRF's event samples)",
        (*EVENTS, *_blur(3), *_events(256, 1.0), *NOISE, f"{MODEL}event-supervision", "pairs"),
    ),
    "thermal-geometry": (
        "All, the thermal-camera term moves the density",
        (f"{MODEL}density-gradient-scales.thermal-camera-loss", "1.0"),
    ),
    "blur-thermal-geometry": (
        "All + blur, the thermal-camera term moves the density",
        (*_blur(3), f"{MODEL}density-gradient-scales.thermal-camera-loss", "1.0"),
    ),
    "dark-recipe": (
        "All + blur + bounded events, the thermal-camera term moves the density",
        (
            *_blur(3),
            *_events(256, 1.0),
            *NOISE,
            f"{MODEL}event-loss-bound",
            "True",
            f"{MODEL}density-gradient-scales.thermal-camera-loss",
            "1.0",
        ),
    ),
    "blur-events-gate": (
        "Ours (RGB module): blur + gated noise-balanced events",
        (*EVENTS, *_blur(3), *OURS_EVENTS),
    ),
    "blur-events-gate-evd-budget": (
        "Ours (RGB module) at EvDeblurNeRF-lite's budget: twice the steps, 32 + 32 samples",
        (*EVENTS, *_blur(3), *OURS_EVENTS, f"{MODEL}num-fine-samples", "32"),
    ),
    "agrinerf": ("Ours: All + blur + gated noise-balanced events", (*_blur(3), *OURS_EVENTS)),
    "rgb-long": ("RGB TensoRF, 4x the steps", RGB),
    "rgb-seed": ("RGB TensoRF, another seed", (*RGB, "--machine.seed", "43")),
    **{
        key: (f"Ours (RGB module) + {label}", (*EVENTS, *_blur(3), *OURS_EVENTS, *options))
        for key, (label, options) in OURS_PLUS_PARTS.items()
    },
}
"""Row key -> (label, ``ns-train`` options of its preset, :data:`ROW_PRESETS`, else ``agrinerf-lite``). The event loss
takes 256 event pixels per batch at weight 0.1 (EvDeblurNeRF's) from the event stream at the event camera's pixels in
random sub-windows (the model's defaults), the blur model 3 renders per blurred pixel, unless the key says
otherwise."""

ROW_PRESETS: Dict[str, str] = {"gate-plus-evd-schedule": "evdeblurnerf-lite"}
"""Rows trained with another preset's optimizers: Ours' RGB module (its options, the same model) under
``evdeblurnerf-lite``'s learning rates and schedule (Adam x 0.1^(step / 10k), not x0.1 at 1/3 and 2/3 of 2k steps)."""

BASELINES: Dict[str, str] = {
    "nerfacto": "Nerfacto (RGB)",
    "nerfacto-thermal": "Nerfacto (Thermal)",
    "evdeblurnerf-lite": "EvDeblurNeRF (TensoRF-lite field and its grid rate, not PDRF's)",
}
"""Rows that are other methods (``agrinerf_ns.lab.methods.METHODS``), at the profile's step budget for them.
``evdeblurnerf-lite`` is EvDeblurNeRF's recipe (event-to-event samples, learnt event response and rigid blur kernel
from step 1200, EDI prior, its learning-rate schedule) on AgriNeRF-lite's field: its budget must pass step 1200."""

_PRESET_GRIDS = evdeblurnerf_lite.config.optimizers["encodings"]
_PDRF_GRID_LR = (
    "--optimizers.encodings.optimizer.lr", str(EVDEBLURNERF_LR),
    # the preset's own decay (EvDeblurNeRF's x0.1 per 10k steps over its scheduled steps), from the published start
    "--optimizers.encodings.scheduler.lr-final",
    f"{EVDEBLURNERF_LR * _PRESET_GRIDS['scheduler'].lr_final / _PRESET_GRIDS['optimizer'].lr:.6g}",
)  # fmt: skip

PUBLISHED_VARIANTS: Dict[str, Tuple[str, Tuple[str, ...]]] = {
    "learnt-kernel": (
        "RGB + learnt rigid kernel (frames only: EvDeblurNeRF's recipe without events)",
        (*RGB, f"{MODEL}edi-prior", "False", f"{MODEL}event-crf", "False"),
    ),
    "recipe-rgb": (
        "RGB TensoRF on EvDeblurNeRF's recipe (its schedule and steps; no kernel, no events)",
        (*RGB, f"{MODEL}blur-samples", "1", f"{MODEL}edi-prior", "False", f"{MODEL}event-crf", "False"),
    ),
    "evdeblurnerf-lite-pdrf-lr": ("EvDeblurNeRF, grids at PDRF's learning rate (5e-3, as published)", _PDRF_GRID_LR),
    "evdeblurnerf-lite-fine32": (
        "EvDeblurNeRF as published, 32 + 32 samples (the preset's since these rows; 16 fine before)",
        (f"{MODEL}num-fine-samples", "32"),
    ),
    "evdeblurnerf-lite-no-edi": ("EvDeblurNeRF as published, without the EDI prior", (f"{MODEL}edi-prior", "False")),
    "evdeblurnerf-lite-no-crf": (
        "EvDeblurNeRF as published, without the learnt event response",
        (f"{MODEL}event-crf", "False"),
    ),
    "evdeblurnerf-lite-trajectory": (
        "EvDeblurNeRF as published, the trajectory kernel in place of the learnt one",
        (f"{MODEL}blur-kernel", "trajectory"),
    ),
    "evdeblurnerf-lite-windows": (
        "EvDeblurNeRF as published, windowed events in place of event-to-event pairs (no response: pairs only)",
        (f"{MODEL}event-supervision", "stream", f"{MODEL}event-crf", "False"),
    ),
}
"""Rows that switch parts of ``evdeblurnerf-lite`` off (its steps, schedule and kernel), to attribute its gap:
``learnt-kernel`` is the frame-only deblurring its paper compares against (DP-NeRF's learnt kernel, no events);
``recipe-rgb`` the same recipe without the kernel, so that the kernel's part and the schedule's part separate;
``evdeblurnerf-lite-pdrf-lr`` the recipe with the grids learnt at PDRF's published rate, not TensoRF's (the preset's);
the ``-no-edi``, ``-no-crf``, ``-trajectory`` and ``-windows`` rows each take one of its parts away (issue #63, item
1a; the learnt response reads event pairs only, so the windows row has none)."""

TABLE_I: Tuple[Tuple[str, str], ...] = (
    ("rgb", "RGB TensoRF"),
    ("nerfacto", "Nerfacto (RGB)"),
    ("nerfacto-thermal", "Nerfacto (Thermal)"),
    ("evdeblurnerf-lite", "EvDeblurNeRF (TensoRF-lite field at its grid rate)"),
    ("evdeblurnerf-lite-pdrf-lr", "EvDeblurNeRF (as published: PDRF's grid rate)"),
    ("evdeblurnerf", "EvDeblurNeRF port (windowed events, trajectory blur)"),
    ("blur", "RGB TensoRF + trajectory blur model, no events"),
    ("blur-events-noise", "Ours (RGB module), ungated events"),
    ("blur-events-gate", "Ours (RGB module: blur + gated noise-balanced events)"),
    ("blur-events-gate-evd-budget", "Ours (RGB module) at EvDeblurNeRF-lite's 1600 steps and 32 + 32 samples"),
    ("agrinerf", "Ours (RGB): All + blur + gated noise-balanced events"),
)
"""The paper's Tables I/II rows: row key -> label."""

PAIRS: Tuple[Tuple[str, str, str], ...] = (
    ("blur-events-gate", "blur", "Ours (RGB) against the same module without events"),
    ("blur-events-gate", "blur-events-noise", "The gate against the ungated event term"),
    ("blur-events-noise", "blur", "The ungated event term against the same module without events"),
    ("blur-events-gate", "evdeblurnerf-lite", "Ours (RGB) against EvDeblurNeRF at TensoRF's grid rate"),
    ("blur-events-gate-evd-budget", "evdeblurnerf-lite", "The same, Ours at EvDeblurNeRF-lite's steps and samples"),
    (
        "blur-events-gate-evd-budget",
        "blur-events-gate",
        "Ours at EvDeblurNeRF-lite's steps and samples, against its own",
    ),
    ("blur", "evdeblurnerf-lite", "The trajectory blur model against EvDeblurNeRF at TensoRF's grid rate"),
    ("evdeblurnerf-lite", "evdeblurnerf-lite-pdrf-lr", "EvDeblurNeRF at TensoRF's grid rate against PDRF's"),
    ("evdeblurnerf-lite", "learnt-kernel", "EvDeblurNeRF against its recipe without events (its paper's ordering)"),
    ("learnt-kernel", "recipe-rgb", "The learnt rigid kernel against the same recipe without it"),
    ("evdeblurnerf-lite", "evdeblurnerf-lite-no-edi", "The EDI prior's part of EvDeblurNeRF"),
    *((key, "blur-events-gate", f"Ours (RGB) + {label}, against Ours") for key, (label, _) in OURS_PLUS_PARTS.items()),
    ("gate-plus-pairs-crf", "gate-plus-pairs", "The learnt event response on Ours' event pairs, against none"),
)
"""Paired per-view comparisons reported where both rows ran: (row, against, what it measures)."""


def paired_table(rows, scenes) -> str:
    """Each pair of :data:`PAIRS` that both ran on a scene: its mean per-view PSNR difference, 95% t-interval."""
    last = results.final_rows(rows)
    lines = ["| scene | comparison | PSNR difference (dB) | SSIM |", "|---|---|---|---|"]
    for scene in scenes:
        for mine, base, what in PAIRS:
            a, b = last.get((scene, mine)), last.get((scene, base))
            if a is None or b is None or not results.per_view(a) or not results.per_view(b):
                continue
            difference = results.difference_text(*results.paired_difference(results.per_view(a), results.per_view(b)))
            ssim = f"{results.as_float(a, 'ssim_clean'):.3f} vs {results.as_float(b, 'ssim_clean'):.3f}"
            lines.append(f"| {scene} | {what} | {difference} | {ssim} |")
    return "\n".join(lines) + "\n" if len(lines) > 2 else ""


STEP_FACTORS: Dict[str, int] = {"rgb-long": 4, "blur-events-gate-evd-budget": 2}
"""Rows trained for a multiple of the profile's steps: the RGB TensoRF at about the wall time of the blur model's rows
(their step times: ``benchmarks/bench_event_speed.py``), and Ours at EvDeblurNeRF-lite's 1600 steps."""


@dataclass
class Args:
    out: Path = Path("outputs/deblur")
    """Runs, ``results.csv`` and ``deblur.md``."""
    scenes: Tuple[str, ...] = ("orchard-dusk", "orchard-dark")
    rows: Tuple[str, ...] = tuple(ROWS)
    profile: str = "deblur"
    """Scene size, motion, held-out views and step budget (``agrinerf_ns.lab.profiles``)."""
    seed: int = 0
    """The scenes' seed (below 100 tuning, 100 and up reporting: docs/bench_profiles.md, Seeds)."""
    train_seed: Optional[int] = None
    """Nerfstudio's ``--machine.seed`` for every row (its default 42 where unset)."""
    report_only: bool = False
    """Train nothing: write deblur.md from the rows already in results.csv."""


def row_profile(profile: BenchProfile, key: str) -> BenchProfile:
    """The profile with this row's step budget."""
    if key in BASELINES or key in PUBLISHED_VARIANTS:
        return profile
    steps = profile.steps["agrinerf-lite"] * STEP_FACTORS.get(key, 1)
    return replace(profile, steps={**profile.steps, key: steps})


def method(key: str, train_seed: Optional[int] = None) -> BenchMethod:
    """The row's method, with Nerfstudio's machine seed where one is given."""
    chosen = _method(key)
    if train_seed is None:
        return chosen
    return replace(chosen, train_args=(*chosen.train_args, "--machine.seed", str(train_seed)))


def _method(key: str) -> BenchMethod:
    if key in BASELINES:
        return METHODS[key]
    if key in PUBLISHED_VARIANTS:
        label, options = PUBLISHED_VARIANTS[key]
        return BenchMethod(label, "evdeblurnerf-lite", "transforms.json", "rgb", train_args=options)
    label, options = ROWS[key]
    return BenchMethod(label, ROW_PRESETS.get(key, "agrinerf-lite"), "transforms.json", "rgb", train_args=options)


def tables_i_ii(rows, scenes) -> str:
    """The paper's Tables I/II: PSNR / SSIM / LPIPS of each row's RGB render against the sharp clean truth (and of the
    thermal render against the rescaled thermal frames, for the thermal rows), at the last step."""
    last = results.final_rows(rows)

    def cell(row, key: str, digits: int) -> str:
        value = results.as_float(row, key) if row is not None else float("nan")
        return "-" if value != value else f"{value:.{digits}f}"

    lines = ["| scene | method | steps | PSNR | SSIM | LPIPS | thermal PSNR |", "|---|---|---|---|---|---|---|"]
    for scene in scenes:
        for key, label in TABLE_I:
            row = last.get((scene, key))
            if row is None:
                continue
            lines.append(f"| {scene} | {label} | {row['step']} | {cell(row, 'psnr_clean', 2)} | "
                         f"{cell(row, 'ssim_clean', 3)} | {cell(row, 'lpips', 3)} | {cell(row, 'thermal_psnr', 2)} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(args: Args) -> None:
    known = {**ROWS, **PUBLISHED_VARIANTS, **{k: (label, ()) for k, label in BASELINES.items()}}
    unknown = [r for r in args.rows if r not in known]
    if unknown:
        raise SystemExit(f"unknown rows {unknown}: {list(known)}")
    keys = ["rgb"] + [r for r in args.rows if r != "rgb"]
    profile = PROFILES[args.profile]
    csv_path = args.out / "results.csv"
    device = device_name()
    prepared = (
        {} if args.report_only else {s: prepare_scene(s, profile, args.seed, args.out / "scenes") for s in args.scenes}
    )
    for scene, (raw, data) in prepared.items():
        done = results.done_runs(results.read_rows(csv_path))
        for key in keys:
            if (scene, key) in done:
                continue
            print(f"{scene}: {key}", flush=True)
            rows = run_method(
                scene,
                key,
                method(key, args.train_seed),
                raw,
                data,
                row_profile(profile, key),
                args.out / "runs",
                device,
            )
            results.append_rows(csv_path, rows)
    rows = [r for r in results.read_rows(csv_path) if r["scene"] in args.scenes]
    labels = {k: known[k][0] for k in keys}
    text = (
        "# RGB PSNR of the RGB module's parts on motion-blurred scenes\n\n"
        f"Command: `python benchmarks/bench_event_deblur.py {' '.join(sys.argv[1:])}`\n\n"
        f"Machine: {device}. Profile `{args.profile}`: AgriNeRF-lite's RGB TensoRF, "
        f"{profile.steps['agrinerf-lite']} steps, {profile.views} views of {profile.width}x{profile.height} "
        f"({profile.synth or 'default motion'}), every {profile.eval_every}th held out. PSNR against the sharp, "
        "exposure-aligned clean truth at the last step; in brackets the mean paired per-view difference to the RGB "
        "TensoRF alone and its 95% t-interval (* where the interval excludes 0). Rows: "
        "`benchmarks/bench_event_deblur.py` ROWS.\n\n"
        + results.ablation_table(rows, keys, "rgb", labels)
        + "\nStep time and memory: not from these rows, which ran one after another under whatever else the machine "
        "ran, but from `benchmarks/bench_event_speed.py`, which steps the parts in turn in one process "
        "(results/event-speed: table and plot).\n"
        + "\nThe paper's Tables I/II (RGB rows against the sharp clean truth; LPIPS NaN where no AlexNet weights are "
        "available offline; Nerfacto (Thermal) is scored on the thermal frames only):\n\n"
        + tables_i_ii(rows, args.scenes)
    )
    pairs = paired_table(rows, args.scenes)
    if pairs:
        text += (
            "\nPaired per view (the same held-out views; mean difference and its 95% t-interval, * where it excludes "
            "0):\n\n" + pairs
        )
    (args.out / "deblur.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main(tyro.cli(Args))
