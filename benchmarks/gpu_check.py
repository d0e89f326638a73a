"""The checks a session runs when it is lent a GPU: every preset trains past its first box fit and an upsampling on
CUDA, the stock commands load the paper preset's run, and the paper preset's step is timed against ``tensorf``.

    bash scripts/gpu_check.sh [--out outputs/gpu-check] [--steps 300]    # on a machine with CUDA
    bash scripts/gpu_check.sh --dry-run                                 # any machine: every command parses

Steps, in order (each one's output in ``OUT/logs/``):

1. ``agrinerf-synth`` and ``agrinerf-process --poses given --fruit-mask-maker auto``: a dusk garden with blur, events,
   thermal frames and fruit masks (so every preset builds its fruit head and trains it on CUDA), metric poses (so the
   box fit's voxel target applies, the path of the first GPU crash).
2. ``ns-train PRESET`` for every preset, ``--steps`` steps, its box fits at steps 100 and 200 and its grids upsampled at
   steps 150 and 250, blur model and events on from step 0; then ``ns-eval`` on each run.
3. ``ns-render dataset`` and ``agrinerf-count`` (scored against the synthetic truth) on the paper preset's run.
4. ``benchmarks/bench_step_interleaved.py``: seconds per step of ``tensorf`` and of the paper preset at its start and at
   its final grids (``agrinerf@7000``), stepping in turn on the GPU.

Writes ``OUT/gpu_check.md``: one row per command (exit status, wall seconds, the figure it gives), the device's name
on top. ``--dry-run`` parses every command with the command's own parser (Nerfstudio's and this project's tyro
types) and runs nothing: the suite checks the script this way on a CPU.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Dict, List, NamedTuple, Optional, Tuple

import tyro

from agrinerf_ns.ns_commands import RUN_TIMESTAMP, console_script, headless_train_args

PRESETS = (
    "agrinerf",
    "agrinerf-lite",
    "evdeblurnerf",
    "evdeblurnerf-lite",
    "evdeblurnerf-windowed",
    "evdeblurnerf-windowed-lite",
)
BENCH = Path(__file__).resolve().parent
EXPERIMENT = "gpu-check"
TABLE_COLUMNS = ("check", "command", "exit", "wall (s)", "result")


@dataclass
class Args:
    out: Path = Path("outputs/gpu-check")
    """Folder of everything the check writes (scene, runs, logs, the table)."""
    steps: int = 300
    """Training steps per preset (past the box fits at 100 and 200 and the upsamplings at 150 and 250)."""
    presets: Tuple[str, ...] = PRESETS
    rays_per_batch: int = 4096
    dry_run: bool = False
    """Parse every command with its own parser; run nothing."""
    allow_cpu: bool = False
    """Run the check without CUDA (slow; for trying the script itself)."""


class Step(NamedTuple):
    check: str
    argv: List[str]
    """The command: a console script and its arguments, or python and a script."""
    result: Optional[Callable[[], str]] = None
    """The figure to report once it ran."""


def _train_args(args: Args, preset: str) -> List[str]:
    train = headless_train_args(args.steps, args.rays_per_batch, args.out / "runs", EXPERIMENT, args.steps)
    train[train.index("--machine.device-type") + 1] = "cpu" if args.allow_cpu else "cuda"
    model = "--pipeline.model."
    schedule = [f"{model}box-fit-iters", "100", "200", f"{model}upsampling-iters", "150", "250"]
    if "windowed" not in preset and not preset.startswith("agrinerf-lite"):
        schedule += [f"{model}blur-start-step", "0"]
    return [preset, "--data", str(args.out / "data"), *train, *schedule]


def _config(args: Args, preset: str) -> Path:
    return args.out / "runs" / EXPERIMENT / preset / RUN_TIMESTAMP / "config.yml"


def _json_figure(path: Path, *keys: str) -> Callable[[], str]:
    def read() -> str:
        data = json.loads(path.read_text())
        for key in keys[:-1]:
            data = data.get(key, {})
        value = data.get(keys[-1])
        return f"{keys[-1]} {value:.4g}" if isinstance(value, (int, float)) else f"{keys[-1]}: not found"

    return read


def _count_figure(path: Path) -> Callable[[], str]:
    def read() -> str:
        report = json.loads(path.read_text())
        score = report.get("score") or {}
        fruit = report.get("fruit")
        return f"{fruit} fruit; F1 {score['f1']:.3f} at {score['match_distance']} m" if score else f"{fruit} fruit"

    return read


def _step_figure(path: Path) -> Callable[[], str]:
    """Each run's median seconds per step and its median per-round ratio to the first run (tensorf)."""

    def read() -> str:
        rows = [[c.strip() for c in line.strip().strip("|").split("|")] for line in path.read_text().splitlines()]
        rows = [r for r in rows if len(r) >= 8 and r[0] not in ("run", "---")]
        return "; ".join(f"{r[0]} {r[5]} s/step ({r[7]}x tensorf)" for r in rows)

    return read


