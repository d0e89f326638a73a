"""What pulls the geometry: each loss term's gradient on the shared density and on each head, over training.

    python benchmarks/bench_loss_gradients.py --data outputs/routing/scenes/orchard-dusk/data \
        --out outputs/gradients-dusk [--routings paper camera] [--steps 500] [--every 25]

AgriNeRF-lite trains in this process (Nerfstudio's pipeline, optimizers, schedulers and the model's upsampling and
occupancy callbacks, as ``ns-train`` runs them) once per routing. Every ``--every`` steps each weighted loss term of
that step's batch is differentiated on its own: the L2 norm of its gradient on the density volume, each appearance
volume and each MLP, and the cosine between its density gradient and L_rgb's (does it push the geometry the way the
RGB frames do?). Writes ``OUT/gradients.csv`` (every measurement), ``OUT/gradients.md`` (medians over the first and
last thirds of training) and ``OUT/gradients.png`` (density gradient norm per term against step).
"""

from __future__ import annotations

import csv
import math
import statistics
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Dict, List, Tuple

import torch
import tyro

from agrinerf_ns.lab.stepper import MethodStepper
from agrinerf_ns.machine import device_name
from agrinerf_ns.model.gradients import parameter_groups, term_gradients
from agrinerf_ns.model.loss_routing import PAPER_DENSITY_GRADIENT_SCALES

CAMERA_SCALES = {**PAPER_DENSITY_GRADIENT_SCALES, "thermal_loss": 0.0, "reg_rgb_loss": 0.0, "reg_event_loss": 0.0}
ROUTINGS: Dict[str, Dict[str, object]] = {
    "paper": {"density_gradient_scales": dict(PAPER_DENSITY_GRADIENT_SCALES), "thermal_camera_output": False},
    "camera": {"density_gradient_scales": CAMERA_SCALES},
    "default": {},
}
"""paper: every term moves the density, one thermal output (the loss as written). camera: the thermal-camera channel
moves the density, the cross-spectral terms do not. default: the model's defaults (only L_rgb moves it)."""


@dataclass
class Args:
    data: Path
    """A processed dataset folder."""
    out: Path = Path("outputs/gradients")
    routings: Tuple[str, ...] = ("paper", "camera", "default")
    modalities: Tuple[str, ...] = ("rgb", "thermal", "events")
    steps: int = 500
    every: int = 25
    rays_per_batch: int = 1024
    seed: int = 0


Row = Dict[str, object]


def measure(args: Args, routing: str) -> List[Row]:
    torch.manual_seed(args.seed)
    overrides = {"modalities": tuple(args.modalities), **ROUTINGS[routing]}
    stepper = MethodStepper("agrinerf-lite", args.data, args.rays_per_batch, overrides, callbacks=True)
    model = stepper.pipeline.model
    rows: List[Row] = []
    for step in range(args.steps):
        loss_dict = stepper.loss_dict(step)
        if step % args.every == 0 or step == args.steps - 1:
            data_terms = {k: v for k, v in loss_dict.items() if k.endswith("_loss")}
            grads = term_gradients(data_terms, parameter_groups(model))
            rgb_density = grads.get("rgb_loss", {}).get("density")
            for term, by_group in grads.items():
                density = by_group["density"]
                cosine = math.nan
                if density is not None and rgb_density is not None and term != "rgb_loss":
                    cosine = float(torch.nn.functional.cosine_similarity(density, rgb_density, dim=0))
                row: Row = {"routing": routing, "step": step, "term": term, "loss": float(loss_dict[term]),
                            "cos_rgb_density": cosine}  # fmt: skip
                for group, grad in by_group.items():
                    row[group] = 0.0 if grad is None else float(grad.double().norm())
                rows.append(row)
        stepper.apply(loss_dict, step)
    return rows


GROUPS = ("density", "rgb_volume", "rgb_mlp", "thermal_volume", "thermal_mlp")


