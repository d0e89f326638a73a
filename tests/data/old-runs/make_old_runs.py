# Writes the fixtures of this folder (see README.md); run with the commit it names checked out.
"""Make tiny runs with today's (pre-refactor) code, as fixtures of older runs."""

import os
import subprocess
from pathlib import Path

from agrinerf_ns.ns_commands import headless_train_args
from agrinerf_ns.process import ProcessConfig, process_capture
from agrinerf_ns.synth import SynthConfig, generate_capture

root = Path("/tmp/oldrun")
data = root / "orchard"
if not data.exists():
    raw = generate_capture(SynthConfig.tiny(seed=2, lighting="dusk"), root / "raw")
    process_capture(raw, data, ProcessConfig(poses="given", show_progress=False))
env = {**os.environ, "PYTHONWARNINGS": "ignore"}
small = [
    "--pipeline.model.init-resolution",
    "8",
    "--pipeline.model.final-resolution",
    "8",
    "--pipeline.model.occupancy-resolution",
    "8",
]
for method, extra in (
    (
        "agrinerf-lite",
        [
            "--pipeline.model.event-rays-per-batch",
            "32",
            "--pipeline.model.event-threshold-learnt",
            "True",
            "--pipeline.model.event-loss-weighting",
            "noise",
            "--pipeline.model.blur-samples",
            "3",
        ],
    ),
    (
        "evdeblurnerf-lite",
        [
            "--pipeline.model.blur-start-step",
            "0",
            "--pipeline.model.event-crf-start-step",
            "0",
            "--pipeline.model.event-rays-per-batch",
            "16",
            "--pipeline.model.blur-samples",
            "3",
            "--pipeline.model.event-threshold-learnt",
            "True",
        ],
    ),
):
    args = (
        ["ns-train", method, "--data", str(data)] + headless_train_args(3, 64, root / "outputs", "old") + small + extra
    )
    subprocess.run(args, check=True, env=env, timeout=900)