def _data_steps(raw: Path, data: Path) -> List[Step]:
    """The synthetic scene and its dataset."""
    synth = ["--scene", "garden", "--lighting", "dusk", "--seed", "0", "--views", "24", "--no-preview"]
    masks = ["--poses", "given", "--fruit-mask-maker", "auto"]
    return [
        Step("scene", ["agrinerf-synth", "--out", str(raw), *synth]),
        # fruit masks from the frames (colour where lit, thermal where dark): the fruit head trains, its CUDA path runs
        Step("dataset", ["agrinerf-process", "--raw", str(raw), "--out", str(data), *masks]),
    ]


def _train_steps(args: Args) -> List[Step]:
    """Training and evaluating every preset."""
    plan = []
    for preset in args.presets:
        plan.append(Step(f"train {preset}", ["ns-train", *_train_args(args, preset)]))
        metrics = args.out / "eval" / f"{preset}.json"
        plan.append(
            Step(
                f"eval {preset}",
                ["ns-eval", "--load-config", str(_config(args, preset)), "--output-path", str(metrics)],
                _json_figure(metrics, "results", "psnr"),
            )
        )
    return plan


def _paper_steps(args: Args, raw: Path, data: Path) -> List[Step]:
    """The stock render and the count on the paper preset's run, and the step time against tensorf."""
    out, paper = args.out, _config(args, args.presets[0])
    render = ["--rendered-output-names", "rgb", "thermal", "--output-path", str(out / "renders")]
    timing = ["--data", str(data), "--out", str(out / "step-speed"), "--runs", "tensorf", "agrinerf", "agrinerf@7000"]
    timing += ["--steps", "20", "--rays-per-batch", str(args.rays_per_batch)]
    return [
        Step("render", ["ns-render", "dataset", "--load-config", str(paper), *render]),
        Step(
            "count",
            ["agrinerf-count", "--config", str(paper), "--out", str(out / "count"), "--truth", str(raw)],
            _count_figure(out / "count" / "count.json"),
        ),
        Step(
            "step time",
            [sys.executable, str(BENCH / "bench_step_interleaved.py"), *timing],
            _step_figure(out / "step-speed" / "step_speed.md"),
        ),
    ]


def steps(args: Args) -> List[Step]:
    """Every command of the check, in order."""
    raw, data = args.out / "raw", args.out / "data"
    return _data_steps(raw, data) + _train_steps(args) + _paper_steps(args, raw, data)