def report(rows: List[Row], args: Args, device: str) -> str:
    lines = [
        "# Loss-term gradients on the AgriNeRF-lite parameter groups",
        "",
        f"Command: `python benchmarks/bench_loss_gradients.py {' '.join(sys.argv[1:])}`",
        "",
        f"Machine: {device}. Data: `{args.data}`, modalities {' '.join(args.modalities)}, {args.steps} steps, "
        f"{args.rays_per_batch} rays per batch, measured every {args.every} steps. Each figure is the median over "
        "the first / last third of training of the L2 norm of one weighted term's gradient on one parameter group; "
        "`share` is the term's part of the summed density gradient norms; `cos(rgb)` the median cosine between "
        "the term's density gradient and L_rgb's.",
        "",
    ]
    third = args.steps / 3
    for routing in args.routings:
        mine = [r for r in rows if r["routing"] == routing]
        lines += [f"## Routing `{routing}`", "",
                  "| term | loss (last third) | density (first / last) | share of density | cos(rgb) | "
                  + " | ".join(f"{g} (last)" for g in GROUPS[1:]) + " |",
                  "|---|---|---|---|---|" + "---|" * (len(GROUPS) - 1)]  # fmt: skip
        late = [r for r in mine if float(r["step"]) >= 2 * third]  # type: ignore[arg-type]
        total_late = sum(float(r["density"]) for r in late)  # type: ignore[arg-type]
        for term in sorted({str(r["term"]) for r in mine}):
            early_t = [r for r in mine if r["term"] == term and float(r["step"]) < third]  # type: ignore[arg-type]
            late_t = [r for r in late if r["term"] == term]
            share = sum(float(r["density"]) for r in late_t) / total_late if total_late else math.nan  # type: ignore
            cells = [term, f"{med(late_t, 'loss'):.3g}", f"{med(early_t, 'density'):.3g} / {med(late_t, 'density'):.3g}",
                     f"{share:.0%}", _fmt(med(late_t, "cos_rgb_density"))]  # fmt: skip
            cells += [_fmt(med(late_t, g), "{:.3g}") for g in GROUPS[1:]]
            lines.append("| " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def med(rows: List[Row], key: str) -> float:
    """Median of the finite values of `key` in `rows` (NaN when there are none)."""
    values = [float(r[key]) for r in rows if key in r and math.isfinite(float(r[key]))]  # type: ignore[arg-type]
    return statistics.median(values) if values else math.nan


def _fmt(value: float, pattern: str = "{:+.2f}") -> str:
    return "-" if not math.isfinite(value) else pattern.format(value)


def plot(rows: List[Row], args: Args, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(args.routings), figsize=(5.5 * len(args.routings), 4.0), squeeze=False)
    for ax, routing in zip(axes[0], args.routings, strict=True):
        mine = [r for r in rows if r["routing"] == routing]
        for term in sorted({str(r["term"]) for r in mine}):
            pts = [(r["step"], r["density"]) for r in mine if r["term"] == term and float(r["density"]) > 0]  # type: ignore
            if pts:
                ax.plot([p[0] for p in pts], [p[1] for p in pts], label=term)
        ax.set_yscale("log")
        ax.set_title(f"routing: {routing}")
        ax.set_xlabel("step")
        ax.set_ylabel("|gradient| on the density volume")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(args: Args) -> None:
    unknown = [r for r in args.routings if r not in ROUTINGS]
    if unknown:
        raise SystemExit(f"unknown routings {unknown}: choose from {list(ROUTINGS)}")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = [row for routing in args.routings for row in measure(args, routing)]
    fields = ["routing", "step", "term", "loss", "cos_rgb_density", *GROUPS]
    with open(args.out / "gradients.csv", "w", newline="") as handle:
        writer = csv.DictWriter(handle, fieldnames=fields, restval="")
        writer.writeheader()
        writer.writerows(rows)
    (args.out / "gradients.md").write_text(report(rows, args, device_name()))
    plot(rows, args, args.out / "gradients.png")
    print((args.out / "gradients.md").read_text())


if __name__ == "__main__":
    main(tyro.cli(Args))
