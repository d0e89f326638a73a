"""RGB PSNR of AgriNeRF-lite under each loss routing (which terms may move the shared density), per modality set.

    python benchmarks/bench_loss_routing.py --out outputs/routing --scenes orchard-dusk orchard-dark \
        [--routings paper detach-reg camera] [--sets rgb-thermal all] [--profile ablation]

Every (routing, modality set) is one ``ns-train agrinerf-lite`` run on the profile's scene, evaluated on the held-out
views against the exposure-aligned clean truth; the RGB-only run (no thermal or event term, so no routing) is the
baseline each row is paired with, view by view. Writes ``OUT/results.csv`` (resumable) and ``OUT/routing.md``.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import tyro

from agrinerf_ns.dataparsers.agrinerf_dataparser import rgb_level
from agrinerf_ns.lab import results
from agrinerf_ns.lab.methods import BenchMethod
from agrinerf_ns.lab.profiles import PROFILES
from agrinerf_ns.lab.runs import run_method
from agrinerf_ns.lab.scenes import prepare_scene
from agrinerf_ns.machine import device_name
from agrinerf_ns.modalities import TABLE_IV_ABLATIONS
from agrinerf_ns.model.model import AgriNeRFModelConfig

SCALES = "--pipeline.model.density-gradient-scales."


def _scales(thermal: float, reg: float, camera: float) -> Tuple[str, ...]:
    return (
        f"{SCALES}thermal-loss", str(thermal), f"{SCALES}reg-rgb-loss", str(reg), f"{SCALES}reg-event-loss", str(reg),
        f"{SCALES}thermal-camera-loss", str(camera),
    )  # fmt: skip


NO_CAMERA = ("--pipeline.model.thermal-camera-output", "False")
ROUTINGS: Dict[str, Tuple[str, ...]] = {
    "paper": (*NO_CAMERA, *_scales(1.0, 1.0, 1.0)),
    "detach-reg": (*NO_CAMERA, *_scales(1.0, 0.0, 1.0)),
    "rgb-geometry": (*NO_CAMERA, *_scales(0.0, 0.0, 1.0)),
    "camera": _scales(0.0, 0.0, 1.0),
    "camera-0.3": _scales(0.0, 0.0, 0.3),
    "camera+reg": _scales(0.0, 1.0, 1.0),
    "default": (),
    "camera-only": (*_scales(0.0, 0.0, 1.0), f"{SCALES}rgb-loss", "0.0"),
    "camera-rgb0.25": (*_scales(0.0, 0.0, 1.0), f"{SCALES}rgb-loss", "0.25"),
    "camera-w4": (*_scales(0.0, 0.0, 1.0), "--pipeline.model.loss-coefficients.thermal-camera-loss", "4.0"),
}
"""Routing name -> ``ns-train`` options. paper: every term moves the density (the loss as written, one thermal
output). detach-reg: L_reg trains the thermal appearance only. rgb-geometry: only L_rgb moves the density, in any
light. camera: the thermal-camera channel carries the thermal geometry, the cross-spectral terms none. camera-0.3: the
same at 0.3 strength. camera-only: the thermal-camera channel alone moves the density (L_rgb trains the RGB appearance
on it). camera-rgb0.25: L_rgb moves it at 0.25. camera-w4: camera with the thermal-camera term weighted 4. camera+reg:
the camera channel and L_reg move the density. default: the model's defaults (rgb-geometry's routing, and camera's
where the RGB frames are dark: ``low_light_level``)."""

SETS: Dict[str, str] = {"rgb-events": "RGB+Events", "rgb-thermal": "RGB+Thermal", "all": "All"}


@dataclass
class Args:
    out: Path = Path("outputs/routing")
    """Runs, ``results.csv`` and ``routing.md``."""
    scenes: Tuple[str, ...] = ("orchard-dusk", "orchard-dark")
    routings: Tuple[str, ...] = tuple(ROUTINGS)
    sets: Tuple[str, ...] = ("rgb-thermal", "all")
    """Table IV modality sets (besides the RGB baseline): rgb-events, rgb-thermal, all."""
    profile: str = "ablation"
    """Scene size, held-out views and step budget (``agrinerf_ns.lab.profiles``)."""
    seed: int = 0
    """Seed of the synthetic scenes."""
    run_seeds: Tuple[int, ...] = (0,)
    """Random streams of the training runs (``--machine.seed``; 0: Nerfstudio's default), each run of stream s > 0
    keyed ``<key>@s<s>``. A run and its RGB baseline share the stream (common random numbers: an added camera that
    sends the RGB model the same gradient trains the very same model); with two or more streams the intervals also
    cover how each difference varies between streams."""
    report_only: bool = False
    """Train nothing: write routing.md from the rows already in results.csv."""


def method(routing: str, modality_set: str, run_seed: int = 0) -> Tuple[str, BenchMethod]:
    """Result key and method of one routing and modality set (``rgb`` is the routing-free baseline), trained with
    random stream ``run_seed``."""
    stream = ("--machine.seed", str(run_seed)) if run_seed else ()
    if modality_set == "rgb":
        return results.seed_key("rgb", run_seed), BenchMethod("RGB", "agrinerf-lite", "transforms.json", "rgb",
                                  train_args=("--pipeline.model.modalities", "rgb", *stream))  # fmt: skip
    modalities = TABLE_IV_ABLATIONS[SETS[modality_set]]
    return results.seed_key(f"{routing}:{modality_set}", run_seed), BenchMethod(
        f"{SETS[modality_set]}, {routing}",
        "agrinerf-lite",
        "transforms.json",
        "rgb",
        train_args=("--pipeline.model.modalities", *modalities, *ROUTINGS[routing], *stream),
    )


def main(args: Args) -> None:
    unknown = [r for r in args.routings if r not in ROUTINGS] + [s for s in args.sets if s not in SETS]
    if unknown:
        raise SystemExit(f"unknown routings or sets {unknown}: routings {list(ROUTINGS)}, sets {list(SETS)}")
    profile = PROFILES[args.profile]
    csv_path = args.out / "results.csv"
    device = device_name()
    plan = [(seed, "-", "rgb") for seed in args.run_seeds] + [
        (seed, r, s) for seed in args.run_seeds for s in args.sets for r in args.routings
    ]
    prepared = (
        {} if args.report_only else {s: prepare_scene(s, profile, args.seed, args.out / "scenes") for s in args.scenes}
    )
    for scene, (raw, data) in prepared.items():
        done = results.done_runs(results.read_rows(csv_path))
        for run_seed, routing, modality_set in plan:
            key, bench_method = method(routing, modality_set, run_seed)
            if (scene, key) in done:
                continue
            print(f"{scene}: {key}", flush=True)
            rows = run_method(scene, key, bench_method, raw, data, profile, args.out / "runs", device)
            results.append_rows(csv_path, rows)
    rows = [r for r in results.read_rows(csv_path) if r["scene"] in args.scenes]
    text = report(rows, args, profile, device)
    (args.out / "routing.md").write_text(text)
    print(text)


REPLICATE_ROUTINGS = ("rgb-geometry",)
"""Routings whose density and RGB appearance receive exactly the RGB-only run's gradient: their runs of any modality
set are replicates of the RGB-only model with other random streams, so they measure the run-to-run spread."""


def report(rows, args: Args, profile, device: str) -> str:
    """routing.md: one Table IV in PSNR per routing (modality sets across), intervals covering the views and the
    run-to-run spread, then the thermal outputs' own PSNR."""
    compared = [method(r, s)[0] for r in args.routings for s in args.sets]
    sd, dof = results.difference_spread(rows, compared, "rgb", args.run_seeds)
    factor = 1.0
    streams = ", ".join(str(s) for s in args.run_seeds)
    if dof:
        spread = (
            "Common random numbers: each run draws the same random stream as the RGB-only run it is compared with, so "
            "an added camera that sends the RGB model the same gradient trains the very same model (`identical`: "
            "every held-out view the same to the last digit). Where a camera does move the model, the training "
            f"diverges from there on, and the difference itself varies between streams ({streams}): by a standard "
            f"deviation of {sd:.2f} dB ({dof} degrees of freedom, pooled over the scenes and the rows that are not "
            "identical). Each interval below adds that to the paired per-view interval (in quadrature), so a * marks "
            "a difference beyond both. Cells are the runs of stream 0.\n\n"
        )
    else:
        replicates = ["rgb"] + [method(r, s)[0] for r in REPLICATE_ROUTINGS for s in SETS]
        sd, dof = results.run_spread(rows, replicates)
        factor = 2.0**0.5
        spread = (
            "Run-to-run spread: training is deterministic for one random stream, but the RGB-only model's final PSNR "
            f"moves with the stream (the rays drawn) by a standard deviation of {sd:.2f} dB ({dof} degrees of "
            "freedom, pooled over the scenes from the RGB run and the `rgb-geometry` runs, which receive exactly its "
            "gradient; runs that drew the same stream count once). Each interval below adds that spread for two "
            "single runs to the paired per-view interval (in quadrature), so a * marks a difference beyond both.\n\n"
            if dof
            else "No replicate runs: the intervals cover the held-out views only, not the run-to-run spread.\n\n"
        )
    text = (
        "# RGB PSNR per loss routing\n\n"
        f"Command: `python benchmarks/bench_loss_routing.py {' '.join(sys.argv[1:])}`\n\n"
        f"Machine: {device}. Profile `{args.profile}`: AgriNeRF-lite, {profile.steps['agrinerf-lite']} steps, "
        f"{profile.views} views of {profile.width}x{profile.height}, every {profile.eval_every}th held out. PSNR "
        "against the exposure-aligned clean truth at the last step; in brackets the mean paired per-view difference "
        "to the RGB-only run and its 95% interval (* where the interval excludes 0). Routings: "
        "`benchmarks/bench_loss_routing.py` ROUTINGS.\n\n" + spread
    )
    for routing in args.routings:
        keys = ["rgb"] + [method(routing, s)[0] for s in args.sets]
        labels = {"rgb": "RGB", **{method(routing, s)[0]: SETS[s] for s in args.sets}}
        table_rows, note = rows, ""
        if routing == "default":
            table_rows, borrowed = default_rows(rows, args.out / "scenes")
            if borrowed:
                note = f"Scenes {', '.join(borrowed)}: frames above the low-light level. "
            if len(table_rows) > len(rows):
                note += (
                    "Where the frames are above it, and in RGB+Events (no thermal frames) everywhere, the default routes "
                    "as `rgb-geometry` (the same RGB gradient), and the cells are the `rgb-geometry` runs.\n"
                )
        table = results.ablation_table(table_rows, keys, "rgb", labels, (sd, dof), factor)
        text += f"Routing `{routing}`:\n\n" + table + ("\n" + note if note else "") + "\n"
    keys = [method(r, s)[0] for s in args.sets for r in args.routings]
    return (
        text
        + "Thermal-camera and cross-spectral thermal PSNR (against the rescaled thermal frames):\n\n"
        + thermal_table(rows, keys)
    )


def default_rows(rows, scenes: Path) -> Tuple[list, List[str]]:
    """The rows with `default` runs borrowed from `rgb-geometry` in the scenes that have none and whose training
    frames (``scenes/<scene>/data/images``) are above the model's low-light level: there the low-light rule does not
    fire and both routings send the density only L_rgb's gradient. Returns the rows and the scenes borrowed for."""
    level = AgriNeRFModelConfig().low_light_level
    have = {r["scene"] for r in rows if r["method"].startswith("default:")}
    bright = set()
    for scene in {r["scene"] for r in rows} - have:
        images = sorted((scenes / scene / "data" / "images").glob("*.png"))
        if images and rgb_level(images) >= level:
            bright.add(scene)
    have_runs = {(r["scene"], r["method"]) for r in rows}
    extra = []
    for r in rows:
        routing, _, modality_set = r["method"].partition(":")
        no_thermal = "thermal" not in TABLE_IV_ABLATIONS[SETS.get(modality_set, "All")]
        if routing == "rgb-geometry" and (r["scene"] in bright or no_thermal):
            if (r["scene"], f"default:{modality_set}") not in have_runs:
                extra.append({**r, "method": f"default:{modality_set}"})
    return list(rows) + extra, sorted(bright)


def thermal_table(rows, keys) -> str:
    """Final PSNR / SSIM of the cross-spectral `thermal` output and PSNR of `thermal_camera` (against the rescaled
    thermal frames), per scene and run."""
    last = results.final_rows(rows)
    lines = [
        "| scene | run | thermal PSNR / SSIM (cross-spectral) | thermal_camera PSNR |",
        "|---|---|---|---|",
    ]
    for (scene, key), row in sorted(last.items()):
        if key not in keys:
            continue
        psnr, ssim, camera = (results.as_float(row, k) for k in ("thermal_psnr", "thermal_ssim", "thermal_camera_psnr"))
        if psnr != psnr:
            continue  # no thermal frames in this set (RGB+Events)
        camera_cell = "-" if camera != camera else f"{camera:.2f}"
        lines.append(f"| {scene} | {key} | {psnr:.2f} / {ssim:.3f} | {camera_cell} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main(tyro.cli(Args))