def _parsers() -> Dict[str, Callable[[List[str]], object]]:
    """Each command's own argument parser, run on a list of arguments without running the command."""
    import importlib.util

    from nerfstudio.scripts.eval import ComputePSNR
    from nerfstudio.scripts.render import Commands
    from nerfstudio.scripts.train import AnnotatedBaseConfigUnion

    from agrinerf_ns.count.cli import CountArgs
    from agrinerf_ns.process.cli import ProcessArgs
    from agrinerf_ns.synth.cli import SynthCommand

    spec = importlib.util.spec_from_file_location("bench_step_interleaved", BENCH / "bench_step_interleaved.py")
    assert spec is not None and spec.loader is not None
    step_bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = step_bench  # dataclasses look their module up while the class is made
    spec.loader.exec_module(step_bench)
    types: Dict[str, object] = {
        "ns-train": AnnotatedBaseConfigUnion,
        "ns-eval": ComputePSNR,
        "ns-render": Commands,
        "agrinerf-count": CountArgs,
        "agrinerf-process": ProcessArgs,
        "agrinerf-synth": SynthCommand,
        "bench_step_interleaved.py": step_bench.Args,
    }
    return {name: (lambda argv, t=t: tyro.cli(t, args=argv)) for name, t in types.items()}  # type: ignore[misc]


def _command_name(argv: List[str]) -> Tuple[str, List[str]]:
    if argv[0] == sys.executable:
        return Path(argv[1]).name, argv[2:]
    return argv[0], argv[1:]


def dry_run(plan: List[Step]) -> List[str]:
    """Parse every command; returns one line per command ("ok" or the parser's complaint)."""
    parsers = _parsers()
    lines = []
    for step in plan:
        name, rest = _command_name(step.argv)
        try:
            parsers[name](rest)
            lines.append(f"ok      {step.check}: {' '.join(step.argv)}")
        except SystemExit as err:
            lines.append(f"FAILED  {step.check}: {' '.join(step.argv)} (parser exit {err.code})")
    return lines


def run(args: Args, plan: List[Step]) -> List[Tuple[str, ...]]:
    """Run the commands in order (a failed one is recorded and the rest still run); returns the table's rows."""
    logs = args.out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    rows = []
    for i, step in enumerate(plan):
        argv = [console_script(step.argv[0]), *step.argv[1:]] if step.argv[0] != sys.executable else step.argv
        log = logs / f"{i:02d}-{step.check.replace(' ', '-')}.log"
        start = time.perf_counter()
        with open(log, "w") as handle:
            code = subprocess.run(argv, stdout=handle, stderr=subprocess.STDOUT, check=False).returncode
        wall = time.perf_counter() - start
        result = ""
        if code == 0 and step.result is not None:
            try:
                result = step.result()
            except (OSError, ValueError, KeyError, IndexError) as err:
                result = f"no figure: {err}"
        elif code != 0:
            result = f"failed: see {log}"
        rows.append((step.check, " ".join(step.argv), str(code), f"{wall:.1f}", result))
        print(f"{step.check}: exit {code}, {wall:.1f} s {result}", flush=True)
    return rows


def write_table(path: Path, device: str, rows: List[Tuple[str, ...]]) -> None:
    lines = [f"# GPU check on {device}", "", "| " + " | ".join(TABLE_COLUMNS) + " |", "|---" * len(TABLE_COLUMNS) + "|"]
    lines += ["| " + " | ".join(cell.replace("|", "/") for cell in row) + " |" for row in rows]
    tmp = path.with_suffix(".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(path)


def main(args: Args) -> int:
    plan = steps(args)
    if args.dry_run:
        lines = dry_run(plan)
        print("\n".join(lines))
        return 1 if any(line.startswith("FAILED") for line in lines) else 0
    import torch

    from agrinerf_ns.machine import device_name

    if not torch.cuda.is_available() and not args.allow_cpu:
        print("gpu_check: PyTorch sees no CUDA device (--allow-cpu runs the check on the CPU)", file=sys.stderr)
        return 2
    args.out.mkdir(parents=True, exist_ok=True)
    rows = run(args, plan)
    write_table(args.out / "gpu_check.md", device_name(), rows)
    print(f"wrote {args.out / 'gpu_check.md'}")
    return 0 if all(row[2] == "0" for row in rows) else 1


if __name__ == "__main__":
    sys.exit(main(tyro.cli(Args)))
